"""The compiled per-step kernel's copy of the residual corrector's weights (:mod:`.step_kernel`).

:func:`pack_weights` copies every weight of the per-step path -- the frame encoder's vector MLP, the dynamic
feature extractor's temporal layer, diff cross-attention and pooling, the residual head's layers after its
per-step first layer -- out of the modules once, as contiguous float32 arrays in a :class:`StepWeights`
(the policy re-packs when they change); :func:`supports` says whether the kernel covers a corrector. Neither
imports numba.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from lerobot_dcdp.model.dynamics import DynamicFeatureExtractor, FrameEncoder
from lerobot_dcdp.model.residual import ResidualHead


class StepWeights(NamedTuple):
    """Every weight of the per-step path, contiguous float32 (linear weights (out, in), as in nn.Linear)."""

    shift: np.ndarray  # frame standardisation (n,)
    scale: np.ndarray
    f1: np.ndarray  # frame MLP: three weights and biases
    f1b: np.ndarray
    f2: np.ndarray
    f2b: np.ndarray
    f3: np.ndarray
    f3b: np.ndarray
    alpha: float
    pos: np.ndarray  # (M, d)
    use_temporal: bool
    t_ln1: np.ndarray  # (2, d): LayerNorm weight, bias
    t_q: np.ndarray  # in_proj split into q, k, v: (d, d) each
    t_qb: np.ndarray
    t_k: np.ndarray
    t_kb: np.ndarray
    t_v: np.ndarray
    t_vb: np.ndarray
    t_out: np.ndarray  # (d, d)
    t_outb: np.ndarray
    t_ln2: np.ndarray
    t_ff1: np.ndarray  # (ff, d)
    t_ff1b: np.ndarray
    t_ff2: np.ndarray  # (d, ff)
    t_ff2b: np.ndarray
    t_eps: float
    use_cross: bool
    diff_pos: np.ndarray  # (M-1, d)
    c_lnq: np.ndarray
    c_lnkv: np.ndarray
    c_q: np.ndarray
    c_qb: np.ndarray
    c_k: np.ndarray
    c_kb: np.ndarray
    c_v: np.ndarray
    c_vb: np.ndarray
    c_out: np.ndarray
    c_outb: np.ndarray
    c_eps: float
    heads: int
    p_ln: np.ndarray  # (2, 2d)
    p_eps: float
    p_w: np.ndarray  # (d, 2d)
    p_b: np.ndarray
    h2: np.ndarray  # head layers after the per-step first layer
    h2b: np.ndarray
    h3: np.ndarray
    h3b: np.ndarray
    change_scale: float


def _np(t: torch.Tensor) -> np.ndarray:
    """A contiguous float32 copy (never a view of the parameter: the weights may change in place)."""
    return np.array(t.detach().to("cpu", torch.float32).numpy(), dtype=np.float32, order="C", copy=True)


def _lin(layer: nn.Linear) -> tuple[np.ndarray, np.ndarray]:
    return _np(layer.weight), _np(layer.bias)


def _ln(norm: nn.LayerNorm) -> np.ndarray:
    return np.stack([_np(norm.weight), _np(norm.bias)])


def supports(frames: FrameEncoder, extractor: DynamicFeatureExtractor) -> bool:
    """Whether :func:`residual_step` computes this corrector: vector frames only, ReLU temporal layer."""
    t = extractor.temporal
    return (
        frames.state is not None
        and frames.image is None
        and (t is None or (t.norm_first and t.activation_relu_or_gelu == 1))
    )


@torch.no_grad()
def pack_weights(
    frames: FrameEncoder, extractor: DynamicFeatureExtractor, head: ResidualHead, change_scale: float
) -> StepWeights:
    """The kernel's copy of the weights (see :func:`supports` for what it covers)."""
    if not supports(frames, extractor):
        raise ValueError("the compiled step covers vector frames and a ReLU, norm_first temporal layer only")
    f = [m for m in frames.state.net if isinstance(m, nn.Linear)]
    h = [m for m in head.net if isinstance(m, nn.Linear)]
    d = extractor.pos.shape[1]
    empty2, empty = np.zeros((1, 1), np.float32), np.zeros(1, np.float32)
    t, c = extractor.temporal, extractor.cross
    temporal = (
        (
            _ln(t.norm1),
            *_lin_in(t.self_attn),
            *_lin(t.self_attn.out_proj),
            _ln(t.norm2),
            *_lin(t.linear1),
            *_lin(t.linear2),
            float(t.norm1.eps),
        )
        if t is not None
        else (empty2, *(empty2, empty) * 4, empty2, *(empty2, empty) * 2, 1e-5)
    )
    cross = (
        (
            _np(extractor.diff_pos),
            _ln(extractor.cross_norm_q),
            _ln(extractor.cross_norm_kv),
            *_lin_in(c),
            *_lin(c.out_proj),
            float(extractor.cross_norm_q.eps),
        )
        if c is not None
        else (empty2, empty2, empty2, *(empty2, empty) * 4, 1e-5)
    )
    heads = t.self_attn.num_heads if t is not None else (c.num_heads if c is not None else 1)
    if c is not None and t is not None and c.num_heads != heads:
        raise ValueError("the compiled step needs the same number of heads in both attentions")
    if d % heads:
        raise ValueError(f"feature width {d} is not divisible by {heads} heads")
    return StepWeights(
        _np(frames.state_shift),
        _np(frames.state_scale),
        *_lin(f[0]),
        *_lin(f[1]),
        *_lin(f[2]),
        float(extractor.alpha),
        _np(extractor.pos),
        t is not None,
        *temporal,
        c is not None,
        *cross,
        heads,
        _ln(extractor.pool[0]),
        float(extractor.pool[0].eps),
        *_lin(extractor.pool[1]),
        *_lin(h[1]),
        *_lin(h[2]),
        float(change_scale),
    )


def _lin_in(attn: nn.MultiheadAttention) -> tuple[np.ndarray, ...]:
    """q, k, v projections as separate contiguous (in, out) weights and biases."""
    w, b = attn.in_proj_weight.chunk(3), attn.in_proj_bias.chunk(3)
    return tuple(a for i in range(3) for a in (_np(w[i]), _np(b[i])))
