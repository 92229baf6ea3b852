"""Compare dcdp-benchmark cells of two result files on the seeds they share (screens vs the main table).

Usage: python scripts/compare_cells.py results/benchmark.json diffusion runs/screens/x.json demos \
           --methods open_loop object_anchored dcdp --conditions static constant_2.0
Prints, per condition, the score and success of each (file, label, method) on the common seeds.
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def _seeds(cell: dict) -> list[int]:
    """A cell stores its seeds as [first, last] (consecutive, one episode each)."""
    first, last = cell["seeds"]
    return list(range(first, last + 1))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("base_file")
    p.add_argument("base_label")
    p.add_argument("new_file")
    p.add_argument("new_label")
    p.add_argument("--methods", nargs="+", default=["open_loop", "object_anchored"])
    p.add_argument("--new-methods", nargs="+", default=["dcdp"])
    p.add_argument("--conditions", nargs="+", required=True)
    a = p.parse_args()
    base = json.load(open(a.base_file))["cells"]
    new = json.load(open(a.new_file))["cells"]
    for cond in a.conditions:
        rows = [(a.base_label, m, base.get(f"{a.base_label}|{m}|{cond}")) for m in a.methods]
        rows += [(a.new_label, m, new.get(f"{a.new_label}|{m}|{cond}")) for m in a.new_methods]
        rows = [r for r in rows if r[2]]
        seeds = set.intersection(*(set(_seeds(c)) for _, _, c in rows))
        print(f"{cond} ({len(seeds)} common seeds)")
        for label, method, cell in rows:
            keep = [i for i, s in enumerate(_seeds(cell)) if s in seeds]
            r = np.asarray(cell["max_rewards"])[keep]
            ok = np.asarray(cell["successes"], dtype=float)[keep]
            se = r.std(ddof=1) / np.sqrt(len(r)) if len(r) > 1 else 0.0
            score = f"score {r.mean():.3f} +- {se:.3f}"
            print(f"  {label:>10s} {method:16s} {score}  success {100 * ok.mean():3.0f} %")


if __name__ == "__main__":
    main()
