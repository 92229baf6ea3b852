"""A learned completion gate: leave the base's plan uncorrected once the task is nearly done.

Correcting a chunk for the object's motion keeps the pushes' geometry relative to the object, which is what
transport needs; in the final alignment it moves the last pushes' end point off the goal by the drift
(docs/FINDINGS.md, "Mild-drift success: gates and finish screens"). The gate learns, from plain
demonstrations, where "nearly done" is: a frame is *near completion* when the object's keypoints are within
``radius`` (mean distance, raw units) of where they are on the episode's last frame -- a demonstration ends
with the task done, so its last frame is the goal, whatever the task. The radius is a fraction of the
demonstrations' own scale (``travel_scale``: how far the object typically travels to its end), so the same
default fits pixels, metres or any other unit. At run time the policy scales the
change of the plan by ``1 - p(near)`` in the modes that move it, ``dcdp`` and ``object_anchored``
(``DCDPPolicy.gate_applies``; ``completion_gate=true``). Fitted by ``dcdp-fit-completion-gate``
(``fit_completion_gate.py``): after stage 1 on a corrector, or around a bare base for the training-free
anchoring.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

#: the execution modes that move the base's plan: where a fitted completion gate leaves it as planned near
#: completion and where the scene lead applies
GATED_MODES = ("dcdp", "object_anchored")


def distance_to_end(points: Tensor, episode_index: Tensor) -> Tensor:
    """Mean keypoint distance (T,) of each frame's object to its place on its episode's last frame (pure).

    Args:
        points: Object keypoints (T, N, 2) in raw units, frames in dataset order.
        episode_index: Episode of each frame (T,); an episode's frames are contiguous, its last frame last.

    Returns:
        A float tensor (T,) in the keypoints' units.
    """
    if points.ndim != 3 or points.shape[-1] != 2:
        raise ValueError(f"points must be (T, N, 2) keypoints, got shape {tuple(points.shape)}")
    if episode_index.shape != points.shape[:1]:
        raise ValueError(f"episode_index must be ({points.shape[0]},), got {tuple(episode_index.shape)}")
    ends, run_of = _episode_runs(episode_index)
    return (points - points[ends[run_of]]).norm(dim=-1).mean(-1)


def _episode_runs(episode_index: Tensor) -> tuple[Tensor, Tensor]:
    """The last frame of each run of equal episode indices (R,) and each frame's run number (T,)."""
    change = torch.ones_like(episode_index, dtype=torch.bool)
    change[:-1] = episode_index[1:] != episode_index[:-1]
    ends = torch.nonzero(change).squeeze(1)
    run_of = torch.cumsum(torch.cat([torch.zeros(1, dtype=torch.long), change[:-1].long()]), 0)
    return ends, run_of


def travel_scale(points: Tensor, episode_index: Tensor) -> float:
    """How far the object travels to its end in a typical demonstration (pure): the median over episodes of
    the largest ``distance_to_end`` within the episode, in the keypoints' units.

    Raises:
        ValueError: The object never moves in any episode (no scale to take a fraction of).
    """
    distance = distance_to_end(points, episode_index)
    ends, run_of = _episode_runs(episode_index)
    farthest = torch.zeros(len(ends), dtype=distance.dtype).scatter_reduce(0, run_of, distance, "amax")
    scale = float(farthest.quantile(0.5))
    if not scale > 0:
        raise ValueError("the object does not move in the demonstrations: no travel to take a radius from")
    return scale


def completion_labels(points: Tensor, episode_index: Tensor, radius: float) -> Tensor:
    """Whether each frame's object is within ``radius`` of its episode's last frame (pure).

    Args:
        points: Object keypoints (T, N, 2) in raw units, frames in dataset order.
        episode_index: Episode of each frame (T,); an episode's frames are contiguous, its last frame last.
        radius: Largest mean keypoint distance (raw units) to the last frame's keypoints that counts as near.

    Returns:
        A bool tensor (T,).
    """
    if radius <= 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    return distance_to_end(points, episode_index) < radius


class CompletionGate(nn.Module):
    """Probability (B,) that the task is nearly done, from the current observation's state features.

    Args:
        dims: ``{feature: size}`` of the (base-normalised) state features it reads, in order.
        hidden: Hidden width of its two-layer MLP.
    """

    def __init__(self, dims: dict[str, int], hidden: int = 64) -> None:
        super().__init__()
        if not dims:
            raise ValueError("the completion gate needs at least one state feature to read")
        self.keys = list(dims)
        size = sum(dims.values())
        self.net = nn.Sequential(
            nn.Linear(size, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1)
        )

    def inputs(self, batch: dict[str, Tensor]) -> Tensor:
        """The gate's input (B, D): its features of the newest frame, concatenated."""
        parts = []
        for key in self.keys:
            x = batch[key]
            parts.append(x[:, -1] if x.ndim == 3 else x)  # (B, n_obs, D) histories: the newest frame
        return torch.cat(parts, dim=-1)

    def logit(self, x: Tensor) -> Tensor:
        """Logits (B,) of inputs ``x`` (B, D)."""
        return self.net(x).squeeze(-1)

    def forward(self, batch: dict[str, Tensor]) -> Tensor:
        """p(near completion) (B,) of the observation in ``batch``."""
        return torch.sigmoid(self.logit(self.inputs(batch)))


def gated_action(plan: Tensor, action: Tensor, near: Tensor) -> Tensor:
    """The corrected ``action`` (B, ...), its correction over ``plan`` (same shape) scaled by ``1 - near``
    (B,): one action (B, A) or a whole chunk (B, H, A)."""
    keep = (1.0 - near).reshape(-1, *[1] * (action.ndim - 1))
    return plan + keep * (action - plan)


def gate_applies(gate: CompletionGate | None, config) -> bool:
    """Whether a fitted ``gate`` scales the current mode's change of the plan (pure): ``completion_gate`` on
    and ``config.execution`` one of the modes that move the plan (``GATED_MODES``: ``dcdp``,
    ``object_anchored``)."""
    return gate is not None and config.completion_gate and config.execution in GATED_MODES


def build_gate(config, dims: dict[str, int]) -> CompletionGate | None:
    """The gate module a policy with ``config`` holds: one whenever a gate was fitted (``completion_gate``
    on, or its ``completion_radius`` recorded), so ``completion_gate=false`` still loads the folder and runs
    it off; ``None`` otherwise."""
    fitted = config.completion_gate or config.completion_radius is not None
    return CompletionGate(dims) if fitted else None
