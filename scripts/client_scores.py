"""Table of scripts/client_scores.sh: per fps, the stock RobotClient's and dcdp-robot-client's episodes
(``<client>_<fps>.jsonl`` written by the pusht_sim robot), score ± s.e. and success, and their difference
on the seeds both finished. Usage: python scripts/client_scores.py <out dir>[,<out dir>...] <fps> [<fps> ...]
(several folders: runs of the script on other seeds, pooled by seed)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def load(paths: list[Path]) -> dict[int, dict]:
    """Finished episodes by seed, pooled over ``paths`` (an absent file: none)."""
    out: dict[int, dict] = {}
    for path in paths:
        if path.exists():
            out.update({e["seed"]: e for e in map(json.loads, path.read_text().splitlines())})
    return out


def mean_se(values: list[float]) -> tuple[float, float]:
    n = len(values)
    if n == 0:
        return math.nan, math.nan
    m = sum(values) / n
    se = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1) / n) if n > 1 else math.nan
    return m, se


CLIENTS = {
    "stock": "stock RobotClient, base alone",
    "dcdp": "dcdp-robot-client",
    "dcdp_hold": "dcdp-robot-client, ticks_per_step = fps / 10",
}


def main(outs: list[Path], rates: list[str]) -> None:
    print("| fps | client | episodes | score ± s.e. | success | minus stock, same seeds (n) |")
    print("|---|---|---|---|---|---|")
    for fps in rates:
        runs = {c: load([out / f"{c}_{fps}.jsonl" for out in outs]) for c in CLIENTS}
        for client, name in CLIENTS.items():
            eps = list(runs[client].values())
            if not eps:
                continue
            m, se = mean_se([e["score"] for e in eps])
            succ = 100 * sum(e["success"] for e in eps) / len(eps)
            extra = ""
            common = sorted(set(runs["stock"]) & set(runs[client]))
            if client != "stock" and common:
                d, d_se = mean_se([runs[client][s]["score"] - runs["stock"][s]["score"] for s in common])
                extra = f"{d:+.3f} ± {d_se:.3f} ({len(common)})"
            print(f"| {fps} | {name} | {len(eps)} | {m:.3f} ± {se:.3f} | {succ:.0f} % | {extra} |")


if __name__ == "__main__":
    main([Path(d) for d in sys.argv[1].split(",")], sys.argv[2:])
