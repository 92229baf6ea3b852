"""How large a recorded corrections dataset's labels are, by the chunk's delay and step.

For every frame of a ``dcdp-record-corrections`` dataset: the label (``action``) minus the plan's entry
for the frame's step s (``observation.dcdp_plan`` at ``observation.dcdp_plan_step``), in raw action units
(px on PushT). Episodes whose every label is the plan (the still episodes of a gated teacher) are counted and
left out of the per-delay rows, which give the mean and 90th percentile correction and the mean at each
step s. A dataset without ``observation.dcdp_plan_delay`` (recorded on time) is all d = 0.

Usage: python scripts/correction_stats.py data/pusht_corrections_late [more dataset roots]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd


def _column(df: pd.DataFrame, key: str) -> np.ndarray:
    return np.stack([np.atleast_1d(v) for v in df[key].to_numpy()])


def correction_table(root: Path) -> str:
    """Markdown lines of the label sizes of the dataset at ``root``."""
    files = sorted((root / "data").glob("*/*.parquet"))
    if not files:
        raise SystemExit(f"{root}: no data/*/*.parquet files (not a LeRobot dataset root?)")
    df = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)
    missing = [k for k in ("observation.dcdp_plan", "observation.dcdp_plan_step", "action") if k not in df]
    if missing:
        raise SystemExit(f"{root}: not a recorded corrections dataset, it lacks {missing}")
    n = len(df)
    steps = _column(df, "observation.dcdp_plan_step")[:, 0].astype(int)
    action = _column(df, "action")
    plans = _column(df, "observation.dcdp_plan").reshape(n, -1, action.shape[1])
    delays = (
        _column(df, "observation.dcdp_plan_delay")[:, 0].astype(int)
        if "observation.dcdp_plan_delay" in df
        else np.zeros(n, dtype=int)
    )
    corr = np.linalg.norm(action - plans[np.arange(n), steps], axis=1)
    episode = df["episode_index"].to_numpy()
    per_episode = pd.Series(corr).groupby(episode).max()
    corrected = per_episode.reindex(episode).to_numpy() > 0
    horizon = int(steps.max()) + 1
    lines = [
        f"`{root}`: {n} frames, {per_episode.size} episodes ({int((per_episode == 0).sum())} with every "
        f"label the plan); correction mean {corr.mean():.2f}, p90 {np.percentile(corr, 90):.2f}",
        "",
        "| delay d | frames (corrected episodes) | mean | p90 | mean at s = "
        + ", ".join(map(str, range(horizon)))
        + " |",
        "|---|---|---|---|---|",
    ]
    for d in range(int(delays.max()) + 1):
        sel = corrected & (delays == d)
        if not sel.any():
            continue
        by_step = [
            corr[sel & (steps == s)].mean() if (sel & (steps == s)).any() else np.nan for s in range(horizon)
        ]
        lines.append(
            f"| {d} | {int(sel.sum())} | {corr[sel].mean():.2f} | {np.percentile(corr[sel], 90):.2f} | "
            + " / ".join(f"{v:.1f}" for v in by_step)
            + " |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "roots", nargs="+", type=Path, help="dataset roots written by dcdp-record-corrections"
    )
    for root in parser.parse_args().roots:
        print(correction_table(root), end="\n\n")


if __name__ == "__main__":
    main()
