"""The residual corrector's per-step path as one traced graph (inference speed only; same actions).

At batch 1 the corrector's arithmetic is tiny and its cost is per-op overhead: Python module calls, dispatch,
small allocations. :class:`ResidualStep` is the whole per-step path of ``DCDPPolicy.select_action`` for a
vector-input residual corrector -- standardise the new frame, its token, the history bank update, the
dynamic feature F, the head's per-step part (``ResidualHead.step``) -- and :func:`trace_step` freezes it
with ``torch.jit`` (weights become constants, so it is rebuilt whenever they change). The policy still
loads from its plain checkpoint; the trace is made at run time. ``fast_inference = False`` on the policy
runs the eager path, which tests compare with (equal within 1e-6).
"""

from __future__ import annotations

import warnings

import torch
from torch import Tensor, nn

from lerobot_dcdp.dynamics import DynamicFeatureExtractor, FrameEncoder
from lerobot_dcdp.residual import ResidualHead


class ResidualStep(nn.Module):
    """One control step of the residual corrector: ``(x, bank, at_plan, terms_s, w_step, plan_s, half)`` ->
    ``(action, new bank, standardised frame vector)``.

    Args (of ``forward``):
        x: The frame's raw vector inputs, concatenated in ``FrameEncoder.state_keys`` order, (B, n).
        bank: History bank of frame tokens before this step, (B, M, d).
        at_plan: Standardised frame vector at plan time, (B, n).
        terms_s: ``ResidualHead.chunk_terms`` row of this step, (B, hidden).
        w_step: First-layer weights of the per-step inputs (``chunk_terms``' second output).
        plan_s: The planned action of this step, base-normalised, (B, A).
        half: Half the range of the base-normalised actions, (A,).
    """

    def __init__(
        self,
        frames: FrameEncoder,
        extractor: DynamicFeatureExtractor,
        head: ResidualHead,
        change_scale: float,
    ) -> None:
        super().__init__()
        self.frames, self.extractor, self.head = frames, extractor, head
        self.change_scale = change_scale

    def forward(
        self,
        x: Tensor,
        bank: Tensor,
        at_plan: Tensor,
        terms_s: Tensor,
        w_step: Tensor,
        plan_s: Tensor,
        half: Tensor,
    ) -> tuple[Tensor, Tensor, Tensor]:
        vec = (x - self.frames.state_shift) / self.frames.state_scale
        token = self.frames.state(vec)
        bank = torch.cat([bank[:, 1:], token.unsqueeze(1)], dim=1)
        feature, _ = self.extractor(bank)
        delta = self.head.step(terms_s, feature, self.change_scale * (vec - at_plan), w_step)
        return plan_s + delta * half, bank, vec


@torch.no_grad()
def trace_step(step: ResidualStep, example: tuple[Tensor, ...]) -> torch.jit.ScriptModule:
    """``step`` traced on ``example`` inputs and frozen (its weights are constants of the graph)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        return torch.jit.freeze(torch.jit.trace(step.eval(), example, check_trace=False))
