"""The residual corrector's per-step path as one compiled CPU kernel (inference speed only; same actions).

At batch 1 the per-step arithmetic is ~1 M multiply-adds, ~50 us on one core, but as PyTorch ops it is ~60
dispatched calls (frame MLP, the history bank update, the extractor's temporal attention, diff
cross-attention and pooling, the head's per-step layers), each paying Python / dispatcher / allocation
overhead: ~0.5 ms back to back and ~1 ms inside a control loop, where the env and LeRobot's processors run
between two steps (``docs/FINDINGS.md``, the compiled per-step kernel). :func:`residual_step` is that same
per-step path written as plain loops and compiled by numba: one call per control step, no allocation of
tensors.

It computes exactly what the modules compute -- :class:`~lerobot_dcdp.model.dynamics.FrameEncoder`'s vector
branch, :class:`~lerobot_dcdp.model.dynamics.DynamicFeatureExtractor` (``nn.TransformerEncoderLayer`` with
``norm_first`` and ReLU, ``nn.MultiheadAttention``, LayerNorm, pooling) and
:meth:`~lerobot_dcdp.model.residual.ResidualHead.step` -- in float32 with its own summation order, so the
actions equal the eager path's up to float rounding (tests: within 1e-6). The weights come from
:func:`~lerobot_dcdp.runtime.step_weights.pack_weights` (re-exported here with :class:`StepWeights` and
:func:`supports`), copied out of the modules once (the policy re-packs when they change); the checkpoint
stays a plain state dict.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

#: Where numba keeps the compiled kernel: ``$DCDP_KERNEL_CACHE``, else ``$XDG_CACHE_HOME/lerobot_dcdp/numba``
#: (``~/.cache/...``). Never the package folder, which a plain ``pip install`` may leave read-only. Set before
#: numba is imported; a process that imported numba earlier keeps its own ``NUMBA_CACHE_DIR``.
CACHE_ENV = "DCDP_KERNEL_CACHE"


def cache_dir() -> Path:
    """The kernel's cache location (see :data:`CACHE_ENV`)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "lerobot_dcdp" / "numba"


def _usable_cache_dir() -> Path:
    """Create the cache folder and prove it writable. numba itself would silently fall back to the package
    folder (its in-tree locator) when the cache folder is unusable; raising here instead makes the policy
    take the PyTorch path with one warning."""
    folder = cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise OSError(f"kernel cache {folder} is not a writable folder ({err}); set {CACHE_ENV}") from err
    return folder


if not os.environ.get("NUMBA_CACHE_DIR"):
    os.environ["NUMBA_CACHE_DIR"] = str(_usable_cache_dir())

import numpy as np  # noqa: E402
import torch  # noqa: E402
from numba import njit  # noqa: E402

from lerobot_dcdp.runtime.step_weights import StepWeights, pack_weights, supports  # noqa: E402

__all__ = [
    "CACHE_ENV",
    "StepWeights",
    "cache_dir",
    "loaded",
    "pack_weights",
    "residual_step",
    "supports",
    "warm_up",
]


# ---------------------------------------------------------------------------------------- compiled parts
@njit(cache=True, fastmath={"reassoc", "contract"})
def _matmul(x, w, b, out, relu):
    """``out = x @ w.T + b`` (then ReLU when ``relu``): x (R, k), w (n, k) in nn.Linear's layout, out (R, n).

    Blocks of 16 weight rows stay in cache while every input row passes them (the weights are read once per
    call, whatever the batch); a 4 x 2 tile of outputs shares each load. The sums over k are vectorised
    (reassociated), so they round differently from PyTorch's, by float32 rounding."""
    rows, k = x.shape
    n = w.shape[0]
    for j0 in range(0, n, 16):
        j1 = min(j0 + 16, n)
        r = 0
        while r + 4 <= rows:
            x0, x1, x2, x3 = x[r], x[r + 1], x[r + 2], x[r + 3]
            j = j0
            while j < j1:
                two = j + 1 < j1
                wa, wb = w[j], w[j + 1 if two else j]
                a0 = a1 = a2 = a3 = c0 = c1 = c2 = c3 = np.float32(0.0)
                for i in range(k):
                    a0 += x0[i] * wa[i]
                    a1 += x1[i] * wa[i]
                    a2 += x2[i] * wa[i]
                    a3 += x3[i] * wa[i]
                    c0 += x0[i] * wb[i]
                    c1 += x1[i] * wb[i]
                    c2 += x2[i] * wb[i]
                    c3 += x3[i] * wb[i]
                out[r, j] = a0 + b[j]
                out[r + 1, j] = a1 + b[j]
                out[r + 2, j] = a2 + b[j]
                out[r + 3, j] = a3 + b[j]
                if two:
                    out[r, j + 1] = c0 + b[j + 1]
                    out[r + 1, j + 1] = c1 + b[j + 1]
                    out[r + 2, j + 1] = c2 + b[j + 1]
                    out[r + 3, j + 1] = c3 + b[j + 1]
                j += 2
            r += 4
        while r < rows:
            xr = x[r]
            for j in range(j0, j1):
                wj = w[j]
                a0 = np.float32(0.0)
                for i in range(k):
                    a0 += xr[i] * wj[i]
                out[r, j] = a0 + b[j]
            r += 1
    if relu:
        for r in range(rows):
            for j in range(n):
                out[r, j] = max(out[r, j], np.float32(0.0))


