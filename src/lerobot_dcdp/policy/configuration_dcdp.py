"""Configuration of the DCDP corrector ("Closed-Loop Action Chunks with Dynamic Corrections")."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.optim import AdamWConfig, DiffuserSchedulerConfig

from lerobot_dcdp.policy.config_checks import (  # the choice tuples stay importable from here
    CHECKS,
    CORRECTIONS,
    EXECUTION_MODES,
)
from lerobot_dcdp.policy.config_options import (
    OPTION_GROUPS,
)

__all__ = ["CORRECTIONS", "EXECUTION_MODES", "DCDPConfig"]


@PreTrainedConfig.register_subclass("dcdp")
@dataclass
class DCDPConfig(PreTrainedConfig, *OPTION_GROUPS):
    """Configuration of a DCDP corrector wrapped around a frozen chunking base policy.

    The base policy (Diffusion Policy, ACT, VQ-BeT, ...) plans a chunk every ``n_action_steps`` control steps;
    the corrector (dynamic feature extractor + chunk encoder, paper Sec. 3) adjusts every action of the chunk
    at every step from the latest ``n_history`` observations: by default a residual head adds a learned
    correction to the planned action (``correction='residual'``); the paper's GRU decoder re-decodes it
    (``correction='reconstruct'``).

    The options are grouped by concern in :mod:`lerobot_dcdp.policy.config_options`, one dataclass each, which
    this class inherits (the flags stay flat: ``--policy.planning``, ``--policy.motion_label``, ...):
    ``ExecutionOptions`` (the base, the chunk, the execution mode), ``PlanningOptions`` (synchronous or
    asynchronous planning, local or remote base, control rate), ``CorrectionOptions`` (the correction recipe,
    anchor keypoints, compiled path, completion gate), ``SynthesisOptions`` (stage 1 on plain demonstrations),
    ``NetworkOptions`` (the corrector's networks and loss weights) and ``BidOptions`` (the BID peer). Each is
    validated by the pure check of the same concern in :mod:`lerobot_dcdp.policy.config_checks`. Their
    ``Args:`` follow this docstring in ``lerobot-train --policy.type=dcdp --help``.

    Args:
        optimizer_lr: AdamW learning rate (the residual recipe's 1e-3; authors and the paper preset: 1e-4).
        optimizer_betas: AdamW betas.
        optimizer_weight_decay: AdamW weight decay (authors: 1e-4).
        optimizer_grad_clip_norm: Gradient clipping (authors: 1.0).
        scheduler_name: Name of the diffusers learning-rate schedule (``cosine``: warm-up, then cosine decay).
        scheduler_warmup_steps: Warm-up of the cosine schedule.
        normalization_mapping: Normalisation mode per feature type; overwritten with the base's mapping when
            the policy is built (wrapper and base share one normaliser, the base's).
        n_obs_steps: LeRobot's observation-history length; not read by DCDP (its history is ``n_history``;
            the base keeps its own ``n_obs_steps``).
        input_features: The observation features, filled in by LeRobot from the dataset (``lerobot-train``);
            the recorded plan keys (``plan_feature`` ...) are dropped from them when the policy is built.
        output_features: The action feature, filled in by LeRobot from the dataset.
        device: Where the corrector and its base run (``cpu``, ``cuda``, ``cuda:0``, ``mps``); unset or
            unavailable: LeRobot picks an available device.
        use_amp: LeRobot's automatic mixed precision in training and evaluation (turned off on a device
            without it).
        use_peft: LeRobot's PEFT switch: whether the policy was fine-tuned with PEFT adapters.
        push_to_hub: Push the trained corrector and its processors to the Hub at the end of ``lerobot-train``
            (needs ``repo_id``, and ``hub_base_policy_path`` when the base is a local folder).
        repo_id: Hub repo id the trained corrector is pushed to.
        private: Push to a private Hub repo.
        tags: Tags of the pushed corrector on the Hub.
        license: License of the pushed corrector on the Hub.
        pretrained_path: Set by LeRobot to the folder or Hub id the policy is loaded from (``--policy.path``);
            a relative ``base_policy_path`` is looked up beside it first.
        pretrained_revision: Hub revision (commit, branch or tag) of ``--policy.path``.
    """

    optimizer_lr: float = 1e-3
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_weight_decay: float = 1e-4
    optimizer_grad_clip_norm: float = 1.0
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 0

    # Overwritten with the base's mapping when the policy is built: wrapper and base share one normaliser.
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.MEAN_STD,
            "STATE": NormalizationMode.MIN_MAX,
            "ENV": NormalizationMode.MIN_MAX,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        # one pure check per option group (config_checks.py); each takes the options it reads by name
        for check in CHECKS:
            check(**self._options_of(check))

    def _options_of(self, check: Callable[..., None]) -> dict:
        """This config's values of the options ``check`` reads (its parameters are named as the options)."""
        return {name: getattr(self, name) for name in inspect.signature(check).parameters}

    # ------------------------------------------------------------------ what a training sample holds
    @property
    def observation_delta_indices(self) -> list[int]:
        """``reconstruct``: observations t-M+1 .. t+H-1 (decoder step s sees the window ending at t+s:
        train as you infer). ``residual``: a sample is one control step t; observations t-K+1 .. t with
        K = max(M, H + train_max_delay) hold the history window and the frame the plan was made from,
        t-s-d (step s < H, delay d <= train_max_delay)."""
        if self.correction == "residual":
            return list(range(1 - max(self.n_history, self.n_action_steps + self.train_max_delay), 1))
        return list(range(1 - self.n_history, self.n_action_steps))

    @property
    def action_delta_indices(self) -> list[int]:
        """``reconstruct``: actions t .. t+H-1 (the executed part of a chunk); ``residual``: actions
        t-H+1 .. t+H-1 (the target is the one at t; on plain demonstrations, the demonstration's own chunk
        planned at t-s is the plan, for any step s < H)."""
        if self.correction == "residual":
            return list(range(1 - self.n_action_steps, self.n_action_steps))
        return list(range(self.n_action_steps))

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name=self.scheduler_name, num_warmup_steps=self.scheduler_warmup_steps)

    # ------------------------------------------------------------------ features
    @property
    def plan_columns(self) -> tuple[str, str, str]:
        """Dataset keys of recorded corrections' plan context (plan, step, delay): training targets'
        context, never corrector inputs."""
        return (self.plan_feature, self.plan_step_feature, self.plan_delay_feature)

    @property
    def corrector_features(self) -> list[str]:
        """Observation keys the corrector reads: ``observation_features``, or every observation input (the
        cameras excepted when a keypoint reader gives their estimate)."""
        if self.observation_features:
            return list(self.observation_features)
        skip = self.plan_columns
        cameras_too = not self.keypoint_reader_path  # with a reader, the camera reaches it as keypoints
        return [
            k
            for k, ft in (self.input_features or {}).items()
            if ft.type is not FeatureType.ACTION
            and k not in skip
            and (cameras_too or ft.type is not FeatureType.VISUAL)
        ]

    def with_encoded_cameras(self, base_features: dict) -> dict:
        """``input_features`` plus each base camera a dataset holds only as the base encoder's features
        (``dcdp-precompute-base-features --drop-cameras``): declared as the base declares it, since the
        trained folder reads the camera at run time.

        Args:
            base_features: The base's input features (``{key: PolicyFeature}``).
        """
        from lerobot_dcdp.model.dynamics import BASE_ENCODED_SUFFIX

        feats = dict(self.input_features or {})
        for key, ft in base_features.items():
            if ft.type is FeatureType.VISUAL and key not in feats and key + BASE_ENCODED_SUFFIX in feats:
                feats[key] = ft
        return feats

    def used_inputs(self, base_features: dict) -> dict:
        """``input_features`` less what nothing reads: the keys the base, the corrector
        (:attr:`corrector_features`) and the anchoring (``anchor_feature``) read. A dataset's other columns
        (the recorded plan's context; keypoints that a keypoint reader's estimate stands in for) are then
        neither checked nor asked of the env or robot at run time.

        Args:
            base_features: The base's input features (``{key: PolicyFeature}``).
        """
        used = {*base_features, *self.corrector_features, self.anchor_feature} - set(self.plan_columns)
        return {k: v for k, v in (self.input_features or {}).items() if k in used}

    @property
    def resolved_backbone(self) -> str:
        if self.backbone != "auto":
            return self.backbone
        feats = self.input_features or {}
        return (
            "resnet18"
            if any(feats[k].type is FeatureType.VISUAL for k in self.corrector_features if k in feats)
            else "mlp"
        )

    def validate_features(self) -> None:
        feats = self.input_features or {}
        if self.action_feature is None:
            raise ValueError("output_features must contain 'action' (the base's action)")
        missing = [k for k in self.corrector_features if k not in feats]
        if missing:
            raise ValueError(
                f"observation_features {missing} are not among the input features {sorted(feats)}"
            )
        if not self.corrector_features:
            raise ValueError("the corrector needs at least one observation feature (input_features is empty)")
        if self.resolved_backbone == "mlp" and not any(
            feats[k].type in (FeatureType.STATE, FeatureType.ENV) for k in self.corrector_features
        ):
            raise ValueError("backbone='mlp' needs a state or environment_state observation feature")
        if self.anchor_feature:
            if self.anchor_feature not in feats:
                raise ValueError(
                    f"anchor_feature {self.anchor_feature!r} is not among the input features {sorted(feats)}"
                )
            shape = tuple(feats[self.anchor_feature].shape)
            if len(shape) != 1 or shape[0] < 4 or shape[0] % 2:
                raise ValueError(
                    f"anchor_feature {self.anchor_feature!r} must hold >= 2 xy keypoints as a flat vector "
                    f"(x0, y0, x1, y1, ...), got shape {shape}"
                )
            if self.action_feature.shape[0] < 2:
                raise ValueError("anchor_feature needs actions whose first two dims are xy")
        if self.resolved_backbone in ("resnet18", "base_encoder") and not any(
            feats[k].type is FeatureType.VISUAL for k in self.corrector_features
        ):
            raise ValueError(f"backbone={self.resolved_backbone!r} needs an image observation feature")


# ``lerobot-train --help`` prints this class's docstring: each option group's follows it, so every option is
# described there
DCDPConfig.__doc__ += "".join(f"\n    {group.__name__}: {group.__doc__}" for group in OPTION_GROUPS)
