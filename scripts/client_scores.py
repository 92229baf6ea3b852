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
    """Finished episodes by seed, pooled over ``paths`` (an absent file: none; a last line cut off by a killed
    client is skipped).

    Raises:
        ValueError: an episode without a seed (the robot ran unseeded) or a seed found twice.
    """
    out: dict[int, dict] = {}
    for path in paths:
        if not path.exists():
            continue
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            try:
                e = json.loads(line)
            except json.JSONDecodeError:
                if i == len(lines) - 1:
                    continue
                raise
            if e.get("seed") is None or e["seed"] in out:
                raise ValueError(f"{path}: episodes must have distinct seeds (--robot.seed), got {e}")
            out[e["seed"]] = e
    return out


def mean_se(values: list[float]) -> tuple[float, float]:
    """Mean and its standard error (NaN where undefined)."""
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
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    main([Path(d) for d in sys.argv[1].split(",")], sys.argv[2:])