@njit(cache=True)
def _gelu(x):
    """Exact (erf) GELU in place, ``nn.GELU()``."""
    for r in range(x.shape[0]):
        for j in range(x.shape[1]):
            x[r, j] = 0.5 * x[r, j] * (1.0 + math.erf(x[r, j] * 0.7071067811865476))


@njit(cache=True)
def _layer_norm(x, wb, eps, out):
    """``nn.LayerNorm`` over the last axis of x (R, n); wb = (weight, bias)."""
    rows, n = x.shape
    for r in range(rows):
        mean = 0.0
        for j in range(n):
            mean += x[r, j]
        mean /= n
        var = 0.0
        for j in range(n):
            var += (x[r, j] - mean) ** 2
        inv = 1.0 / math.sqrt(var / n + eps)
        for j in range(n):
            out[r, j] = (x[r, j] - mean) * inv * wb[0, j] + wb[1, j]


@njit(cache=True, fastmath={"reassoc", "contract"})
def _attention(q, k, v, heads, out):
    """Scaled dot-product attention per head of projected q (Mq, d), k / v (Mk, d) -> out (Mq, d)."""
    mq, d = q.shape
    mk = k.shape[0]
    dh = d // heads
    scale = np.float32(1.0 / math.sqrt(dh))
    p = np.empty(mk, np.float32)
    for h in range(heads):
        lo, hi = h * dh, (h + 1) * dh
        for i in range(mq):
            qi, oi = q[i, lo:hi], out[i, lo:hi]
            top = -np.inf
            for j in range(mk):
                kj = k[j, lo:hi]
                s = np.float32(0.0)
                for t in range(dh):
                    s += qi[t] * kj[t]
                p[j] = s * scale
                top = max(top, p[j])
            total = np.float32(0.0)
            for j in range(mk):
                p[j] = math.exp(p[j] - top)
                total += p[j]
            oi[:] = 0.0
            for j in range(mk):
                pj, vj = p[j] / total, v[j, lo:hi]
                for t in range(dh):
                    oi[t] += pj * vj[t]


