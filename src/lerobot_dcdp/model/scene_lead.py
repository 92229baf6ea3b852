"""The scene lead: plan and act in a scene moved ahead by the object's own recent motion.

A base trained on still scenes brings the object to its goal and stops; when the world keeps moving the
object (a drifting block, a conveyor), the object settles downstream of the goal by about the drift over one
chunk, and the final alignment misses. With ``lead_steps`` L set, every observation the policy uses (the
base's, the corrector's, the gate's) shows the object *and the robot* moved ``L`` steps of the object's
recent motion ahead, and the actions are moved back by the same amount: the relative geometry of robot and
object is the observed one, only where the scene stands against the fixed frame (the goal) changes. So the
base aims the object upstream of the goal by the motion it will have over ``L`` steps, and the world carries
it in (docs/FINDINGS.md, "The two recommended folders").

The object's motion is the world's: of its keypoint centroid's per-step displacements over the last
``lead_window`` steps, the newest one that at least ``lead_repeats`` of them repeat (within
``lead_tolerance`` x its length, plus ``lead_noise``). The world moves the object by the same step again and
again; the robot's pushes move it by steps that vary, and in a sustained push they are the majority of a
window, which a median would follow (docs/FINDINGS.md, "Scene-lead variants"). Where no step
repeats, the motion found last holds; a still object's steps are zero and repeat (with a jittering tracker,
only within ``lead_noise``). Until a window has been seen the lead is zero.

With ``lead_in_range`` (default) the lead is clipped, per axis, so that no led keypoint leaves the range its
coordinate has in the base's training data (the base's saved min / max): the world cannot carry the object
through the workspace's walls, and a base shown an object beyond them plans from a scene it never saw
(docs/FINDINGS.md, "The two recommended folders").

The robot's xy are the first two dims of ``lead_state_feature``, in the keypoints' frame, as the actions'
first two dims are (the frame ``object_anchored`` already assumes); the base must read both, and no image.
The lead applies in the modes that move the plan (``dcdp``, ``object_anchored``:
``config_checks.GATED_MODES``) with the base in this process; the baselines run the observed scene. Each
step's action is moved back by the *current* lead, so where the plan runs as planned (the completion gate) it
follows a change of the lead since plan time; the lead enters as one step of ``L`` x the motion when the
first window is full.
"""

from __future__ import annotations

import torch
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_dcdp.model.base_normalizer import BaseNormalizer
from lerobot_dcdp.model.completion_gate import GATED_MODES


def repeated_motion(
    steps: Tensor, tolerance: float, repeats: int, noise: float = 0.0
) -> tuple[Tensor, Tensor]:
    """The world's per-step motion of an object from its per-step displacements ``steps`` (W, B, 2) (pure).

    The world moves the object by the same displacement step after step; the robot's pushes move it by
    displacements that vary. So the motion is the newest displacement that at least ``repeats`` steps of the
    window repeat -- within ``tolerance`` x its own length plus ``noise`` (the tracker's per-step noise, in
    the steps' units), itself included -- averaged over those steps.

    Returns:
        ``(motion, found)``: the motion (B, 2) and whether a repeated displacement was found (B,) (where not,
        the motion is zero).

    Raises:
        ValueError: ``steps`` is not (W, B, 2) with W >= 1.
    """
    if steps.ndim != 3 or steps.shape[-1] != 2 or steps.shape[0] < 1:
        raise ValueError(f"steps must be (W, B, 2) displacements with W >= 1, got shape {tuple(steps.shape)}")
    s = steps.transpose(0, 1)  # (B, W, 2)
    gap = (s[:, :, None] - s[:, None]).norm(dim=-1)  # [b, k, j]: how far step j is from step k
    near = gap <= tolerance * s.norm(dim=-1, keepdim=True) + noise  # j repeats k, within k's tolerance
    valid = near.sum(-1) >= repeats  # (B, W)
    order = torch.arange(1, s.shape[1] + 1, device=s.device)
    newest = (valid * order).argmax(-1)  # the newest valid k (0 where none)
    members = near[torch.arange(s.shape[0], device=s.device), newest].to(s.dtype)  # (B, W)
    found = valid.any(-1)
    motion = (members[..., None] * s).sum(1) / members.sum(-1, keepdim=True).clamp_min(1)
    return motion * found[:, None], found


#: for Gaussian jitter of the tracked positions, the gap between two still steps' displacements exceeds this
#: multiple of their 25th-percentile length on 5 % of the pairs
STILL_GAP_FACTOR = 4.6


