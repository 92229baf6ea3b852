"""DCDP policy: a frozen chunking base plus a corrector that adjusts every action of a chunk at every step.

Stage 1 (``forward``), ``residual`` (default): one control step t per sample; the corrector -- dynamic feature
extractor pi_f, chunk encoder E and residual head -- learns ``a_t = plan_s + delta(z, plan_s, F_t, change
since plan time, e_s)`` from recorded corrections of stale chunks, or from plain demonstrations with
synthesised object motion (``motion_synthesis.py``). ``reconstruct`` (the paper's): the VAE reconstructs
demonstration chunks, ``L = MSE(A_hat, A) + lambda_KL KL(q(z|A) || N(0, I)) + lambda_diff L_diff``. The base
is not called.

Stage 2 (``select_action``): every H steps the base plans a chunk, which is normalised to [-1, 1] and encoded
once to ``z_t = mu``; at every step s the newest observation enters the history bank (one cached frame token
per step) and the action is ``plan_s + delta`` (``residual``) or ``D(z_t, F_{t+s}, e_s)`` (``reconstruct``).
The baselines (open loop, closed loop, temporal ensemble, object anchoring) are other execution modes of this
same loop.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections import deque
from pathlib import Path

import torch
from lerobot.configs.types import FeatureType, NormalizationMode
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_dcdp.action_vae import ActionDecoder, ChunkEncoder, kl_to_standard_normal, reparameterize
from lerobot_dcdp.base_policy import (
    load_base_policy,
    load_base_stats,
    portable_base_reference,
    resolve_base_reference,
)
from lerobot_dcdp.chunk_sources import ChunkSource, make_chunk_source
from lerobot_dcdp.configuration_dcdp import CHUNK_MODES, DCDPConfig
from lerobot_dcdp.correction import (
    action_range,
    anchor_actions,
    check_normalization,
    from_unit_range,
    normalize,
    rigid_fit_2d,
    sliding_windows,
    state_dict_sha256,
    temporal_ensemble_step,
    to_unit_range,
    unnormalize,
)
from lerobot_dcdp.dynamics import DynamicFeatureExtractor, FrameEncoder, diff_loss
from lerobot_dcdp.motion_synthesis import draw_motions, keypoint_extent, move_window
from lerobot_dcdp.planner import BackgroundPlanner
from lerobot_dcdp.residual import ResidualHead, change_input

NORMALIZER_STATS = ("min", "max", "mean", "std", "q01", "q99", "q10", "q90")


class BaseMismatchError(ValueError):
    """The base policy found at load time is not the one the corrector was trained against."""


class DCDPPolicy(PreTrainedPolicy):
    """DCDP corrector around a frozen chunking base policy (see the module docstring)."""

    config_class = DCDPConfig
    name = "dcdp"

    def __init__(self, config: DCDPConfig, dataset_stats: dict | None = None, dataset_meta=None, **kwargs):
        super().__init__(config)
        self.config = config
        base = load_base_policy(config.base_policy_path, config.device, config.pretrained_path)
        object.__setattr__(self, "_base", base)  # not a submodule: out of state_dict/parameters/train()
        digest = state_dict_sha256(base.state_dict())
        if config.base_weights_sha256 is None:
            config.base_weights_sha256 = digest
        elif config.base_weights_sha256 != digest:
            raise BaseMismatchError(
                f"base_weights_sha256 mismatch: the corrector was trained against base weights "
                f"{config.base_weights_sha256[:12]}..., but base_policy_path={config.base_policy_path!r} "
                f"now holds {digest[:12]}...; retrain stage 1 or point base_policy_path at the original base"
            )
        if config.base_policy_type not in (None, base.config.type):
            raise BaseMismatchError(
                f"base_policy_type mismatch: recorded {config.base_policy_type!r}, found {base.config.type!r}"
            )
        config.base_policy_type = base.config.type
        config.normalization_mapping = dict(base.config.normalization_mapping)
        self.source: ChunkSource = make_chunk_source(base)
        if config.input_features:  # the recorded plan is a training target's context, never an input
            config.input_features = {
                k: v
                for k, v in config.input_features.items()
                if k not in (config.plan_feature, config.plan_step_feature)
            }
        self._check_against_base(base)
        config.validate_features()

        feats = config.input_features
        keys = config.corrector_features
        state_dims = {
            k: feats[k].shape[0] for k in keys if feats[k].type in (FeatureType.STATE, FeatureType.ENV)
        }
        image_keys = [k for k in keys if feats[k].type is FeatureType.VISUAL]
        if config.resolved_backbone == "mlp":
            image_keys = []
        action_dim = config.action_feature.shape[0]
        self.frame_encoder = FrameEncoder(
            state_dims,
            image_keys,
            config.feature_dim,
            config.state_hidden_dim,
            config.image_backbone_weights,
            config.freeze_image_backbone,
        )
        self.extractor = DynamicFeatureExtractor(
            config.n_history,
            config.feature_dim,
            config.n_heads,
            config.alpha_init,
            config.use_temporal_attention,
            config.use_diff_cross_attention,
            use_alpha=config.use_diff_cross_attention or config.use_diff_loss,
        )
        self.encoder = ChunkEncoder(
            config.n_action_steps, action_dim, config.encoder_hidden_dim, config.latent_dim
        )
        if config.correction == "residual":
            change_dim = 2 * (sum(state_dims.values()) if state_dims else config.feature_dim)
            change_dim += action_dim if config.anchor_input else 0
            self.residual = ResidualHead(
                config.n_action_steps,
                action_dim,
                config.latent_dim,
                config.feature_dim,
                change_dim,
                config.decoder_hidden_dim,
                config.step_embed_dim,
            )
        else:
            self.decoder = ActionDecoder(
                config.n_action_steps,
                action_dim,
                config.latent_dim,
                config.feature_dim,
                config.decoder_hidden_dim,
                config.step_embed_dim,
            )
        if dataset_stats is not None:
            self._set_raw_input_scaling(state_dims, dataset_stats)
        self._base_stats = {  # only what (un)normalising needs: a few tensors touched every step
            key: (mode, {k: v for k, v in stats.items() if k in NORMALIZER_STATS})
            for key, (mode, stats) in load_base_stats(config.base_policy_path, config.pretrained_path).items()
        }
        for key, (mode, stats) in self._base_stats.items():
            check_normalization(key, mode, stats)
        low, high = self._action_range(action_dim)
        self.register_buffer("action_low", low, persistent=False)
        self.register_buffer("action_high", high, persistent=False)
        self._frame_keys = list(state_dims) + image_keys
        self._needed_keys = sorted(set(self._frame_keys) | set(base.config.input_features or {}))
        declared = {**(base.config.input_features or {}), **(config.input_features or {})}
        #: the shape (without batch) every observation key the policy reads must have, checked every step
        self._expected_shapes = {
            k: tuple(declared[k].shape) if k in declared else None
            for k in dict.fromkeys([*self._frame_keys, *self._needed_keys])
        }
        #: residual: sum the head's fixed inputs once per chunk and, on CPU, run the rest of each step as one
        #: compiled kernel (step_kernel.py); same actions up to float rounding. False: the plain eager path.
        #: Both are chosen (and the kernel's weights re-packed if they changed) at planning steps only.
        self.fast_inference = True
        self._packed: tuple[tuple, object] | None = None  # (weight versions, step_kernel.StepWeights)
        self._kernel_supported: bool | None = None  # step_kernel.supports(...) of these modules, once known
        self._kernel = None  # the packed weights while the current chunk runs on the kernel, else None
        self._planner: BackgroundPlanner | None = None  # planning='async': created on first use
        self.register_buffer("action_half_range", 0.5 * (high - low), persistent=False)
        self.reset()

    # ------------------------------------------------------------------ set-up helpers
    @property
    def base(self) -> PreTrainedPolicy:
        """The frozen base policy (not a submodule of this one)."""
        return self._base

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, *, config: DCDPConfig | None = None, **kwargs):
        if config is None:
            config = DCDPConfig.from_pretrained(
                pretrained_name_or_path,
                **{
                    k: v
                    for k, v in kwargs.items()
                    if k in ("revision", "cache_dir", "local_files_only", "token")
                },
            )
        if config.pretrained_path is None and os.path.isdir(str(pretrained_name_or_path)):
            config.pretrained_path = pretrained_name_or_path
        kwargs["strict"] = True  # a corrector key that fails to load would silently leave a head at zero
        try:
            policy = super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)
        except RuntimeError as err:
            if "Missing key" not in str(err) and "Unexpected key" not in str(err):
                raise
            raise ValueError(
                f"corrector weights in {pretrained_name_or_path} do not match config.json "
                f"({str(err).strip().splitlines()[-1].strip()}): it was saved by another dcdp version or "
                "config; retrain it or restore the matching config.json"
            ) from err
        policy.warm_up_kernel()
        return policy

    def warm_up_kernel(self) -> None:
        """Load the compiled per-step kernel (step_kernel.py) now, when it will be used: its first call in a
        process loads it from numba's disk cache (~0.5 s with the import) or compiles it (~15 s, once per
        machine), which would otherwise stall the first control step (``from_pretrained`` calls this)."""
        if self._kernel_applies():
            try:
                self._kernel_weights()
            except Exception as err:
                self._kernel_failed(err)

    def _kernel_failed(self, err: Exception) -> None:
        """``compiled_kernel='auto'``: fall back to the PyTorch path for good, with one warning."""
        if self.config.compiled_kernel == "on":
            raise RuntimeError(
                f"compiled_kernel='on' but the numba kernel failed ({type(err).__name__}: {err}); use "
                "--policy.compiled_kernel=auto to fall back to the PyTorch path"
            ) from err
        logging.getLogger(__name__).warning(
            "dcdp: the compiled per-step kernel is unavailable (%s: %s); using the PyTorch path (same "
            "actions, slower). Set DCDP_KERNEL_CACHE to a writable folder or --policy.compiled_kernel=off.",
            type(err).__name__,
            err,
        )
        self._kernel_supported = False
        self._kernel = None

    def _check_against_base(self, base: PreTrainedPolicy) -> None:
        cfg, bcfg = self.config, base.config
        if cfg.n_action_steps > self.source.chunk_length:
            raise ValueError(
                f"n_action_steps={cfg.n_action_steps} exceeds the base's chunk: "
                f"base type {bcfg.type!r} returns "
                f"{self.source.chunk_length} actions per call; use --policy.n_action_steps between 1 and "
                f"{self.source.chunk_length}"
            )
        if cfg.n_action_steps + cfg.inference_delay > self.source.max_length:
            raise ValueError(
                f"inference_delay={cfg.inference_delay} needs n_action_steps + inference_delay = "
                f"{cfg.n_action_steps + cfg.inference_delay} actions per chunk, but base type {bcfg.type!r} "
                f"returns at most {self.source.max_length}"
            )
        if cfg.output_features and bcfg.output_features:
            ours, theirs = cfg.action_feature, bcfg.action_feature
            if ours is not None and theirs is not None and tuple(ours.shape) != tuple(theirs.shape):
                raise ValueError(
                    f"feature mismatch on 'action': dataset/env shape {tuple(ours.shape)}, "
                    f"base {tuple(theirs.shape)}"
                )
        if cfg.input_features:
            for key, ft in (bcfg.input_features or {}).items():
                if key not in cfg.input_features:
                    raise ValueError(
                        f"feature mismatch: the base needs input {key!r}, "
                        "which the dataset/env does not provide "
                        f"(has {sorted(cfg.input_features)}). Fix: train on a dataset that records {key!r} "
                        "(re-record or convert it with that feature), evaluate in an env observation type "
                        "that reports it (PushT keypoints: --env.obs_type=environment_state_agent_pos), or "
                        "wrap a base trained without it"
                    )
                if tuple(cfg.input_features[key].shape) != tuple(ft.shape):
                    raise ValueError(
                        f"feature mismatch on {key!r}: "
                        f"dataset/env shape {tuple(cfg.input_features[key].shape)}, "
                        f"base {tuple(ft.shape)}"
                    )
        else:
            cfg.input_features = dict(bcfg.input_features)
            cfg.output_features = dict(bcfg.output_features)

    def _set_raw_input_scaling(self, state_dims: dict[str, int], stats: dict) -> None:
        """Standardise (with the dataset's stats) the vector inputs that the base's normaliser leaves raw."""
        mapping = self.config.normalization_mapping
        shift, scale, i = self.frame_encoder.state_shift.clone(), self.frame_encoder.state_scale.clone(), 0
        for key, dim in state_dims.items():
            mode = mapping.get(self.config.input_features[key].type.value, NormalizationMode.IDENTITY)
            if (
                NormalizationMode(mode) is NormalizationMode.IDENTITY
                and key in stats
                and "mean" in stats[key]
            ):
                shift[i : i + dim] = torch.as_tensor(stats[key]["mean"], dtype=torch.float32).reshape(-1)
                scale[i : i + dim] = (
                    torch.as_tensor(stats[key]["std"], dtype=torch.float32).reshape(-1).clamp_min(1e-6)
                )
            i += dim
        self.frame_encoder.state_shift.copy_(shift)
        self.frame_encoder.state_scale.copy_(scale)

    def _action_range(self, action_dim: int) -> tuple[Tensor, Tensor]:
        """Range of the base-normalised actions, mapped to [-1, 1] before encoding (paper: min-max)."""
        mode, stats = self._base_stats.get(ACTION, ("IDENTITY", {}))
        return action_range(stats, mode, action_dim)

    def _norm(self, key: str, x: Tensor, inverse: bool = False) -> Tensor:
        """(Un)normalise feature ``key`` exactly as the base's saved normaliser does."""
        mode, stats = self._base_stats.get(key, ("IDENTITY", {}))
        if any(v.device != x.device or v.dtype != x.dtype for v in stats.values()):
            stats = {k: v.to(x.device, x.dtype) for k, v in stats.items()}
        return unnormalize(x, stats, mode) if inverse else normalize(x, stats, mode)

    def _save_pretrained(self, save_directory, *args, **kwargs) -> None:
        """Save as LeRobot does, recording a local base relative to ``save_directory``."""
        cfg = self.config
        original = cfg.base_policy_path
        cfg.base_policy_path = portable_base_reference(original, cfg.pretrained_path, save_directory)
        try:
            super()._save_pretrained(save_directory, *args, **kwargs)
        finally:
            cfg.base_policy_path = original

    def push_model_to_hub(self, cfg, *args, **kwargs):
        """Push the corrector only; its config names the base by Hub id (``hub_base_policy_path`` when the
        base is a local folder), since a folder on this machine means nothing to whoever downloads it."""
        config = self.config
        local = Path(resolve_base_reference(config.base_policy_path, config.pretrained_path)).is_dir()
        if local and not config.hub_base_policy_path:
            raise ValueError(
                "cannot push a corrector whose base is the local folder "
                f"{config.base_policy_path!r}: push the base to the Hub first and name it with "
                "--policy.hub_base_policy_path=<user/base> (its weights hash is checked on every load)"
            )
        original = config.base_policy_path
        config.base_policy_path = config.hub_base_policy_path if local else original
        try:
            return super().push_model_to_hub(cfg, *args, **kwargs)
        finally:
            config.base_policy_path = original

    def to(self, *args, **kwargs):
        super().to(*args, **kwargs)
        self._base.to(*args, **kwargs)
        return self

    def generate_model_card(self, dataset_repo_id, model_type, license, tags, cfg=None, dataset_meta=None):
        """DCDP's own card (base reference and hash, measured numbers, eval command); built offline."""
        from lerobot_dcdp.model_card import make_model_card

        return make_model_card(
            self.config, state_dict_sha256(self.state_dict()), dataset_repo_id, license, tags
        )

    def get_optim_params(self) -> list[torch.nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    # ------------------------------------------------------------------ stage 1
    def _features(self, frames: Tensor) -> tuple[Tensor, Tensor]:
        """Frame tokens (B, T, d) -> per-step F (B, T-M+1, d) and last differentials (B, T-M+1, d)."""
        windows = sliding_windows(frames, self.config.n_history)  # (B, S, M, d)
        b, s = windows.shape[:2]
        f, d_last = self.extractor(windows.reshape(b * s, *windows.shape[2:]))
        return f.reshape(b, s, -1), d_last.reshape(b, s, -1)

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Stage-1 loss (``reconstruct``: paper; ``residual``: recorded corrections, see the config)."""
        if self.config.correction == "residual":
            return self._residual_loss(batch)
        return self._reconstruction_loss(batch)

    def _reconstruction_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Paper's stage 1 on a sample of observations t-M+1..t+H-1 and actions t..t+H-1."""
        cfg = self.config
        frames = self.frame_encoder({k: batch[k] for k in self._frame_keys})  # (B, M+H-1, d)
        feats, d_last = self._features(frames)  # (B, H, d)
        target = to_unit_range(batch[ACTION], self.action_low, self.action_high)
        mu, logvar = self.encoder(target)
        z = reparameterize(mu, logvar) if self.training else mu
        pred = self.decoder(z, feats)
        valid = (
            (~batch["action_is_pad"]).unsqueeze(-1).to(pred.dtype)
            if "action_is_pad" in batch
            else torch.ones_like(pred[..., :1])
        )
        recon = ((pred - target) ** 2 * valid).sum() / (valid.sum() * pred.shape[-1]).clamp_min(1.0)
        kl = kl_to_standard_normal(mu, logvar)
        loss = recon + cfg.kl_weight * kl
        l_diff = diff_loss(feats.flatten(0, 1), d_last.flatten(0, 1))
        if cfg.use_diff_loss:
            loss = loss + cfg.diff_weight * l_diff
        return loss, {
            "recon_loss": recon.item(),
            "kl_loss": kl.item(),
            "diff_loss": l_diff.item(),
            "alpha": float(self.extractor.alpha.detach()),
        }

    def _current_action(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """The action at t (B, A) of a residual sample (actions t-H+1 .. t+H-1), and whether it is real."""
        actions = batch[ACTION]
        actions = actions.unsqueeze(1) if actions.dim() == 2 else actions
        now = min(self.config.n_action_steps - 1, actions.shape[1] - 1)
        pad = batch.get("action_is_pad")
        valid = (
            ~pad.reshape(pad.shape[0], -1)[:, now] if pad is not None else torch.ones_like(actions[:, 0, 0])
        )
        return actions[:, now], valid.to(actions.dtype)

    def _plan_column(self, batch: dict[str, Tensor]) -> Tensor:
        """``plan_feature`` as chunks: (B, [K,] L, A) from a (L, A) column or a flat (L * A,) one."""
        plan, a = batch[self.config.plan_feature], self.config.action_feature.shape[0]
        if plan.dim() == 2 or (plan.dim() == 3 and plan.shape[-1] != a):  # flat, without / with time axis
            if plan.shape[-1] % a:
                raise ValueError(
                    f"{self.config.plan_feature} holds {plan.shape[-1]} values per frame, not a multiple of "
                    f"the action size {a}"
                )
            return plan.reshape(*plan.shape[:-1], -1, a)
        return plan

    def _recorded_plan(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """The recorded chunk (B, H, A), base-normalised, and each sample's step s (B,) in it."""
        cfg = self.config
        plan, step = self._plan_column(batch), batch[cfg.plan_step_feature]
        # the observation delta indices stack a time axis: the current frame is the last one (a (1,)-shaped
        # feature arrives as (B, K))
        plan = plan[:, -1] if plan.dim() == 4 else plan
        step = step.reshape(step.shape[0], -1)[:, -1]
        if plan.dim() != 3 or plan.shape[1] < cfg.n_action_steps:
            raise ValueError(
                f"{cfg.plan_feature} must hold (L >= n_action_steps={cfg.n_action_steps}, A) actions per "
                f"frame, got shape {tuple(plan.shape[1:])}"
            )
        step = step.round().long()
        if (step < 0).any() or (step >= cfg.n_action_steps).any():
            raise ValueError(f"{cfg.plan_step_feature} must lie in [0, {cfg.n_action_steps - 1}]")
        return self._norm(ACTION, plan[:, : cfg.n_action_steps]), step

    def _motion_max_speed(self) -> float:
        """``motion_max_speed``, or its default from the anchor keypoints' extent in the base's statistics."""
        cfg = self.config
        if cfg.motion_max_speed is not None:
            return cfg.motion_max_speed
        _, stats = self._base_stats.get(cfg.anchor_feature, ("IDENTITY", {}))
        if not stats:
            raise ValueError(
                f"the base's normaliser has no statistics for anchor_feature {cfg.anchor_feature!r}: set "
                "--policy.motion_max_speed (raw anchor units per control step) to synthesise object motion"
            )
        return 0.006 * keypoint_extent(stats)

    def _synthesised_sample(self, batch: dict[str, Tensor]) -> tuple[dict, Tensor, Tensor, Tensor, Tensor]:
        """A plain demonstration sample with synthesised object motion (motion_synthesis.py).

        Each sample is repeated ``motions_per_sample`` times; each copy gets a step s (plan time t-s, inside
        the episode), the demonstration's own chunk planned at t-s as the plan (or the base's chunk planned
        then, when ``plan_feature`` holds one per frame), its own rigid motion of the anchor keypoints
        through the window, and as the target the plan's action s carried with the object's motion since plan
        time (``motion_label``: the whole motion the moved keypoints show, or only the synthesised one).

        Returns:
            The moved batch, the plan (B', H, A) and step s (B',), the target (B', A) (all base-normalised)
            and its validity (B',).
        """
        cfg = self.config
        horizon, key = cfg.n_action_steps, cfg.anchor_feature
        if key not in cfg.corrector_features:
            raise ValueError(
                f"synthesising object motion moves {key!r}, which the corrector does not read: add it to "
                f"--policy.observation_features (now {cfg.corrector_features})"
            )
        images = [k for k in self._frame_keys if cfg.input_features[k].type is FeatureType.VISUAL]
        if images:
            raise ValueError(
                f"synthesised object motion moves only {key!r}, not the images {images}: train an image "
                "corrector on recorded corrections (dcdp-record-corrections) or read vector features only "
                "(--policy.observation_features)"
            )
        reps = cfg.motions_per_sample
        batch = {k: (v.repeat_interleave(reps, 0) if isinstance(v, Tensor) else v) for k, v in batch.items()}
        kp = self._norm(key, batch[key], inverse=True)
        if kp.dim() != 3:
            raise ValueError(
                "correction='residual' needs the observation history of the config's delta indices"
            )
        b, k = kp.shape[:2]
        actions = batch[ACTION]
        if actions.dim() != 3 or actions.shape[1] != 2 * horizon - 1:
            raise ValueError(
                f"synthesised corrections need actions t-{horizon - 1} .. t+{horizon - 1} per sample "
                f"(the residual config's action delta indices), got shape {tuple(actions.shape[1:])}"
            )
        # plan time t-s must lie inside the episode: s <= the number of real frames before t
        pad = batch.get(f"{key}_is_pad")
        history = (~pad).sum(1) - 1 if pad is not None else torch.full((b,), k - 1, device=kp.device)
        limit = torch.minimum(history.clamp_min(0), torch.full_like(history, min(horizon, k) - 1))
        step = (torch.rand(b, device=kp.device) * (limit + 1)).floor().long().clamp_max(limit)
        rows = torch.arange(b, device=kp.device)
        if cfg.plan_feature in batch:  # the base's chunk planned at each frame (dcdp-precompute-plans)
            per_frame = self._plan_column(batch)
            if per_frame.dim() != 4 or per_frame.shape[2] < horizon:
                raise ValueError(
                    f"{cfg.plan_feature} must hold the base's chunk (>= {horizon} actions) at every frame "
                    f"of the observation window, got shape {tuple(per_frame.shape[1:])}"
                )
            plan = self._norm(ACTION, per_frame[rows, k - 1 - step][:, :horizon])
        else:  # the demonstration's own chunk from t-s
            cols = (horizon - 1 - step).unsqueeze(1) + torch.arange(horizon, device=kp.device)
            plan = actions[rows.unsqueeze(1), cols]
        velocity, turn = draw_motions(
            b,
            self._motion_max_speed(),
            math.radians(cfg.motion_max_turn_deg),
            cfg.motion_static_fraction,
            device=kp.device,
        )
        moved, rot, shift = move_window(kp.reshape(b, k, -1, 2), k - 1 - step, velocity, turn)
        batch[key] = self._norm(key, moved.reshape(kp.shape))
        if cfg.motion_label == "observed":  # the whole motion the moved keypoints show since plan time
            rot, shift = rigid_fit_2d(moved[rows, k - 1 - step], moved[:, -1])
        plan_s = plan[rows, step]
        moving = (velocity != 0).any(-1) | (turn != 0)
        carried = self._norm(ACTION, anchor_actions(self._norm(ACTION, plan_s, inverse=True), rot, shift))
        target = torch.where(moving.unsqueeze(-1), carried, plan_s)  # a still scene keeps the plan exactly
        _, valid = self._current_action(batch)
        return batch, plan, step, target, valid

    def _residual_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """One control step t per sample: ``MSE(plan_s + delta, a_t) + lambda_KL KL + lambda_diff L_diff``.

        The frames are t-K+1 .. t (K = max(M, H)): the last M feed F_t, the one at t-s is the plan-time frame.
        The plan, step and target come from recorded corrections when the batch holds them, else from
        synthesised object motion on the demonstration (:meth:`_synthesised_sample`).
        """
        cfg = self.config
        if cfg.plan_feature in batch and cfg.plan_step_feature in batch:
            plan, step = self._recorded_plan(batch)
            target, valid = self._current_action(batch)
            source = "recorded"
        elif cfg.anchor_feature and cfg.anchor_feature in batch:
            batch, plan, step, target, valid = self._synthesised_sample(batch)
            source = "synthesised"
        else:
            raise ValueError(
                "correction='residual' trains on recorded corrections or on demonstrations with synthesised "
                f"object motion, but the batch has neither {cfg.plan_feature!r} + {cfg.plan_step_feature!r} "
                "(record them with dcdp-record-corrections) nor an anchor feature: name the object's xy "
                "keypoints with --policy.anchor_feature=<observation key> (or use "
                "--config_path=configs/policy/dcdp_paper.json, the paper's reconstruction recipe)"
            )
        frames, vec = self.frame_encoder.encode({k: batch[k] for k in self._frame_keys})  # (B, K, d)
        if frames.dim() != 3:
            raise ValueError(
                "correction='residual' needs the observation history of the config's delta indices"
            )
        feature, d_last = self.extractor(frames[:, -cfg.n_history :])
        # what the head compares between plan time and now: the standardised vector inputs (tokens when the
        # corrector reads images only), (B, K, r)
        rep = frames if vec is None else vec
        k = rep.shape[1]
        idx = (k - 1 - step).clamp_min(0).view(-1, 1, 1).expand(-1, 1, rep.shape[-1])
        at_plan = rep.gather(1, idx)[:, 0]
        plan_unit = to_unit_range(plan, self.action_low, self.action_high)
        mu, logvar = self.encoder(plan_unit)
        z = reparameterize(mu, logvar) if self.training else mu
        rows = torch.arange(len(step), device=step.device)
        plan_s = plan_unit[rows, step]
        change = change_input(at_plan, rep[:, -1], cfg.change_scale)
        if cfg.anchor_input:
            key = cfg.anchor_feature
            kp = self._norm(key, batch[key], inverse=True)
            kp = kp.reshape(*kp.shape[:2], -1, 2)
            rot, t = rigid_fit_2d(kp[rows, k - 1 - step], kp[:, -1])
            raw = self._norm(ACTION, plan[rows, step], inverse=True)
            proposal = to_unit_range(
                self._norm(ACTION, anchor_actions(raw, rot, t)), self.action_low, self.action_high
            )
            change = torch.cat([change, cfg.change_scale * (proposal - plan_s)], dim=-1)
        delta = self.residual(z, plan_s, feature, change, step)
        target = to_unit_range(target.reshape(plan_s.shape), self.action_low, self.action_high)
        extra = {"anchor_gap": ((proposal - target) ** 2).mean().item()} if cfg.anchor_input else {}
        valid = valid.unsqueeze(-1)
        denom = (valid.sum() * delta.shape[-1]).clamp_min(1.0)
        recon = (((plan_s + delta - target) ** 2) * valid).sum() / denom
        kl = kl_to_standard_normal(mu, logvar)
        l_diff = diff_loss(feature, d_last)
        loss = recon + cfg.kl_weight * kl + (cfg.diff_weight * l_diff if cfg.use_diff_loss else 0.0)
        return loss, {
            "recon_loss": recon.item(),
            "plan_gap": ((((plan_s - target) ** 2) * valid).sum() / denom).item(),
            "kl_loss": kl.item(),
            "diff_loss": l_diff.item(),
            "synthesised": float(source == "synthesised"),
            **extra,
        }

    # ------------------------------------------------------------------ stage 2
    def reset(self) -> None:
        """Clear the history bank and the chunk state, and reset the base (call on env reset)."""
        self.source.reset()
        self._bank: Tensor | None = None  # (B, M, d) cached frame tokens
        self._rep: Tensor | None = None  # newest change representation (residual)
        self._step = 0
        self._chunk: Tensor | None = None
        self._plan: Tensor | None = None
        self._z: Tensor | None = None
        self._h: Tensor | None = None
        self._at_plan: Tensor | None = None  # residual: change representation at plan time
        self._terms: Tensor | None = None  # residual: the head's per-chunk part (ResidualHead.chunk_terms)
        self._w_step: Tensor | None = None
        self._anchor_plan: Tensor | None = None  # raw anchor keypoints at plan time
        self._t = 0  # control steps since reset
        self._past: deque[dict] = deque(maxlen=self.config.inference_delay + 1)  # steps t-d .. t
        self.last_step: int | None = None
        if getattr(self, "_planner", None) is not None:
            self._planner.cancel()
        self._tick_at: float | None = None  # planning='async', wall clock: last tick's time
        self._tick_s: float | None = None  # smoothed tick period (s)
        self._plan_s: float | None = None  # smoothed planning time of the base (s)

    def _check_batch(self, batch: dict[str, Tensor]) -> None:
        missing = [k for k in self._needed_keys if k not in batch]
        if self.config.execution == "object_anchored" or self.config.anchor_input:
            anchor = self.config.anchor_feature
            if not anchor:
                raise ValueError(
                    "execution='object_anchored' needs anchor_feature (the object's xy keypoints)"
                )
            missing += [anchor] if anchor not in batch else []
        if missing:
            raise ValueError(f"observation is missing {missing}; it has {sorted(batch)}")
        planned = None if self._chunk is None else self._chunk.shape[0]
        mid_chunk = planned is not None and (self._step != 0 or self.config.planning == "async")
        for key, shape in self._expected_shapes.items():
            x = batch[key]
            if shape is not None and tuple(x.shape[1:]) != shape:
                raise ValueError(
                    f"observation {key!r} has shape {tuple(x.shape)}, expected (batch, "
                    f"{', '.join(map(str, shape))}) as the corrector and its base were trained"
                )
            if mid_chunk and x.shape[0] != planned:
                width = ", ".join(map(str, x.shape[1:]))
                raise ValueError(
                    f"observation {key!r} has batch {x.shape[0]} but the current chunk was planned for "
                    f"batch {planned}: expected (batch, features) = ({planned}, {width}) as in this chunk "
                    "(call reset() between episodes)"
                )
            if x.is_floating_point() and not torch.isfinite(x).all():
                raise ValueError(
                    f"observation {key!r} holds a non-finite value (NaN or inf); the corrector would carry "
                    f"it in its history for {self.config.n_history} steps -- fix the sensor or filter the "
                    "observation"
                )

    def _push_frame(self, batch: dict[str, Tensor]) -> None:
        token, vec = self.frame_encoder.encode({k: batch[k] for k in self._frame_keys})  # one new frame
        if self._bank is None or self._bank.shape[0] != token.shape[0]:
            self._bank = token.unsqueeze(1).repeat(1, self.config.n_history, 1)
        else:
            self._bank = torch.cat([self._bank[:, 1:], token.unsqueeze(1)], dim=1)
        if self.config.correction == "residual":
            self._rep = token if vec is None else vec

    def _anchor_points(self, batch: dict[str, Tensor]) -> Tensor:
        """Raw (un-normalised) anchor keypoints (B, N, 2) of the current observation."""
        key = self.config.anchor_feature
        x = self._norm(key, batch[key], inverse=True)
        return x.reshape(x.shape[0], -1, 2)

    def _anchored(self, plan_s: Tensor, batch: dict[str, Tensor]) -> Tensor:
        """``object_anchored``: the planned action carried along with the object's rigid motion since the
        chunk was planned, estimated from the anchor keypoints (least squares)."""
        rot, t = rigid_fit_2d(self._anchor_plan, self._anchor_points(batch))
        raw = self._norm(ACTION, plan_s, inverse=True)
        return self._norm(ACTION, anchor_actions(raw, rot, t))

    @property
    def planned_chunk(self) -> Tensor | None:
        """The chunk being executed (B, H, A), base-normalised, as the base planned it (open loop, DCDP and
        object_anchored; ``last_step`` is the index of the action last returned)."""
        return self._chunk

    def encode_chunk(self, chunk: Tensor) -> Tensor:
        """Normalise a base chunk (B, H, A) to [-1, 1] and encode it to z = mu."""
        return self.encoder(to_unit_range(chunk, self.action_low, self.action_high))[0]

    def decode_step(self, feature: Tensor, step: int) -> Tensor:
        """Action of chunk step ``step`` from the current z, F and decoder state (base-normalised)."""
        a, self._h = self.decoder.step(self._z, feature, step, self._h)
        return from_unit_range(a, self.action_low, self.action_high)

    def residual_step(self, feature: Tensor, step: int, batch: dict[str, Tensor]) -> Tensor:
        """``plan_s + delta`` (base-normalised); delta == 0 returns the planned action bit for bit."""
        plan_s = self._chunk[:, step]
        if self._terms is not None:  # per-chunk terms summed at plan time (chunk_terms)
            change = self.config.change_scale * (self._rep - self._at_plan)
            delta = self.residual.step(self._terms[:, step], feature, change, self._w_step)
            return plan_s + delta * self.action_half_range
        s = torch.full((plan_s.shape[0],), step, dtype=torch.long, device=plan_s.device)
        change = change_input(self._at_plan, self._rep, self.config.change_scale)
        plan_unit = to_unit_range(plan_s, self.action_low, self.action_high)
        if self.config.anchor_input:
            proposal = to_unit_range(self._anchored(plan_s, batch), self.action_low, self.action_high)
            change = torch.cat([change, self.config.change_scale * (proposal - plan_unit)], dim=-1)
        delta = self.residual(self._z, plan_unit, feature, change, s)
        return plan_s + delta * self.action_half_range

    def _remember(self, prepared: dict[str, Tensor], batch: dict[str, Tensor]) -> None:
        """Keep what a base answering ``inference_delay`` steps late planned from, step by step."""
        anchored = self.config.execution == "object_anchored" or self.config.anchor_input
        self._past.append(
            {
                "t": self._t,
                "prepared": prepared,
                "queues": self.source.snapshot(),
                "rep": self._rep,
                "anchor": self._anchor_points(batch) if anchored else None,
            }
        )

    def _plan_chunk(
        self, prepared: dict[str, Tensor], batch: dict[str, Tensor], length: int | None
    ) -> Tensor:
        """The chunk that starts being used now; sets the plan-time references (rep, anchor keypoints).

        With ``inference_delay`` d it was planned from step max(t-d, 0) and the entries for the steps past
        since then are skipped."""
        cfg = self.config
        anchored = cfg.execution == "object_anchored" or (cfg.execution == "dcdp" and cfg.anchor_input)
        if not cfg.inference_delay:
            self._at_plan = self._rep
            self._anchor_plan = self._anchor_points(batch) if anchored else None
            return self.source.chunk(prepared, length)
        then = self._past[0]
        skip = self._t - then["t"]
        length = min((length or self.source.chunk_length) + skip, self.source.max_length)
        self._at_plan, self._anchor_plan = then["rep"], then["anchor"]
        return self.source.chunk_from(then["prepared"], then["queues"], length)[:, skip:]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor]) -> Tensor:
        """One action (B, A) per environment for the current step (normalised; the post-processor maps it)."""
        self._check_batch(batch)
        cfg = self.config
        if cfg.planning == "async":
            return self._select_async(batch)
        mode, horizon = cfg.execution, cfg.n_action_steps
        prepared = self.source.observe(batch)
        if mode == "dcdp" and self._step != 0 and self._step_graph is not None:
            return self._kernel_step(batch)
        # A planning step that will run on the compiled kernel leaves the frame to it (it pushes the frame
        # after the plan); the plan only needs the frame's standardised vector as its plan-time reference.
        defer = (
            mode == "dcdp"
            and self._step == 0
            and self._bank is not None
            and self._bank.shape[0] == batch[self._frame_keys[0]].shape[0]
            and self._kernel_applies()
        )
        if defer:
            self._rep = self.frame_encoder.vector({k: batch[k] for k in self._frame_keys})
        elif mode == "dcdp":
            self._push_frame(batch)
        if cfg.inference_delay:
            self._remember(prepared, batch)
        replan = mode in ("closed_loop", "temporal_ensemble") or self._step == 0
        if replan:
            if mode == "temporal_ensemble":
                chunk = self._plan_chunk(prepared, batch, None)
                self._plan = temporal_ensemble_step(self._plan, chunk, cfg.te_weight)
            elif mode == "closed_loop":
                self._plan = self._plan_chunk(prepared, batch, 1)
            else:
                self._chunk = self._plan_chunk(prepared, batch, horizon)
                if mode == "dcdp":
                    self._z = self.encode_chunk(self._chunk)
                    if cfg.correction != "residual":
                        self._h = self.decoder.initial_state(self._z)
                    elif self.fast_inference and not cfg.anchor_input:
                        unit = to_unit_range(self._chunk, self.action_low, self.action_high)
                        self._terms, self._w_step = self.residual.chunk_terms(self._z, unit, self._at_plan)
                        self._prepare_kernel()
                        if defer and self._step_graph is not None:
                            return self._kernel_step(batch)
                        if defer:
                            self._push_frame(batch)
                    else:
                        self._terms = None
        self._t += 1
        if mode in ("closed_loop", "temporal_ensemble"):
            self.last_step = 0
            return self._plan[:, 0]
        step = self._step
        self.last_step = step
        self._step = (self._step + 1) % horizon
        if mode == "open_loop":
            return self._chunk[:, step]
        if mode == "object_anchored":
            return self._anchored(self._chunk[:, step], batch)
        feature, _ = self.extractor(self._bank)
        if cfg.correction == "residual":
            return self.residual_step(feature, step, batch)
        return self.decode_step(feature, step)

    # ------------------------------------------------------------ asynchronous planning (planner.py)
    def _select_async(self, batch: dict[str, Tensor]) -> Tensor:
        """``planning='async'``: the action of the chunk being executed, at once; the next chunk is planned on
        the worker thread (see ``DCDPConfig.planning``)."""
        cfg = self.config
        mode, horizon = cfg.execution, cfg.n_action_steps
        if mode not in CHUNK_MODES:
            raise ValueError(f"planning='async' applies to the chunk modes {CHUNK_MODES}, not {mode!r}")
        now = time.perf_counter()
        if self._tick_at is not None:
            self._tick_s = _smoothed(self._tick_s, now - self._tick_at)
        self._tick_at = now
        prepared = self.source.observe(batch)
        planner = self._planner
        pending = planner is not None and planner.pending
        quiet = (  # neither submits nor switches a chunk: the compiled kernel does the whole step
            self._chunk is not None
            and not (not pending and self._step >= horizon - self._planning_lead())
            and not (pending and self._step >= horizon)
        )
        if mode == "dcdp" and quiet and self._kernel is not None and self._terms is not None:
            step = min(self._step, horizon - 1)
            self.last_step = step
            self._step += 1
            self._t += 1
            return self._kernel_action(
                torch.cat([batch[k] for k in self.frame_encoder.state_keys], dim=-1), step
            )
        if mode == "dcdp":
            self._push_frame(batch)
        anchored = mode == "object_anchored" or (mode == "dcdp" and cfg.anchor_input)
        context = (self._rep, self._anchor_points(batch) if anchored else None)
        t = self._t
        if self._chunk is None:  # an episode's first chunk: nothing to execute yet, planned on this tick
            started = time.perf_counter()
            chunk = self.source.chunk(prepared, horizon)
            self._plan_s = _smoothed(self._plan_s, time.perf_counter() - started)
            self._use_chunk(chunk, context)
        else:
            if self._planner is None:
                self._planner = BackgroundPlanner(self.source)
            planner = self._planner
            if not planner.pending and self._step >= horizon - self._planning_lead():
                planner.submit(t, prepared, self.source.snapshot(), self.source.max_length, context)
            if planner.pending and self._step >= horizon:
                if cfg.planning_clock == "steps":
                    due = t - planner.t_obs >= cfg.inference_delay
                    job = planner.take(wait=True) if due else None
                else:
                    job = planner.take(wait=False)
                if job is not None:
                    self._plan_s = _smoothed(self._plan_s, job.seconds)
                    age = t - job.t_obs
                    self._use_chunk(job.chunk[:, age : age + horizon], job.context)
        step = min(self._step, self._chunk.shape[1] - 1)  # a chunk kept past its end holds its last step
        self.last_step = step
        self._step += 1
        self._t += 1
        if mode == "open_loop":
            return self._chunk[:, step]
        if mode == "object_anchored":
            return self._anchored(self._chunk[:, step], batch)
        feature, _ = self.extractor(self._bank)
        if cfg.correction == "residual":
            return self.residual_step(feature, step, batch)
        return self.decode_step(feature, step)

    def _planning_lead(self) -> int:
        """Ticks before the chunk's end at which the next one is planned (``DCDPConfig.planning_clock``)."""
        cfg = self.config
        if cfg.planning_clock == "steps":
            return cfg.inference_delay
        if not self._plan_s or not self._tick_s:
            return 1
        return min(cfg.n_action_steps, math.ceil(self._plan_s / self._tick_s) + 1)

    def _use_chunk(self, chunk: Tensor, context: tuple[Tensor | None, Tensor | None]) -> None:
        """Start executing ``chunk`` (B, <= H, A; a short one is padded with its last action) planned from
        the observation whose change representation and anchor keypoints ``context`` holds."""
        cfg = self.config
        horizon = cfg.n_action_steps
        if chunk.shape[1] < horizon:
            chunk = torch.cat([chunk, chunk[:, -1:].expand(-1, horizon - chunk.shape[1], -1)], dim=1)
        self._at_plan, self._anchor_plan = context
        self._chunk, self._step = chunk, 0
        self._terms = None
        if cfg.execution != "dcdp":
            return
        self._z = self.encode_chunk(chunk)
        if cfg.correction != "residual":
            self._h = self.decoder.initial_state(self._z)
        elif self.fast_inference and not cfg.anchor_input:
            unit = to_unit_range(chunk, self.action_low, self.action_high)
            self._terms, self._w_step = self.residual.chunk_terms(self._z, unit, self._at_plan)
            self._prepare_kernel()

    def close(self) -> None:
        """Stop the asynchronous planner's worker thread (``planning='async'``); the policy stays usable."""
        if self._planner is not None:
            self._planner.close()
            self._planner = None

    # ------------------------------------------------------------ compiled per-step path (step_kernel.py)
    @property
    def _step_graph(self):
        """The compiled per-step path's weights for the current chunk, or None (eager path)."""
        return self._kernel if self._terms is not None else None

    def _kernel_applies(self) -> bool:
        """Whether the compiled per-step kernel covers this corrector as it runs now: a residual head without
        anchor input or a synchronous inference delay, vector frames, float32 on CPU, eval mode,
        ``fast_inference`` (with ``planning='async'``: the ticks that neither submit nor switch a chunk)."""
        cfg = self.config
        weight = self.residual.net[0].weight if cfg.correction == "residual" else None
        if not (
            weight is not None
            and self.fast_inference
            and cfg.compiled_kernel != "off"
            and not self.training
            and not (cfg.anchor_input or (cfg.inference_delay and cfg.planning == "sync"))
            and weight.device.type == "cpu"
            and weight.dtype == torch.float32
        ):
            return False
        if self._kernel_supported is None:
            try:
                from lerobot_dcdp import step_kernel
            except Exception as err:  # numba missing, or it cannot set up its cache
                self._kernel_failed(err)
                return False
            self._kernel_supported = step_kernel.supports(self.frame_encoder, self.extractor)
        return self._kernel_supported

    def _kernel_weights(self):
        """The kernel's packed weights, re-packed (and the kernel loaded) when the module weights changed."""
        from lerobot_dcdp import step_kernel

        # a tensor's storage and version change with optimiser steps, load_state_dict (copy or assign) and
        # `param.data = ...`; writes through `param.data` change neither, so each tensor's sum is compared too
        # (~0.05 ms per chunk)
        tensors = (*self.parameters(), *self.buffers())
        versions = (
            self.config.change_scale,
            *((t.data_ptr(), t._version) for t in tensors),
            torch.stack([t.detach().double().sum() for t in tensors]).tolist(),
        )
        if self._packed is None or self._packed[0] != versions:
            packed = step_kernel.pack_weights(
                self.frame_encoder, self.extractor, self.residual, self.config.change_scale
            )
            first = not step_kernel.loaded()
            started = time.perf_counter()
            step_kernel.warm_up(packed)  # the first call in a process loads the kernel: not on a control step
            if first:
                logging.getLogger(__name__).info(
                    "dcdp: compiled per-step kernel ready in %.1f s (cache: %s)",
                    time.perf_counter() - started,
                    step_kernel.cache_dir(),
                )
            self._packed = (versions, packed)
        self._run_kernel = step_kernel.residual_step  # numba is imported only once a kernel is used
        return self._packed[1]

    def _prepare_kernel(self) -> None:
        """Run this chunk's steps on the compiled kernel when it applies (after ``chunk_terms``)."""
        self._kernel = None
        if self._rep is None or self._bank is None or not self._kernel_applies():
            return
        try:
            self._kernel = self._kernel_weights()
        except Exception as err:  # compile or cache failure: this chunk and later ones run eagerly
            self._kernel_failed(err)
            return
        self._w_step_np = self._w_step.T.contiguous().numpy()  # the kernel's (out, in) layout
        self._half_np = self.action_half_range.numpy()

    def _kernel_step(self, batch: dict[str, Tensor]) -> Tensor:
        x = torch.cat([batch[k] for k in self.frame_encoder.state_keys], dim=-1)
        expected = (self._bank.shape[0], self._kernel.shift.shape[0])
        if tuple(x.shape) != expected:  # the kernel does not bounds-check: refuse before it runs
            raise ValueError(
                f"observation vector inputs {self.frame_encoder.state_keys} have shape {tuple(x.shape)}, "
                f"expected (batch, features) = {expected} as in this chunk (call reset() between episodes)"
            )
        step = self._step
        self.last_step = step
        self._step = (self._step + 1) % self.config.n_action_steps
        self._t += 1
        return self._kernel_action(x, step)

    def _kernel_action(self, x: Tensor, step: int) -> Tensor:
        """Chunk step ``step`` on the compiled kernel from the frame vector ``x``; updates bank and rep."""
        action, self._bank, self._rep = self._run_kernel(
            self._kernel,
            x,
            self._bank,
            self._at_plan,
            self._terms[:, step],
            self._w_step_np,
            self._chunk[:, step],
            self._half_np,
        )
        return action

    _STATE = (
        "_bank",
        "_rep",
        "_step",
        "_chunk",
        "_plan",
        "_z",
        "_h",
        "_at_plan",
        "_terms",
        "_w_step",
        "_anchor_plan",
        "_t",
        "_past",
        "last_step",
    )

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor]) -> Tensor:
        """The corrected chunk (B, H, A) the policy would start from ``batch`` as its next observation,
        every step decoded with the current F (no later observation exists yet: for ``residual`` nothing has
        changed since plan time, so this is the base's chunk plus the corrections a still world gets).

        A query: the policy's state (history bank, current chunk and step, the base's observation queues)
        is the same afterwards, so calling it between ``select_action`` calls changes none of their actions.
        """
        self._check_batch(batch)
        cfg = self.config
        saved = {k: getattr(self, k) for k in self._STATE}
        queues = self.source.snapshot()
        try:
            prepared = self.source.observe(batch)
            self._push_frame(batch)
            chunk = self.source.chunk(prepared)[:, : cfg.n_action_steps]
            z = self.encode_chunk(chunk)
            feature, _ = self.extractor(self._bank)
            if cfg.correction == "residual":
                unit = to_unit_range(chunk, self.action_low, self.action_high)
                change = change_input(self._rep, self._rep, cfg.change_scale)
                if cfg.anchor_input:  # a still object: the anchored proposal is the plan itself
                    change = torch.cat([change, torch.zeros_like(unit[:, 0])], dim=-1)
                out = []
                for s in range(cfg.n_action_steps):
                    steps = torch.full((chunk.shape[0],), s, dtype=torch.long, device=chunk.device)
                    delta = self.residual(z, unit[:, s], feature, change, steps)
                    out.append(chunk[:, s] + delta * self.action_half_range)
                return torch.stack(out, dim=1)
            feats = feature.unsqueeze(1).expand(-1, cfg.n_action_steps, -1)
            return from_unit_range(self.decoder(z, feats), self.action_low, self.action_high)
        finally:
            for k, v in saved.items():
                setattr(self, k, v)
            self.source.restore(queues)


def _smoothed(previous: float | None, value: float, weight: float = 0.3) -> float:
    """Exponential moving average (the first value as is)."""
    return value if previous is None else (1 - weight) * previous + weight * value


__all__ = ["DCDPPolicy", "BaseMismatchError"]
