"""Pooled paired difference of two methods over several conditions of one dcdp-benchmark results file.

Usage: python scripts/pool_cells.py results/benchmark_mild.json diffusion_demos dcdp open_loop \
           --conditions constant_0.5 random_0.5 constant_0.75 random_0.75 constant_1.0 random_1.0 \
           [--old-label diffusion]   (OLD's cells from another label, e.g. the base's open loop)
Prints the mean of (new - old) over every (condition, seed) pair, in success points and score, ± its s.e.
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def pooled(
    cells: dict, label: str, new: str, old: str, conditions: list[str], key: str, old_label: str | None = None
) -> np.ndarray:
    """Per-episode ``new - old`` of ``key`` (``successes`` or ``max_rewards``), all conditions concatenated
    (``old`` read from ``old_label``'s cells when given: e.g. the open loop of another corrector's base).

    Raises:
        ValueError: when a condition's two cells ran different seeds.
    """
    out = []
    for c in conditions:
        a, b = cells[f"{label}|{new}|{c}"], cells[f"{old_label or label}|{old}|{c}"]
        if a["seeds"] != b["seeds"]:
            raise ValueError(f"{c}: {new} ran seeds {a['seeds']}, {old} ran {b['seeds']}")
        out.append(np.asarray(a[key], dtype=float) - np.asarray(b[key], dtype=float))
    return np.concatenate(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("file")
    p.add_argument("label")
    p.add_argument("new")
    p.add_argument("old")
    p.add_argument("--conditions", nargs="+", required=True)
    p.add_argument("--old-label", default=None, help="the label whose cells hold OLD (default: LABEL)")
    a = p.parse_args()
    cells = json.load(open(a.file))["cells"]
    s = pooled(cells, a.label, a.new, a.old, a.conditions, "successes", a.old_label)
    r = pooled(cells, a.label, a.new, a.old, a.conditions, "max_rewards", a.old_label)
    n = len(s)
    old = f"{a.old_label} {a.old}" if a.old_label else a.old
    print(
        f"{a.label}: {a.new} - {old} over {len(a.conditions)} conditions ({n} paired episodes): "
        f"success {100 * s.mean():+.1f} ± {100 * s.std(ddof=1) / np.sqrt(n):.1f} points, "
        f"score {r.mean():+.3f} ± {r.std(ddof=1) / np.sqrt(n):.3f}"
    )


if __name__ == "__main__":
    main()
