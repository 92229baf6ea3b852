"""Stage-1 samples of the residual corrector: a plan, the step s in it, and the action to take at s.

Either recorded corrections (``dcdp-record-corrections``: the plan and step stored per frame, the target the
recorded action) or a plain demonstration with synthesised object motion (``motion_synthesis.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from lerobot.configs.types import FeatureType
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_dcdp.model.base_normalizer import BaseNormalizer
from lerobot_dcdp.model.correction import anchor_actions, rigid_fit_2d
from lerobot_dcdp.model.motion_synthesis import draw_motions, keypoint_extent, move_window, push_share

if TYPE_CHECKING:  # the config lives in the policy layer, above this one
    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig


@dataclass
class CorrectionSample:
    """A batch of residual training samples (everything base-normalised).

    Attributes:
        batch: The observations (moved, for synthesised samples).
        plan: (B, H, A) the chunk being executed.
        step: (B,) the step s of each sample in its chunk.
        age: (B,) steps from the observation the chunk was planned from to t: s, plus the delay d of a late
            chunk (its plan-time frame is t-s-d).
        target: (B, A) the action to take at t.
        valid: (B,) 1 where the target is a real (not padded) action.
        synthesised: Whether the motion was synthesised (else recorded).
    """

    batch: dict[str, Tensor]
    plan: Tensor
    step: Tensor
    age: Tensor
    target: Tensor
    valid: Tensor
    synthesised: bool


class CorrectionSamples:
    """Turns a training batch into a :class:`CorrectionSample` (see the module docstring).

    Args:
        config: The policy config (plan/step feature names, anchor feature, motion ranges).
        normalizer: The base's normaliser (plans are stored raw; motion is synthesised in raw units).
        frame_keys: The observation keys the corrector reads.
    """

    def __init__(self, config: DCDPConfig, normalizer: BaseNormalizer, frame_keys: list[str]) -> None:
        self.config = config
        self.norm = normalizer
        self.frame_keys = frame_keys

    def __call__(self, batch: dict[str, Tensor]) -> CorrectionSample:
        cfg = self.config
        if cfg.plan_feature in batch and cfg.plan_step_feature in batch:
            plan, step = self.recorded_plan(batch)
            target, valid = self.current_action(batch)
            age = step + self.recorded_delay(batch)
            return CorrectionSample(batch, plan, step, age, target, valid, synthesised=False)
        if cfg.anchor_feature and cfg.anchor_feature in batch:
            return self.synthesised(batch)
        raise ValueError(
            "correction='residual' trains on recorded corrections or on demonstrations with synthesised "
            f"object motion, but the batch has neither {cfg.plan_feature!r} + {cfg.plan_step_feature!r} "
            "(record them with dcdp-record-corrections) nor an anchor feature: name the object's xy "
            "keypoints with --policy.anchor_feature=<observation key> (or use "
            "--config_path=configs/policy/dcdp_paper.json, the paper's reconstruction recipe)"
        )

    def current_action(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """The action at t (B, A) of a sample (actions t-H+1 .. t+H-1), and whether it is real."""
        actions = batch[ACTION]
        actions = actions.unsqueeze(1) if actions.dim() == 2 else actions
        now = min(self.config.n_action_steps - 1, actions.shape[1] - 1)
        pad = batch.get("action_is_pad")
        valid = (
            ~pad.reshape(pad.shape[0], -1)[:, now] if pad is not None else torch.ones_like(actions[:, 0, 0])
        )
        return actions[:, now], valid.to(actions.dtype)

    def plan_column(self, batch: dict[str, Tensor]) -> Tensor:
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

    def recorded_plan(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """The recorded chunk (B, H, A), base-normalised, and each sample's step s (B,) in it."""
        cfg = self.config
        plan, step = self.plan_column(batch), batch[cfg.plan_step_feature]
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
        return self.norm(ACTION, plan[:, : cfg.n_action_steps]), step

    def recorded_delay(self, batch: dict[str, Tensor]) -> Tensor:
        """Each recorded sample's chunk delay d (B,): ``plan_delay_feature``, 0 where the dataset has none."""
        cfg = self.config
        step = batch[cfg.plan_step_feature]
        if cfg.plan_delay_feature not in batch:
            return torch.zeros(step.shape[0], dtype=torch.long, device=step.device)
        delay = batch[cfg.plan_delay_feature]
        delay = delay.reshape(delay.shape[0], -1)[:, -1].round().long()
        if (delay < 0).any() or (delay > cfg.train_max_delay).any():
            raise ValueError(
                f"{cfg.plan_delay_feature} holds delays up to {int(delay.max())} steps, outside [0, "
                f"train_max_delay={cfg.train_max_delay}]: train with --policy.train_max_delay >= the "
                "recording's --max-delay"
            )
        return delay

    def motion_max_speed(self) -> float:
        """``motion_max_speed``, or its default from the anchor keypoints' extent in the base's statistics."""
        cfg = self.config
        if cfg.motion_max_speed is not None:
            return cfg.motion_max_speed
        _, stats = self.norm.stats.get(cfg.anchor_feature, ("IDENTITY", {}))
        if not stats:
            raise ValueError(
                f"the base's normaliser has no statistics for anchor_feature {cfg.anchor_feature!r}: set "
                "--policy.motion_max_speed (raw anchor units per control step) to synthesise object motion"
            )
        return 0.006 * keypoint_extent(stats)

    def motion_full_carry_at(self) -> float:
        """``motion_full_carry_at``, or its default: ``n_action_steps / 2`` steps of the largest speed."""
        cfg = self.config
        if cfg.motion_full_carry_at is not None:
            return cfg.motion_full_carry_at
        return 0.5 * cfg.n_action_steps * self.motion_max_speed()

    def synthesised(self, batch: dict[str, Tensor]) -> CorrectionSample:
        """A plain demonstration sample with synthesised object motion (motion_synthesis.py).

        Each sample is repeated ``motions_per_sample`` times; each copy gets a step s and a delay d
        (``train_max_delay``; plan time t-s-d, inside the episode), the demonstration's own actions from t-s
        as the plan (or the base's chunk planned at t-s-d with its first d entries skipped, when
        ``plan_feature`` holds one per frame), its own rigid motion of the anchor keypoints through the
        window, and as the target the plan's action s carried with the object's motion since plan time
        (``motion_label``: the whole motion the moved keypoints show, only the synthesised one, or the
        synthesised one plus a share of the rest graded by how far the world moved the object); motions
        slower than ``motion_min_carry_speed`` keep the plan, as still samples do.
        """
        cfg, norm = self.config, self.norm
        horizon, key = cfg.n_action_steps, cfg.anchor_feature
        self._check_synthesis_inputs()
        reps = cfg.motions_per_sample
        batch = {k: (v.repeat_interleave(reps, 0) if isinstance(v, Tensor) else v) for k, v in batch.items()}
        kp = norm(key, batch[key], inverse=True)
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
        step, delay = self._plan_times(batch.get(f"{key}_is_pad"), b, k, kp.device)
        age = step + delay
        plan = self._synthesised_plan(batch, step, delay, k)
        velocity, turn = draw_motions(
            b,
            self.motion_max_speed(),
            math.radians(cfg.motion_max_turn_deg),
            cfg.motion_static_fraction,
            device=kp.device,
        )
        points = kp.reshape(b, k, -1, 2)
        moved, rot, shift = move_window(points, k - 1 - age, velocity, turn)
        batch[key] = norm(key, moved.reshape(kp.shape))
        plan_s = plan[torch.arange(b, device=kp.device), step]
        carried = self._carried(plan_s, points, moved, age, rot, shift)
        moving = (velocity != 0).any(-1) | (turn != 0)
        if cfg.motion_min_carry_speed > 0:  # a slow world is left to the base's next plan
            moving &= velocity.norm(dim=-1) >= cfg.motion_min_carry_speed
        target = torch.where(moving.unsqueeze(-1), carried, plan_s)  # a still scene keeps the plan exactly
        _, valid = self.current_action(batch)
        return CorrectionSample(batch, plan, step, age, target, valid, synthesised=True)

    def _check_synthesis_inputs(self) -> None:
        """Raise a ValueError where synthesised motion cannot train this corrector: it does not read the
        anchor feature, or it reads images (the motion moves the keypoints only)."""
        cfg, key = self.config, self.config.anchor_feature
        if key not in cfg.corrector_features:
            raise ValueError(
                f"synthesising object motion moves {key!r}, which the corrector does not read: add it to "
                f"--policy.observation_features (now {cfg.corrector_features})"
            )
        images = [k for k in self.frame_keys if cfg.input_features[k].type is FeatureType.VISUAL]
        if images:
            raise ValueError(
                f"synthesised object motion moves only {key!r}, not the images {images}: train an image "
                "corrector on recorded corrections (dcdp-record-corrections) or read vector features only "
                "(--policy.observation_features)"
            )

    def _plan_times(self, pad: Tensor | None, b: int, k: int, device: torch.device) -> tuple[Tensor, Tensor]:
        """Each sample's random step s and delay d (B,), plan time t-s-d inside the episode (``pad``: the
        anchor history's padding, (B, K)) and the K-frame window; d is 0 without ``train_max_delay``."""
        cfg, horizon = self.config, self.config.n_action_steps
        # plan time t-s must lie inside the episode: s <= the number of real frames before t
        history = (~pad).sum(1) - 1 if pad is not None else torch.full((b,), k - 1, device=device)
        limit = torch.minimum(history.clamp_min(0), torch.full_like(history, min(horizon, k) - 1))
        step = (torch.rand(b, device=device) * (limit + 1)).floor().long().clamp_max(limit)
        delay = torch.zeros_like(step)
        if cfg.train_max_delay:  # a late chunk: planned d more steps back, inside the episode and window
            room = torch.minimum(history.clamp_min(0) - step, k - 1 - step).clamp(0, cfg.train_max_delay)
            delay = (torch.rand(b, device=device) * (room + 1)).floor().long().clamp_max(room)
        return step, delay

    def _synthesised_plan(self, batch: dict[str, Tensor], step: Tensor, delay: Tensor, k: int) -> Tensor:
        """The chunk (B, H, A), base-normalised, each synthesised sample executes: the base's chunk planned at
        t-s-d with its first d entries skipped where ``plan_feature`` holds one per frame
        (dcdp-precompute-plans), else the demonstration's own actions from t-s."""
        cfg, horizon = self.config, self.config.n_action_steps
        rows = torch.arange(step.shape[0], device=step.device)
        if cfg.plan_feature in batch:  # the base's chunk planned at each frame (dcdp-precompute-plans)
            per_frame = self.plan_column(batch)
            need = horizon + cfg.train_max_delay
            if per_frame.dim() != 4 or per_frame.shape[2] < need:
                raise ValueError(
                    f"{cfg.plan_feature} must hold the base's chunk (>= n_action_steps + train_max_delay = "
                    f"{need} actions) at every frame of the observation window, got shape "
                    f"{tuple(per_frame.shape[1:])}"
                )
            cols = delay.unsqueeze(1) + torch.arange(horizon, device=step.device)
            return self.norm(ACTION, per_frame[rows, k - 1 - (step + delay)][rows.unsqueeze(1), cols])
        # the demonstration's own chunk from t-s
        cols = (horizon - 1 - step).unsqueeze(1) + torch.arange(horizon, device=step.device)
        return batch[ACTION][rows.unsqueeze(1), cols]

    def _carried(
        self, plan_s: Tensor, points: Tensor, moved: Tensor, age: Tensor, rot: Tensor, shift: Tensor
    ) -> Tensor:
        """The planned action ``plan_s`` (B, A, base-normalised) carried with the object's motion since plan
        time, per ``motion_label``: the synthesised motion ``rot``, ``shift`` alone (``added``), the whole
        motion the ``moved`` keypoints (B, K, N, 2) show (``observed``), or the synthesised motion plus a
        share of the rest graded by how far the world moved the ``points``' centroid (``graded``)."""
        cfg, norm = self.config, self.norm
        rows = torch.arange(plan_s.shape[0], device=plan_s.device)
        k = moved.shape[1]
        raw_plan_s = norm(ACTION, plan_s, inverse=True)
        carried = anchor_actions(raw_plan_s, rot, shift)  # with the synthesised motion alone (``added``)
        if cfg.motion_label != "added":  # the whole motion the moved keypoints show since plan time
            whole = anchor_actions(raw_plan_s, *rigid_fit_2d(moved[rows, k - 1 - age], moved[:, -1]))
            if cfg.motion_label == "graded":  # toward it by how far the world moved the centroid
                world_shift = (moved[:, -1].mean(1) - points[:, -1].mean(1)).norm(dim=-1)
                share = push_share(world_shift, self.motion_full_carry_at()).unsqueeze(-1)
                whole = carried + share * (whole - carried)
            carried = whole
        return norm(ACTION, carried)
