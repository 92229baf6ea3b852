"""Pure functions of the correction math (no simulator, no LeRobot state) -- tested on their own."""

from __future__ import annotations

import hashlib

import torch
from torch import Tensor


def to_unit_range(actions: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """Min-max normalise actions to [-1, 1] before encoding (paper: ``2 (a - min) / (max - min) - 1``)."""
    return 2.0 * (actions - low) / (high - low).clamp_min(1e-8) - 1.0


def from_unit_range(actions: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """Inverse of :func:`to_unit_range`."""
    return (actions + 1.0) * 0.5 * (high - low).clamp_min(1e-8) + low


def temporal_ensemble_step(plan: Tensor | None, chunk: Tensor, weight: float) -> Tensor:
    """One temporal-ensemble update (closed loop, replan every step).

    ``plan`` (B, L, A) is the blended plan of the previous step, whose entry k is the action planned for
    step ``t-1+k``; ``chunk`` (B, L, A) is the new prediction for steps ``t .. t+L-1``. Where the two
    overlap, ``a = weight * a_new + (1 - weight) * a_prev``; the last step has no previous estimate.
    The action to execute now is ``result[:, 0]``.
    """
    if plan is None:
        return chunk.clone()
    out = chunk.clone()
    n = min(plan.shape[1] - 1, chunk.shape[1])
    out[:, :n] = weight * chunk[:, :n] + (1.0 - weight) * plan[:, 1 : 1 + n]
    return out


def state_dict_sha256(state_dict: dict[str, Tensor]) -> str:
    """Content hash of a set of weights: names, dtypes, shapes and bytes, in sorted name order."""
    h = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name].detach().to("cpu").contiguous()
        h.update(name.encode())
        h.update(str(t.dtype).encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def sliding_windows(frames: Tensor, window: int) -> Tensor:
    """(B, T, ...) -> (B, T - window + 1, window, ...): the window ending at each step."""
    return frames.unfold(1, window, 1).movedim(-1, 2)


#: LeRobot's normalisation modes and the statistics each maps to [-1, 1] (``MEAN_STD`` standardises instead)
RANGE_STATS = {"MIN_MAX": ("min", "max"), "QUANTILES": ("q01", "q99"), "QUANTILE10": ("q10", "q90")}
NORMALIZATION_MODES = ("MIN_MAX", "MEAN_STD", "QUANTILES", "QUANTILE10", "IDENTITY")


def check_normalization(key: str, mode: str, stats: dict[str, Tensor]) -> None:
    """Refuse a mode this module cannot reproduce, or one whose statistics are missing, naming the feature."""
    if mode not in NORMALIZATION_MODES:
        raise ValueError(
            f"the base normalises {key!r} with mode {mode!r}, which dcdp cannot reproduce "
            f"(supported: {', '.join(NORMALIZATION_MODES)})"
        )
    needed = RANGE_STATS.get(mode, ("mean", "std") if mode == "MEAN_STD" else ())
    missing = [k for k in needed if k not in stats]
    if missing:
        raise ValueError(f"the base normalises {key!r} with {mode} but its saved statistics lack {missing}")


def normalize(x: Tensor, stats: dict[str, Tensor], mode: str) -> Tensor:
    """LeRobot's normalisation of one feature: ``MIN_MAX`` / ``QUANTILES`` (q01-q99) / ``QUANTILE10``
    (q10-q90) to [-1, 1], ``MEAN_STD``, or ``IDENTITY``."""
    if mode in RANGE_STATS:
        lo, hi = (stats[k] for k in RANGE_STATS[mode])
        return 2.0 * (x - lo) / (hi - lo).clamp_min(1e-8) - 1.0
    if mode == "MEAN_STD":
        return (x - stats["mean"]) / stats["std"].clamp_min(1e-8)
    if mode == "IDENTITY":
        return x
    raise ValueError(f"unknown normalisation mode {mode!r} ({', '.join(NORMALIZATION_MODES)})")


def unnormalize(x: Tensor, stats: dict[str, Tensor], mode: str) -> Tensor:
    """Inverse of :func:`normalize`."""
    if mode in RANGE_STATS:
        lo, hi = (stats[k] for k in RANGE_STATS[mode])
        return (x + 1.0) * 0.5 * (hi - lo).clamp_min(1e-8) + lo
    if mode == "MEAN_STD":
        return x * stats["std"].clamp_min(1e-8) + stats["mean"]
    if mode == "IDENTITY":
        return x
    raise ValueError(f"unknown normalisation mode {mode!r} ({', '.join(NORMALIZATION_MODES)})")


def action_range(stats: dict[str, Tensor], mode: str, action_dim: int) -> tuple[Tensor, Tensor]:
    """Range (low, high) of base-normalised actions, mapped to [-1, 1] before encoding (paper: min-max).

    The recorded min/max of the actions, normalised as the base does, when the statistics hold them; else
    [-1, 1] for the range modes (``MIN_MAX``, ``QUANTILES``, ``QUANTILE10``). ``MEAN_STD`` and ``IDENTITY``
    without min/max cannot be bounded and are refused.
    """
    if "min" in stats and "max" in stats:
        lo, hi = normalize(stats["min"], stats, mode), normalize(stats["max"], stats, mode)
        return torch.minimum(lo, hi), torch.maximum(lo, hi)
    if mode in RANGE_STATS or not stats:
        return -torch.ones(action_dim), torch.ones(action_dim)
    raise ValueError(f"the base's action statistics ({mode}) hold no min/max: the action range is unknown")


def rigid_fit_2d(before: Tensor, after: Tensor) -> tuple[Tensor, Tensor]:
    """Least-squares rigid motion (rotation + translation, no reflection) of 2-D point sets (Kabsch).

    Args:
        before: (B, N, 2) keypoints when the chunk was planned.
        after: (B, N, 2) the same keypoints now.

    Returns:
        ``R`` (B, 2, 2) and ``t`` (B, 2) minimising ``sum_i |R p_i + t - q_i|^2``. In 2-D the optimal angle
        has the closed form ``atan2(sum p_i x q_i, sum p_i . q_i)`` over the centred points, so no SVD.
    """
    if before.shape != after.shape or before.shape[-1] != 2 or before.dim() != 3:
        raise ValueError(
            f"rigid_fit_2d needs two (B, N, 2) tensors, got {tuple(before.shape)} and {tuple(after.shape)}"
        )
    pc, qc = before.mean(1, keepdim=True), after.mean(1, keepdim=True)
    p, q = before - pc, after - qc
    sin = (p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]).sum(1)
    cos = (p * q).sum((1, 2))
    angle = torch.atan2(sin, cos)
    c, s = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    t = qc[:, 0] - (rot @ pc[:, 0].unsqueeze(-1)).squeeze(-1)
    return rot, t


def anchor_actions(actions: Tensor, rot: Tensor, t: Tensor) -> Tensor:
    """Carry planned actions along with an object's rigid motion: ``a_xy' = R a_xy + t``.

    Args:
        actions: (B, A) or (B, L, A) raw actions whose first two dims are xy in the keypoints' frame
            (other dims are left as planned).
        rot: (B, 2, 2); t: (B, 2) from :func:`rigid_fit_2d`.
    """
    xy = actions[..., :2]
    if actions.dim() == 2:
        moved = (rot @ xy.unsqueeze(-1)).squeeze(-1) + t
    else:
        moved = xy @ rot.transpose(1, 2) + t.unsqueeze(1)
    return torch.cat([moved, actions[..., 2:]], dim=-1)
