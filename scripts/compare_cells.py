"""Compare dcdp-benchmark cells of two result files on the seeds they share (screens vs the main table).

Usage: python scripts/compare_cells.py results/benchmark.json diffusion runs/screens/x.json demos \
           --methods open_loop object_anchored dcdp --conditions static constant_2.0
Prints, per condition, the score and success of each (file, label, method) on the common seeds, and each new
method minus each stored method, paired by seed (score and success points, with their standard errors), then
those differences pooled over the conditions.
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
    pooled: dict[tuple[str, str], list[np.ndarray]] = {}
    for cond in a.conditions:
        # keyed by file too: the same label and method in both files (a cell rerun) are two rows
        rows = [("base", a.base_label, m, base.get(f"{a.base_label}|{m}|{cond}")) for m in a.methods]
        rows += [("new", a.new_label, m, new.get(f"{a.new_label}|{m}|{cond}")) for m in a.new_methods]
        rows = [r for r in rows if r[3]]
        seeds = set.intersection(*(set(_seeds(c)) for *_, c in rows))
        print(f"{cond} ({len(seeds)} common seeds)")
        got = {}
        for role, label, method, cell in rows:
            pairs = zip(cell["max_rewards"], cell["successes"], strict=True)
            by_seed = dict(zip(_seeds(cell), pairs, strict=True))
            r = np.asarray([by_seed[s][0] for s in sorted(seeds)], dtype=float)
            ok = np.asarray([by_seed[s][1] for s in sorted(seeds)], dtype=float)
            got[role, method] = r, ok
            se = r.std(ddof=1) / np.sqrt(len(r)) if len(r) > 1 else 0.0
            score = f"score {r.mean():.3f} +- {se:.3f}"
            print(f"  {label:>10s} {method:16s} {score}  success {100 * ok.mean():3.0f} %")
        for method in a.new_methods:
            if ("new", method) not in got or len(seeds) < 2:
                continue
            r_new, ok_new = got["new", method]
            for ref in a.methods:
                if ("base", ref) not in got:
                    continue
                dr = r_new - got["base", ref][0]
                dok = 100 * (ok_new - got["base", ref][1])
                pooled.setdefault((method, ref), []).append(np.stack([dr, dok]))
                n = len(dr)
                print(
                    f"    {a.new_label} {method} - {a.base_label} {ref}: score {dr.mean():+.3f} +- "
                    f"{dr.std(ddof=1) / np.sqrt(n):.3f}, success {dok.mean():+.0f} +- "
                    f"{dok.std(ddof=1) / np.sqrt(n):.0f} points (paired)"
                )

    for (method, ref), diffs in pooled.items():
        if len(diffs) > 1:  # every (condition, seed) pair of the conditions above
            dr, dok = np.concatenate(diffs, axis=1)
            n = len(dr)
            print(
                f"pooled over {len(diffs)} conditions ({n} pairs): {a.new_label} {method} - {a.base_label} "
                f"{ref}: score {dr.mean():+.3f} +- {dr.std(ddof=1) / np.sqrt(n):.3f}, success "
                f"{dok.mean():+.1f} +- {dok.std(ddof=1) / np.sqrt(n):.1f} points"
            )


if __name__ == "__main__":
    main()
