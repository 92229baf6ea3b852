"""DCDP policy: a frozen chunking base plus a corrector that adjusts every action of a chunk at every step.

``DCDPPolicy`` is LeRobot's thin wrapper over the parts, each in its own file:

- the base: loaded, hashed and checked in ``base_policy.py``, called through a ``ChunkSource``
  (``chunk_sources.py``), its normalisation reproduced by ``BaseNormalizer``;
- the corrector (``corrector.py``): ``ResidualCorrector`` (default, ``corrector_residual.py``:
  ``a_s = plan_s + delta``, trained on recorded or synthesised corrections, ``training_samples.py``) or the
  paper's ``ReconstructCorrector`` (``corrector_reconstruct.py``), with ``loss`` / ``begin_chunk`` / ``step``;
- the execution modes (``execution_modes.py``: ``dcdp`` and the baselines open loop, closed loop, temporal
  ensemble, object anchoring) over one ``EpisodeState`` (``episode_state.py``);
- the planning (``planning.py``: synchronous, with an optional simulated ``inference_delay``, or
  asynchronous on a worker thread, ``planner.py``);
- the compiled per-step kernel behind ``KernelRunner`` (``kernel_runner.py``);
- the folder and the Hub: loading with the base checked, saving, pushing (``policy_folder.py``).

Stage 1 is ``forward`` (the corrector's loss; the base is not called); stage 2 is ``select_action``.
"""

from __future__ import annotations

import torch
from lerobot.configs.types import FeatureType
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_dcdp.model.anchoring import ObjectAnchor
from lerobot_dcdp.model.base_normalizer import BaseNormalizer
from lerobot_dcdp.model.completion_gate import build_gate, gate_applies, gated_action
from lerobot_dcdp.model.corrector import Corrector
from lerobot_dcdp.model.corrector_reconstruct import ReconstructCorrector
from lerobot_dcdp.model.corrector_residual import ResidualCorrector
from lerobot_dcdp.model.episode_state import EpisodeState
from lerobot_dcdp.model.scene_lead import SceneLead, check_lead_features, lead_applies
from lerobot_dcdp.policy.base_policy import (
    base_image_encoder,
    check_against_base,
    default_image_backbone,
    load_base_policy,
    load_base_stats,
    load_reference_policy,
)
from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.observation_check import ObservationCheck
from lerobot_dcdp.policy.policy_folder import BaseMismatchError, CorrectorFolder
from lerobot_dcdp.policy.processor_pixel_keypoints import declare_reader_output, with_reader_stats
from lerobot_dcdp.runtime.chunk_sources import ChunkSource, RenormalizedSource, make_chunk_source
from lerobot_dcdp.runtime.execution_modes import make_execution_modes
from lerobot_dcdp.runtime.kernel_runner import KernelRunner
from lerobot_dcdp.runtime.planning import AsyncPlanning, SyncPlanning, new_episode

__all__ = ["BaseMismatchError", "DCDPPolicy"]  # the mismatch error is raised on load (policy_folder.py)

#: module names of the corrector's parts in checkpoints saved before they moved under ``corrector.``
LEGACY_PREFIXES = ("frame_encoder.", "extractor.", "encoder.", "residual.", "decoder.")


