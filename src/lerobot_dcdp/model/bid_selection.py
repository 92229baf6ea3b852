"""Bidirectional Decoding's chunk selection (BID, Liu et al., ICLR 2025), as pure functions.

At a decision step the base samples ``N`` candidate chunks (and a weak reference policy ``M``). BID keeps the
candidate that is

- **backward coherent**: close to what the previously chosen chunk still planned for the same steps (the
  previous chunk shifted by the steps executed since), distance per step weighted by ``decay ** j``
  (normalised to sum 1), which keeps the ``N // n_mode`` nearest candidates of each policy; and
- **forward contrastive**: close to the other kept strong candidates (the mean distance to its
  ``K // 2`` nearest, itself excluded) and far from the kept weak ones (the mean distance to its
  ``K_w // 2`` nearest);

the candidate with the smallest ``coherence + positive - negative`` is executed. Distances are the Euclidean
norm of each step's action difference, averaged over the steps (``decay``-weighted for coherence). Our
negative term is the paper's per-candidate one: the authors' code indexes it by weak sample instead.
"""

from __future__ import annotations

import torch
from torch import Tensor


def coherence_distance(candidates: Tensor, prior: Tensor, decay: float) -> Tensor:
    """Each candidate's ``decay``-weighted mean per-step distance to ``prior`` over the steps both plan.

    Args:
        candidates: (B, N, L, A) chunks planned from the current step.
        prior: (B, P, A) what the previous decision still planned from the current step on (P <= L).
        decay: Weight ratio of consecutive steps (the nearest step weighs most when < 1).

    Returns:
        (B, N) distances.
    """
    steps = min(prior.shape[1], candidates.shape[2])
    weights = decay ** torch.arange(steps, dtype=candidates.dtype, device=candidates.device)
    weights = weights / weights.sum()
    dist = (candidates[:, :, :steps] - prior[:, None, :steps]).norm(dim=-1)  # (B, N, steps)
    return (dist * weights).sum(dim=-1)


def pairwise_distance(a: Tensor, b: Tensor) -> Tensor:
    """Mean per-step Euclidean distance between every chunk of ``a`` (B, N, L, A) and of ``b`` (B, M, L, A):
    (B, N, M)."""
    return (a[:, :, None] - b[:, None]).norm(dim=-1).mean(dim=-1)


def nearest_mean(dist: Tensor, k: int, skip_first: bool = False) -> Tensor:
    """Mean of the ``k`` smallest entries of each row of ``dist`` (B, N, M) -> (B, N); ``skip_first`` drops
    the smallest first (a candidate's zero distance to itself)."""
    start = 1 if skip_first else 0
    k = max(1, min(k, dist.shape[-1] - start))
    return dist.sort(dim=-1).values[..., start : start + k].mean(dim=-1)


def keep_nearest(candidates: Tensor, dist: Tensor, keep: int) -> tuple[Tensor, Tensor]:
    """The ``keep`` candidates (B, keep, L, A) of smallest ``dist`` (B, N) and their distances (B, keep)."""
    keep = max(1, min(keep, candidates.shape[1]))
    idx = dist.topk(keep, dim=-1, largest=False).indices
    picked = candidates.gather(1, idx[:, :, None, None].expand(-1, -1, *candidates.shape[2:]))
    return picked, dist.gather(1, idx)


def bid_select(
    strong: Tensor,
    weak: Tensor | None,
    prior: Tensor | None,
    decay: float,
    n_mode: int,
) -> Tensor:
    """The chunk BID executes, (B, L, A).

    Args:
        strong: (B, N, L, A) candidates of the base.
        weak: (B, M, L, A) candidates of the weak reference policy, or None (no forward negative term).
        prior: (B, P, A) the previous decision's chunk from the current step on, or None (first decision:
            no coherence term, every candidate kept).
        decay: Coherence weight ratio of consecutive steps.
        n_mode: The coherence filter keeps ``N // n_mode`` candidates of each policy.
    """
    coherence = torch.zeros(strong.shape[:2], dtype=strong.dtype, device=strong.device)
    if prior is not None:
        to_prior = coherence_distance(strong, prior, decay)
        strong, coherence = keep_nearest(strong, to_prior, strong.shape[1] // n_mode)
        if weak is not None:
            weak, _ = keep_nearest(weak, coherence_distance(weak, prior, decay), weak.shape[1] // n_mode)
    kept = strong.shape[1]
    score = coherence
    if kept > 1:
        score = score + nearest_mean(pairwise_distance(strong, strong), kept // 2, skip_first=True)
    if weak is not None:
        score = score - nearest_mean(pairwise_distance(strong, weak), max(1, weak.shape[1] // 2))
    best = score.argmin(dim=-1)
    return strong[torch.arange(strong.shape[0], device=strong.device), best]