def tracker_noise(points: Tensor, episode_index: Tensor) -> float:
    """The object tracker's per-step noise in demonstrations, as ``lead_noise`` takes it (pure).

    In demonstrations the object stands still on many steps (the robot moves elsewhere); there its keypoint
    centroid's per-step displacements are the tracker's jitter alone. The stillest quarter of all steps
    measures it: ``STILL_GAP_FACTOR`` x the 25th percentile of the displacements' lengths covers the gap
    between two still steps in 95 % of pairs (Gaussian jitter). A simulator's exact still steps give 0.

    Args:
        points: Object keypoints (T, N, 2) in raw units, frames in dataset order.
        episode_index: Episode of each frame (T,); an episode's frames are contiguous.

    Raises:
        ValueError: Shapes that do not match, or no episode with two frames.
    """
    if points.ndim != 3 or points.shape[-1] != 2 or episode_index.shape != points.shape[:1]:
        raise ValueError(
            f"points must be (T, N, 2) with episode_index (T,), got {tuple(points.shape)} and "
            f"{tuple(episode_index.shape)}"
        )
    centroid = points.double().mean(1)
    same = episode_index[1:] == episode_index[:-1]
    if not same.any():
        raise ValueError("no episode has two frames: no per-step displacement to measure the noise on")
    steps = (centroid[1:] - centroid[:-1])[same].norm(dim=-1)
    return STILL_GAP_FACTOR * float(steps.quantile(0.25))


