"""``dcdp-demo`` (``make demo``): the shipped diffusion base with and without its corrector on drifting PushT.

Ten episodes each (seeds 100000..100009) under a constant 2 px/step block drift (where a stale chunk costs
the base half its score), batch 10, for open loop, the training-free object-anchored chunk and DCDP; prints
the score/success/latency table and writes a plot and one side-by-side video under ``outputs/demo/``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from lerobot_dcdp.benchmark import shipped_model


def main(argv: list[str] | None = None) -> None:
    from lerobot_dcdp.benchmark import run

    p = argparse.ArgumentParser(prog="dcdp-demo", description=__doc__.splitlines()[0])
    p.add_argument(
        "--corrector",
        default=shipped_model("pusht-dcdp-state"),
        help="corrector folder to run (default: the shipped diffusion corrector)",
    )
    p.add_argument(
        "--condition", default="constant_2.0", help="PushT perturbation, e.g. constant_2.0 (the default)"
    )
    p.add_argument("--episodes", type=int, default=10, help="episodes per method, rolled out as one batch")
    p.add_argument("--out", default="outputs/demo", help="folder for the results, report, plot and video")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    out = Path(a.out)
    run.main(
        [
            "--model",
            f"diffusion={a.corrector}",
            "--methods",
            "open_loop",
            "object_anchored",
            "dcdp",
            "--conditions",
            a.condition,
            "--episodes",
            str(a.episodes),
            "--batch-size",
            str(a.episodes),
            "--latency-steps",
            "100",
            "--latency-rounds",
            "3",
            "--videos",
            "1",
            "--out",
            str(out / "benchmark.json"),
            "--report",
            str(out / "RESULTS.md"),
            "--force",
        ]
    )
    res = json.loads((out / "benchmark.json").read_text())
    print(
        f"\nPushT, {a.condition} block drift, {a.episodes} episodes (seeds 100000..), shipped diffusion base:"
    )
    print("| method | score | success | per-step latency (ms, batch 1) |\n|---|---|---|---|")
    for m in ("open_loop", "object_anchored", "dcdp"):
        c, lat = res["cells"][f"diffusion|{m}|{a.condition}"], res["latency"].get(f"diffusion|{m}", {})
        print(
            f"| {m} | {c['score']:.3f} | {100 * c['success_rate']:.0f} % "
            f"| {lat.get('mean_ms', float('nan')):.2f} |"
        )
    videos = sorted((out / "videos").glob("*.mp4"))
    print(
        f"\nplot: {out / 'score_vs_drift.png'}; video: {videos[0] if videos else '-'}; "
        f"wall time {time.perf_counter() - t0:.0f} s"
    )


if __name__ == "__main__":
    main()
