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