def in_range_shift(points: Tensor, shift: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """The largest per-axis part of ``shift`` (B, 2) that keeps every keypoint of ``points`` (B, N, 2) within
    its own coordinate's range ``[low, high]`` (N, 2) (pure). The shift is shortened, never reversed: a
    keypoint already outside its range is not pulled back in."""
    up = (high - points).amin(1).clamp_min(0)  # (B, 2): how far the keypoints may move up each axis
    down = (low - points).amax(1).clamp_max(0)  # (B, 2): and down (<= 0)
    return torch.minimum(torch.maximum(shift, down.to(shift.dtype)), up.to(shift.dtype))


def data_range(normalizer: BaseNormalizer, key: str) -> tuple[Tensor, Tensor]:
    """The range ``(low, high)`` (N, 2) of each xy keypoint coordinate of ``key`` in the base's training data,
    from its saved statistics.

    Raises:
        ValueError: The base's statistics hold no min / max for ``key``.
    """
    _, stats = normalizer.stats.get(key, ("IDENTITY", {}))
    if "min" not in stats or "max" not in stats:
        raise ValueError(
            f"lead_in_range needs the min / max of {key!r} in the base's saved statistics, which has "
            f"{sorted(stats) or 'none'}: set --policy.lead_in_range=false to lead without the data's range"
        )
    return stats["min"].reshape(-1, 2), stats["max"].reshape(-1, 2)


def moved_xy(x: Tensor, shift: Tensor, pairs: bool) -> Tensor:
    """``x`` (B, D) in raw units with ``shift`` (B, 2) added to every xy pair (``pairs``) or to its first
    two dims only (pure)."""
    if pairs:
        return (x.reshape(x.shape[0], -1, 2) + shift[:, None]).reshape(x.shape)
    return torch.cat([x[:, :2] + shift, x[:, 2:]], dim=1)


def check_lead_features(config, base_features: dict, normalizer: BaseNormalizer) -> None:
    """Refuse a lead the base would not see: the base must read the object's keypoints (``anchor_feature``)
    and ``lead_state_feature`` (a vector with the robot's xy first), and no image, which the lead cannot move;
    with ``lead_in_range``, its statistics must hold the keypoints' min / max.

    Args:
        config: The policy config.
        base_features: The base's input features (``{key: PolicyFeature}``).
        normalizer: The base's normaliser (its saved statistics).
    """
    from lerobot.configs.types import FeatureType

    for name, key in (
        ("anchor_feature", config.anchor_feature),
        ("lead_state_feature", config.lead_state_feature),
    ):
        if key not in base_features:
            raise ValueError(
                f"{name} {key!r} is not among the base's observations {sorted(base_features)}: the lead "
                "moves what the base plans from (--policy.lead_state_feature names the one with the robot's "
                "xy first), or set lead_steps=0"
            )
    shape = tuple(base_features[config.lead_state_feature].shape)
    if len(shape) != 1 or shape[0] < 2:
        raise ValueError(
            f"lead_state_feature {config.lead_state_feature!r} must be a vector with the robot's xy first, "
            f"got {shape}"
        )
    images = sorted(k for k, f in base_features.items() if f.type is FeatureType.VISUAL)
    if images:
        raise ValueError(f"the scene lead cannot move the images the base reads ({images}): set lead_steps=0")
    if config.lead_in_range:
        data_range(normalizer, config.anchor_feature)


def lead_applies(config) -> bool:
    """Whether the scene lead runs: ``lead_steps`` > 0 in a mode that moves the plan, with the base in this
    process (a remote base plans from the robot's own observation, which the lead cannot move) (pure)."""
    return config.lead_steps > 0 and config.execution in GATED_MODES and config.base_location == "local"


class SceneLead:
    """Tracks the object's motion over an episode and moves observations and actions by the lead.

    Args:
        config: The policy config (``lead_steps``, ``lead_window``, ``lead_tolerance``, ``lead_repeats``,
            ``lead_noise``, ``lead_in_range``, ``lead_state_feature``, ``anchor_feature``).
        normalizer: The base's normaliser: observations and actions are moved in raw units.
    """

    def __init__(self, config, normalizer: BaseNormalizer) -> None:
        self.config = config
        self.normalizer = normalizer
        self._range: tuple[Tensor, Tensor] | None = None  # the data's range, read once (lead_in_range)
        self.reset()

    def reset(self) -> None:
        """Forget the object's track (a new episode)."""
        self._track: list[Tensor] = []
        self._motion: Tensor | None = None  # the world's motion last found, per episode of the batch

    def enter(self, batch: dict[str, Tensor], record: bool = True) -> tuple[dict[str, Tensor], Tensor]:
        """``batch`` as the led scene -- the object's keypoints and the robot's xy moved by the lead -- and
        that lead, the raw shift (B, 2); ``record``: the object joins its track (False: a query that leaves
        the track as it was)."""
        cfg = self.config
        points = self.normalizer(cfg.anchor_feature, batch[cfg.anchor_feature], inverse=True)
        shift = self.observe(points.reshape(points.shape[0], -1, 2), record)
        moved = dict(batch)
        moved[cfg.anchor_feature] = self._normalized(cfg.anchor_feature, moved_xy(points, shift, True), batch)
        state = self.normalizer(cfg.lead_state_feature, batch[cfg.lead_state_feature], inverse=True)
        moved[cfg.lead_state_feature] = self._normalized(
            cfg.lead_state_feature, moved_xy(state, shift.to(state.dtype), False), batch
        )
        return moved, shift

    def observe(self, points: Tensor, record: bool = True) -> Tensor:
        """The raw shift (B, 2) for the object's raw keypoints ``points`` (B, N, 2): ``lead_steps`` x the
        world's motion over the track (zero before a window), with ``lead_in_range`` shortened so that the led
        keypoints stay within the base's data range; ``record``: the centroid joins the track and the motion
        found is kept (False: a query that leaves both as they were)."""
        cfg = self.config
        centroid = points.mean(1)
        fresh = not (self._track and self._track[-1].shape == centroid.shape)  # a new batch of episodes
        track = [*([] if fresh else self._track[-cfg.lead_window :]), centroid]
        motion = torch.zeros_like(centroid) if fresh or self._motion is None else self._motion
        if len(track) > cfg.lead_window:
            found_motion, found = repeated_motion(
                torch.stack(track).diff(dim=0), cfg.lead_tolerance, cfg.lead_repeats, cfg.lead_noise
            )
            motion = torch.where(found[:, None], found_motion, motion)
        if record:
            self._track, self._motion = track, motion
        shift = cfg.lead_steps * motion
        if cfg.lead_in_range:
            shift = in_range_shift(points, shift, *self._data_range(points))
        return shift

    def _data_range(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """The anchor keypoints' data range on ``points``' device and dtype (statistics read once)."""
        kept = self._range
        if kept is None or (kept[0].dtype, kept[0].device) != (points.dtype, points.device):
            low, high = data_range(self.normalizer, self.config.anchor_feature)
            self._range = (low.to(points), high.to(points))
        return self._range

    def _normalized(self, key: str, raw: Tensor, batch: dict[str, Tensor]) -> Tensor:
        return self.normalizer(key, raw).to(batch[key].dtype)

    def move_action(self, action: Tensor, shift: Tensor) -> Tensor:
        """The base-normalised ``action`` (B, A) or chunk (B, H, A) with its xy moved by ``shift`` (B, 2),
        raw units."""
        raw = self.normalizer(ACTION, action, inverse=True)
        step = shift.to(raw.dtype).reshape(shift.shape[0], *[1] * (raw.ndim - 2), 2)
        moved = torch.cat([raw[..., :2] + step, raw[..., 2:]], dim=-1)
        return self.normalizer(ACTION, moved).to(action.dtype)
