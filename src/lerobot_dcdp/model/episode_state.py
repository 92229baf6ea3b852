"""What the policy carries from one control step to the next within an episode."""

from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass, field

from torch import Tensor


@dataclass
class EpisodeState:
    """The per-episode state of the control loop; ``reset()`` starts a new one.

    Attributes:
        bank: (B, M, d) the corrector's history bank, one cached frame token per step.
        rep: The newest frame's change representation (standardised vector inputs, or its token).
        frame_pushed: Whether this step's frame already entered the bank (the compiled kernel pushes it
            itself).
        chunk: (B, H, A) the chunk being executed, base-normalised, as the base planned it.
        step: Index of the next action of ``chunk`` (chunk modes).
        plan: (B, L, A) closed loop / temporal ensemble: this step's plan.
        z: The corrector's chunk code.
        h: ``reconstruct``: the decoder's recurrent state.
        at_plan: ``rep`` of the observation the chunk was planned from.
        anchor_plan: (B, N, 2) raw anchor keypoints of that observation (when anchoring is used).
        terms: ``residual``: the head's per-chunk part (``ResidualHead.chunk_terms``), or None (eager path).
        w_step: ``residual``: the head's per-step weights (with ``terms``).
        kernel: The compiled kernel's packed weights while the current chunk runs on it, else None.
        t: Control steps since reset.
        past: ``inference_delay`` d: what the base saw at steps t-d .. t.
        last_step: Index in the chunk of the action last returned.
        chunk_delay: Steps from the observation the current chunk was planned from to its first action (its
            age at ``last_step`` is ``last_step + chunk_delay``).
        tick_at, tick_s, plan_s: ``planning='async'``, wall clock: the last tick's time, the smoothed tick
            period and the smoothed planning time of the base (seconds).
    """

    bank: Tensor | None = None
    rep: Tensor | None = None
    frame_pushed: bool = False
    chunk: Tensor | None = None
    step: int = 0
    plan: Tensor | None = None
    z: Tensor | None = None
    h: Tensor | None = None
    at_plan: Tensor | None = None
    anchor_plan: Tensor | None = None
    terms: Tensor | None = None
    w_step: Tensor | None = None
    kernel: object | None = None
    t: int = 0
    past: deque = field(default_factory=deque)
    last_step: int | None = None
    chunk_delay: int = 0
    tick_at: float | None = None
    tick_s: float | None = None
    plan_s: float | None = None

    def copy(self) -> EpisodeState:
        """A copy a query may advance without touching this one (tensors are replaced, never written)."""
        other = copy.copy(self)
        other.past = copy.copy(self.past)
        return other
