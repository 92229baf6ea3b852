"""Synthesised object motion for stage 1 on plain demonstrations (no simulator, no recorded plan).

A demonstration window shows a still world; the corrector must learn what to do when the object moves after
the chunk was planned. For each training sample we draw a rigid motion of the object -- a constant velocity
``v`` (raw anchor units per control step, any direction) and a constant turn rate ``omega`` (radians per step,
about the object's keypoint centroid at plan time) -- and apply it to the object's keypoints in every frame of
the observation window: the frame ``j`` steps after plan time (``j < 0`` before it) shows the object moved by
``T_j: p -> R(j omega) (p - c) + c + j v``, so the plan-time frame is unchanged. The label of step ``s`` of
the chunk is the planned action carried along with that motion (the anchoring rule), ``T_s(plan_s)``; a
sample drawn without motion keeps the plan, so the corrector also learns to leave a still scene alone.

Pure functions of tensors; the caller owns the random generator.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def rotation_matrices(angle: Tensor) -> Tensor:
    """(...,) angles in radians -> (..., 2, 2) rotation matrices."""
    c, s = torch.cos(angle), torch.sin(angle)
    return torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)


def draw_motions(
    n: int,
    max_speed: float,
    max_turn_rate: float,
    static_fraction: float,
    generator: torch.Generator | None = None,
    device: torch.device | str = "cpu",
) -> tuple[Tensor, Tensor]:
    """Random rigid motions: speeds uniform in [0, max_speed], any direction, turn rates uniform in
    [-max_turn_rate, max_turn_rate]; a ``static_fraction`` of them (in expectation) is no motion at all.

    Returns:
        ``velocity`` (n, 2) in raw anchor units per step and ``turn_rate`` (n,) in radians per step.
    """
    u = torch.rand(n, 4, generator=generator).to(device)
    speed = max_speed * u[:, 0]
    heading = 2.0 * math.pi * u[:, 1]
    turn = max_turn_rate * (2.0 * u[:, 2] - 1.0)
    moving = (u[:, 3] >= static_fraction).to(speed.dtype)
    velocity = torch.stack([torch.cos(heading), torch.sin(heading)], -1) * (speed * moving).unsqueeze(-1)
    return velocity, turn * moving


def motion_at(offsets: Tensor, velocity: Tensor, turn_rate: Tensor, pivot: Tensor) -> tuple[Tensor, Tensor]:
    """The rigid motion ``T_j`` after ``j`` steps, as ``(R, t)`` with ``T_j(p) = R p + t``.

    Args:
        offsets: (B, T) steps since plan time (negative before it).
        velocity: (B, 2); turn_rate: (B,); pivot: (B, 2) the centre of rotation.

    Returns:
        ``R`` (B, T, 2, 2) and ``t`` (B, T, 2).
    """
    j = offsets.to(velocity.dtype)
    rot = rotation_matrices(j * turn_rate.unsqueeze(-1))
    c = pivot.unsqueeze(1)  # (B, 1, 2)
    t = c - (rot @ c.unsqueeze(-1)).squeeze(-1) + j.unsqueeze(-1) * velocity.unsqueeze(1)
    return rot, t


def move_points(points: Tensor, rot: Tensor, t: Tensor) -> Tensor:
    """Apply per-frame rigid motions to keypoints: (B, T, N, 2) with (B, T, 2, 2) and (B, T, 2)."""
    return points @ rot.transpose(-1, -2) + t.unsqueeze(-2)


def move_window(
    keypoints: Tensor, plan_index: Tensor, velocity: Tensor, turn_rate: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Move the object's keypoints through an observation window, identity at plan time.

    Args:
        keypoints: (B, T, N, 2) raw keypoints of frames t-T+1 .. t.
        plan_index: (B,) index in the window of the frame the chunk was planned from.
        velocity, turn_rate: from :func:`draw_motions`.

    Returns:
        The moved keypoints (B, T, N, 2), and ``(R, t)`` of the motion at the window's last frame (the
        label's motion), shapes (B, 2, 2) and (B, 2).
    """
    b, n_frames = keypoints.shape[:2]
    rows = torch.arange(b, device=keypoints.device)
    pivot = keypoints[rows, plan_index].mean(1)  # (B, 2) centroid at plan time
    offsets = torch.arange(n_frames, device=keypoints.device).unsqueeze(0) - plan_index.unsqueeze(1)
    rot, t = motion_at(offsets, velocity, turn_rate, pivot)
    return move_points(keypoints, rot, t), rot[:, -1], t[:, -1]


def push_share(world_shift: Tensor, full_at: float) -> Tensor:
    """The share of the object's own (push-driven) motion a ``graded`` label carries the plan with.

    Args:
        world_shift: (B,) how far the synthesised motion has carried the object's centroid (raw units).
        full_at: The displacement from which the whole observed motion is carried.

    Returns:
        (B,) ``clamp(world_shift / full_at, 0, 1)``: none for a still world, all of it from ``full_at`` on.
    """
    return (world_shift / full_at).clamp(0.0, 1.0)


def keypoint_extent(stats: dict[str, Tensor]) -> float:
    """The larger of the x and y spans of flat (x0, y0, x1, y1, ...) keypoint statistics: max - min when
    the statistics hold them, else four standard deviations."""
    if "min" in stats and "max" in stats:
        span = (torch.as_tensor(stats["max"]) - torch.as_tensor(stats["min"])).reshape(-1, 2)
    elif "std" in stats:
        span = 4.0 * torch.as_tensor(stats["std"]).reshape(-1, 2)
    else:
        raise ValueError("keypoint statistics hold neither min/max nor std; set motion_max_speed explicitly")
    return float(span.max())