@njit(cache=True)
def _mha(xq, xkv, mq, mk, wq, bq, wk, bk, wv, bv, w_out, b_out, heads, out):
    """``nn.MultiheadAttention(xq, xkv, xkv)`` for B groups stacked as rows: xq (B*mq, d), xkv (B*mk, d)."""
    d = wq.shape[0]
    q = np.empty((xq.shape[0], d), np.float32)
    k = np.empty((xkv.shape[0], d), np.float32)
    v = np.empty((xkv.shape[0], d), np.float32)
    _matmul(xq, wq, bq, q, False)
    _matmul(xkv, wk, bk, k, False)
    _matmul(xkv, wv, bv, v, False)
    att = np.empty_like(q)
    for b in range(xq.shape[0] // mq):
        qs, ks = slice(b * mq, (b + 1) * mq), slice(b * mk, (b + 1) * mk)
        _attention(q[qs], k[ks], v[ks], heads, att[qs])
    _matmul(att, w_out, b_out, out, False)


@njit(cache=True)
def _step(x, bank, at_plan, terms_s, w_step, plan_s, half, w, action, new_bank, vec):
    """:func:`residual_step` on arrays; writes action (B, A), new_bank (B, M, d), vec (B, n)."""
    nb, m, d = bank.shape
    n = x.shape[1]
    # frame token (FrameEncoder.encode, vector branch) and the bank update
    for b in range(nb):
        for j in range(n):
            vec[b, j] = (x[b, j] - w.shift[j]) / w.scale[j]
    h1 = np.empty((nb, w.f1.shape[0]), np.float32)
    h2 = np.empty((nb, w.f2.shape[0]), np.float32)
    tok = np.empty((nb, d), np.float32)
    _matmul(vec, w.f1, w.f1b, h1, False)
    _gelu(h1)
    _matmul(h1, w.f2, w.f2b, h2, False)
    _gelu(h2)
    _matmul(h2, w.f3, w.f3b, tok, False)
    new_bank[:, : m - 1] = bank[:, 1:]
    new_bank[:, m - 1] = tok
    # DynamicFeatureExtractor.forward, the B histories stacked as B*M rows
    hh = np.empty((nb * m, d), np.float32)
    for b in range(nb):
        for i in range(m):
            for j in range(d):
                hh[b * m + i, j] = new_bank[b, i, j] + w.pos[i, j]
    tmp = np.empty_like(hh)
    sub = np.empty_like(hh)
    if w.use_temporal:  # nn.TransformerEncoderLayer: norm_first, ReLU, no dropout
        _layer_norm(hh, w.t_ln1, w.t_eps, tmp)
        _mha(tmp, tmp, m, m, w.t_q, w.t_qb, w.t_k, w.t_kb, w.t_v, w.t_vb, w.t_out, w.t_outb, w.heads, sub)
        hh += sub
        _layer_norm(hh, w.t_ln2, w.t_eps, tmp)
        ff = np.empty((nb * m, w.t_ff1.shape[0]), np.float32)
        _matmul(tmp, w.t_ff1, w.t_ff1b, ff, True)
        _matmul(ff, w.t_ff2, w.t_ff2b, sub, False)
        hh += sub
    if w.use_cross:  # diff cross-attention: the tokens query D = alpha (X_{k+1} - X_k)
        diff = np.empty((nb * (m - 1), d), np.float32)
        for b in range(nb):
            for i in range(m - 1):
                for j in range(d):
                    dk = w.alpha * (new_bank[b, i + 1, j] - new_bank[b, i, j])
                    diff[b * (m - 1) + i, j] = dk + w.diff_pos[i, j]
        kv = np.empty_like(diff)
        _layer_norm(diff, w.c_lnkv, w.c_eps, kv)
        _layer_norm(hh, w.c_lnq, w.c_eps, tmp)
        _mha(tmp, kv, m, m - 1, w.c_q, w.c_qb, w.c_k, w.c_kb, w.c_v, w.c_vb, w.c_out, w.c_outb, w.heads, sub)
        hh += sub
    pooled = np.empty((nb, 2 * d), np.float32)  # [mean over the M tokens, newest token]
    for b in range(nb):
        for j in range(d):
            s = 0.0
            for i in range(m):
                s += hh[b * m + i, j]
            pooled[b, j] = s / m
            pooled[b, d + j] = hh[b * m + m - 1, j]
    normed = np.empty_like(pooled)
    _layer_norm(pooled, w.p_ln, w.p_eps, normed)
    # ResidualHead.step: terms_s + [F, change] @ w_step, then the rest of the head
    step_in = np.empty((nb, d + n), np.float32)
    _matmul(normed, w.p_w, w.p_b, step_in[:, :d], False)
    for b in range(nb):
        for j in range(n):
            step_in[b, d + j] = w.change_scale * (vec[b, j] - at_plan[b, j])
    g1 = np.empty((nb, w_step.shape[0]), np.float32)
    _matmul(step_in, w_step, np.zeros(w_step.shape[0], np.float32), g1, False)
    g1 += terms_s
    _gelu(g1)
    g2 = np.empty((nb, w.h2.shape[0]), np.float32)
    _matmul(g1, w.h2, w.h2b, g2, False)
    _gelu(g2)
    delta = np.empty((nb, w.h3.shape[0]), np.float32)
    _matmul(g2, w.h3, w.h3b, delta, False)
    for b in range(nb):
        for j in range(delta.shape[1]):
            action[b, j] = plan_s[b, j] + delta[b, j] * half[j]


def residual_step(
    w: StepWeights,
    x: torch.Tensor,
    bank: torch.Tensor,
    at_plan: torch.Tensor,
    terms_s: torch.Tensor,
    w_step: np.ndarray,
    plan_s: torch.Tensor,
    half: np.ndarray,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One control step of the residual corrector on CPU: ``(action, new bank, standardised frame)``.

    Args:
        w: :func:`pack_weights` of the corrector.
        x: The frame's raw vector inputs, concatenated in ``FrameEncoder.state_keys`` order, (B, n).
        bank: History bank of frame tokens before this step, (B, M, d).
        at_plan: Standardised frame vector at plan time, (B, n).
        terms_s: ``ResidualHead.chunk_terms`` row of this step, (B, hidden).
        w_step: First-layer weights of the per-step inputs, (hidden, F + n) float32 array: the transpose of
            ``chunk_terms``' second output.
        plan_s: The planned action of this step, base-normalised, (B, A).
        half: Half the range of the base-normalised actions, float32 array (A,).
    """
    xs = [np.ascontiguousarray(t.numpy(), dtype=np.float32) for t in (x, bank, at_plan, terms_s, plan_s)]
    action = np.empty_like(xs[4])
    new_bank = np.empty_like(xs[1])
    vec = np.empty_like(xs[0])
    _step(xs[0], xs[1], xs[2], xs[3], w_step, xs[4], half, w, action, new_bank, vec)
    return torch.from_numpy(action), torch.from_numpy(new_bank), torch.from_numpy(vec)


def loaded() -> bool:
    """Whether this process has already loaded (or compiled) the kernel."""
    return bool(_step.signatures)


def warm_up(w: StepWeights) -> None:
    """Run the kernel once on zeros: the first call in a process loads it from numba's on-disk cache (~0.2 s)
    or compiles it (~15 s, once per machine), which should not land on a control step."""
    n, hidden, d = w.shift.shape[0], w.h2.shape[1], w.pos.shape[1]
    zeros = torch.zeros
    residual_step(
        w,
        zeros(1, n),
        zeros(1, w.pos.shape[0], d),
        zeros(1, n),
        zeros(1, hidden),
        np.zeros((hidden, d + n), np.float32),
        zeros(1, w.h3.shape[0]),
        np.ones(w.h3.shape[0], np.float32),
    )
