"""Standard errors of a cell's score and success rate, and of the difference between two cells."""

from __future__ import annotations

import numpy as np


def score_se(cell: dict) -> float:
    """Standard error of the mean score over the cell's episodes (NaN for a single episode)."""
    x = np.asarray(cell.get("max_rewards") or [cell["score"]], dtype=float)
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def success_se(cell: dict) -> float:
    """Standard error of the success rate (binomial), in the rate's units."""
    p, n = cell["success_rate"], cell.get("episodes", 1)
    return (p * (1 - p) / n) ** 0.5


def paired_diff(new: dict, old: dict, key: str) -> tuple[float, float]:
    """Mean of ``new - old`` over the episodes and its standard error.

    The difference is paired over the seeds when both cells ran the same seeds, else taken from the two
    cells' means with their own standard errors combined.

    Args:
        new: The cell compared.
        old: The cell it is compared against.
        key: ``"max_rewards"`` (score) or ``"successes"`` (success rate).

    Returns:
        ``(mean difference, its standard error)``.
    """
    a = np.asarray(new.get(key) or [], dtype=float)
    b = np.asarray(old.get(key) or [], dtype=float)
    if len(a) == len(b) > 1 and new.get("seeds") == old.get("seeds"):
        d = a - b
        return float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d)))
    if key == "successes":
        return new["success_rate"] - old["success_rate"], (success_se(new) ** 2 + success_se(old) ** 2) ** 0.5
    return new["score"] - old["score"], (score_se(new) ** 2 + score_se(old) ** 2) ** 0.5