class DCDPPolicy(CorrectorFolder, PreTrainedPolicy):
    """DCDP corrector around a frozen chunking base policy (see the module docstring)."""

    config_class = DCDPConfig
    name = "dcdp"

    def __init__(self, config: DCDPConfig, dataset_stats: dict | None = None, dataset_meta=None, **kwargs):
        super().__init__(config)
        self.config = config
        base = load_base_policy(
            config.base_policy_path,
            config.device,
            config.pretrained_path,
            weights=config.base_location == "local",
        )
        object.__setattr__(self, "_base", base)  # not a submodule: out of state_dict/parameters/train()
        self._adopt_base(base)
        self._source: ChunkSource = make_chunk_source(base)
        if config.input_features:  # only what the base, the corrector and the anchoring read is asked for
            config.input_features = config.with_encoded_cameras(base.config.input_features or {})
            config.input_features = config.used_inputs(base.config.input_features or {})
        declare_reader_output(config)
        if config.backbone == "auto" and config.resolved_backbone == "resnet18":
            if not config.image_backbone_weights:  # the choice is saved with the folder
                config.backbone = default_image_backbone(base, config.base_location)
        check_against_base(config, base, self.source.chunk_length, self.source.max_length)
        config.validate_features()

        feats = config.input_features
        keys = config.corrector_features
        state_dims = {
            k: feats[k].shape[0] for k in keys if feats[k].type in (FeatureType.STATE, FeatureType.ENV)
        }
        image_keys = (
            []
            if config.resolved_backbone == "mlp"
            else [k for k in keys if feats[k].type is FeatureType.VISUAL]
        )
        self.normalizer = BaseNormalizer(load_base_stats(config.base_policy_path, config.pretrained_path))
        low, high = self.normalizer.action_range(ACTION, config.action_feature.shape[0])
        self.anchor = anchor = ObjectAnchor(config, self.normalizer)
        base_encoder = config.resolved_backbone == "base_encoder"
        encoder = base_image_encoder(base, config.base_location) if base_encoder else None
        if config.correction == "residual":
            self.corrector: Corrector = ResidualCorrector(
                config,
                state_dims,
                image_keys,
                low,
                high,
                self.normalizer,
                anchor if config.anchor_input else None,
                encoder,
            )
        else:
            self.corrector = ReconstructCorrector(config, state_dims, image_keys, low, high, encoder)
        if dataset_stats is not None:
            raw = [  # what the base's normaliser leaves raw: the corrector standardises it itself
                k for k in state_dims if self.normalizer.stats.get(k, ("IDENTITY",))[0] == "IDENTITY"
            ]
            self.corrector.set_input_scaling(with_reader_stats(config, dataset_stats), raw)
        self.state_dims = state_dims  # the corrector's vector features and their sizes
        self.completion_gate = build_gate(config, state_dims)  # fitted by dcdp-fit-completion-gate
        self._register_load_state_dict_pre_hook(_legacy_keys)
        declared = {**(base.config.input_features or {}), **(config.input_features or {})}
        needed = [*self.corrector.frame_keys, *sorted(base.config.input_features or {})]
        self.check = ObservationCheck(
            config, {k: tuple(declared[k].shape) if k in declared else None for k in dict.fromkeys(needed)}
        )
        if config.lead_steps:
            check_lead_features(config, dict(base.config.input_features or {}), self.normalizer)
        self.lead = SceneLead(config, self.normalizer)
        self.kernel = KernelRunner(self.corrector) if config.correction == "residual" else None
        self.modes = make_execution_modes(config, self.corrector, self.kernel, anchor)
        if config.bid_weak_policy_path:
            self.use_bid_reference(config.bid_weak_policy_path)
        self._sync = SyncPlanning(config, self.source, anchor)
        self._async = AsyncPlanning(config, self.source, anchor)
        self.reset()

    def use_bid_reference(self, path: str | None) -> None:
        """Give ``execution='bid'`` the weak reference policy in ``path`` (checked against the base:
        :func:`~lerobot_dcdp.policy.base_policy.load_reference_policy`), fed and read in the base's units
        whatever statistics it was trained on (``RenormalizedSource``); None: none from now on."""
        weak, source = None, None
        if path:
            weak = load_reference_policy(path, self._base, self.config.device)
            weak = make_chunk_source(weak).base  # refuses a policy that cannot plan chunks
            source = RenormalizedSource(weak, self.normalizer, BaseNormalizer(load_base_stats(path)))
        object.__setattr__(self, "_weak", weak)  # frozen like the base: not a submodule
        self.modes["bid"].weak = source
        self.config.bid_weak_policy_path = path

    # ------------------------------------------------------------------ the base
    @property
    def base(self) -> PreTrainedPolicy:
        """The frozen base policy (not a submodule of this one)."""
        return self._base

    @property
    def source(self) -> ChunkSource:
        """How chunks are asked of the base (``chunk_sources.py``)."""
        return self._source

    @source.setter
    def source(self, source: ChunkSource) -> None:
        """Plan with another chunk source from now on (e.g. a stand-in base in a test)."""
        self._async.close()
        self._source = self._sync.source = self._async.source = source

    def to(self, *args, **kwargs):
        super().to(*args, **kwargs)
        self._base.to(*args, **kwargs)
        if getattr(self, "_weak", None) is not None:
            self._weak.to(*args, **kwargs)
        return self

    def get_optim_params(self) -> list[torch.nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    # ------------------------------------------------------------------ stage 1
    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Stage-1 loss of the corrector (``residual``: ``training_samples.py``; ``reconstruct``: paper)."""
        return self.corrector.loss(batch)

    # ------------------------------------------------------------------ stage 2
    @property
    def fast_inference(self) -> bool:
        """Per-chunk shortcuts and the compiled kernel allowed (False: every step through the plain modules;
        same actions up to float rounding)."""
        return self.corrector.fast_inference

    @fast_inference.setter
    def fast_inference(self, value: bool) -> None:
        self.corrector.fast_inference = value

    @property
    def planned_chunk(self) -> Tensor | None:
        """The chunk being executed (B, H, A), base-normalised, as the base planned it (open loop, DCDP and
        object_anchored; ``last_step`` is the index of the action last returned)."""
        return self.state.chunk

    @property
    def last_step(self) -> int | None:
        """Index in the chunk of the action last returned (0 for the per-step modes)."""
        return self.state.last_step

    @property
    def chunk_delay(self) -> int:
        """Steps from the observation the chunk being executed was planned from to its first action (0 for
        an on-time chunk; ``inference_delay`` or the real lateness under ``planning='async'``)."""
        return self.state.chunk_delay

    def reset(self) -> None:
        """Start a new episode: clear the history bank and the chunk state, and reset the base."""
        self.source.reset()
        for mode in self.modes.values():
            mode.reset()
        self._async.cancel()
        self.state: EpisodeState = new_episode(self.config)
        self.lead.reset()
        self._held: Tensor | None = None  # ticks_per_step > 1: the action held, for _held_ticks more calls
        self._held_ticks = 0

    @property
    def holds_next_tick(self) -> bool:
        """Whether the next ``select_action`` call returns the held action without computing
        (``ticks_per_step`` > 1, between two planned steps)."""
        return self._held_ticks > 0

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor]) -> Tensor:
        """One action (B, A) per environment for the current tick (normalised; the post-processor maps it).
        With ``ticks_per_step`` k > 1 it is computed on every k-th call and held on the calls between."""
        if self._held_ticks > 0:
            self._held_ticks -= 1
            return self._held.clone()
        action = self._compute_action(batch)
        if self.config.ticks_per_step > 1:
            self._held, self._held_ticks = action.clone(), self.config.ticks_per_step - 1
        return action

    def _compute_action(self, batch: dict[str, Tensor]) -> Tensor:
        self.check(batch, self.state)
        if self.config.base_location == "remote" and not self._async.attached:
            raise ValueError(
                "base_location='remote': the base plans on another machine; attach its planner first "
                "(DCDPPolicy.attach_planner, as dcdp-robot-client does)"
            )
        mode = self.modes[self.config.execution]
        planning = self._async if self.config.planning == "async" else self._sync
        led = lead_applies(self.config)
        if led:  # the whole step runs in the led scene; only its action is moved back
            batch, shift = self.lead.enter(batch)
        action = planning.act(self.state, batch, mode)
        if self.gate_applies:
            plan = self.state.chunk[:, self.state.last_step]
            action = gated_action(plan, action, self.completion_gate(batch))
        return self.lead.move_action(action, -shift) if led else action

    @property
    def gate_applies(self) -> bool:
        """Whether the fitted completion gate scales this mode's change of the plan (``gate_applies``)."""
        return gate_applies(self.completion_gate, self.config)

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor]) -> Tensor:
        """The chunk (B, H, A) the policy would start from ``batch`` as its next observation: in ``dcdp`` the
        corrected chunk, every step decoded with the current F (no later observation exists yet: for
        ``residual`` nothing has changed since plan time, so this is the base's chunk plus the corrections a
        still world gets); in the other modes the base's chunk as planned.

        A query: the episode state, the scene lead's track and the base's observation queues are the same
        afterwards, so calling it between ``select_action`` calls changes none of their actions. Its steps are
        planned steps (each lasts ``ticks_per_step`` control ticks). With the scene lead, the chunk is planned
        in the led scene and moved back, as ``select_action`` does.
        """
        self.check(batch, self.state)
        led = lead_applies(self.config)
        if led:
            batch, shift = self.lead.enter(batch, record=False)
        state, queues = self.state.copy(), self.source.snapshot()
        try:
            prepared = self.source.observe(batch)
            self.corrector.push_frame(state, batch)
            chunk = self.source.chunk(prepared)[:, : self.config.n_action_steps]
            # the other modes start from the chunk as planned (nothing has moved since plan time)
            corrected = self.corrector.query_chunk(state, chunk) if self.config.execution == "dcdp" else chunk
            if self.completion_gate is not None and self.config.completion_gate:
                corrected = gated_action(chunk, corrected, self.completion_gate(batch))
            return self.lead.move_action(corrected, -shift) if led else corrected
        finally:
            self.source.restore(queues)

    def attach_planner(self, planner, lead: int | None = None) -> None:
        """Plan every chunk with ``planner`` (``planning='async'``), e.g. a ``RemotePlanner`` whose base runs
        in LeRobot's policy server; ``lead``: request the next chunk this many steps before the current one
        ends (default: the planning clock's own lead). The caller closes the planner."""
        if self.config.planning != "async":
            raise ValueError("attach_planner needs --policy.planning=async")
        self._async.attach(planner, lead)
        self.reset()

    def close(self) -> None:
        """Stop the asynchronous planner's worker thread (``planning='async'``); the policy stays usable."""
        self._async.close()


def _legacy_keys(state_dict: dict, prefix: str, *args) -> None:
    """Load checkpoints saved before the corrector's parts moved under ``corrector.`` (same weights)."""
    for key in list(state_dict):
        rest = key[len(prefix) :]
        if key.startswith(prefix) and rest.startswith(LEGACY_PREFIXES):
            state_dict[f"{prefix}corrector.{rest}"] = state_dict.pop(key)
