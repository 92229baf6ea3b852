"""Trace: where a method loses success under mild drift -- reaching the goal region, or finishing inside it.

Runs one benchmark condition (same envs, seeds and seeding as ``near_misses.py``) for each method and records,
per episode, whether and when the block first came within ``--radius`` px and ``--angle`` degrees of the goal
pose (the goal region), how many steps it spent there, how often it left it again, whether the episode
succeeded, and the mean size of the correction (executed action minus the base's planned action, px) on steps
inside and outside the region. Prints one row per method and, for each method against the first one (open
loop by default), the paired seeds where the first succeeds and the method fails: did the method reach the
region, and how late. ``--out`` writes the per-episode records as JSON.

Usage: .venv/bin/python scripts/goal_region_trace.py [--policy models/pusht-dcdp-state-demos]
           [--condition constant_0.5 | constant:0.6:300] [--episodes 100] [--seed-start 100000]
           [--methods open_loop object_anchored dcdp] [--radius 20] [--angle 20]
           [--out runs/screens/goal_region.json]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile

import numpy as np
import torch


def trace(args: argparse.Namespace, method: str) -> list[dict]:
    """Per-episode goal-region records of one method on ``args.condition``."""
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep

    rollout = condition_rollout(args.policy, args.condition, args.episodes, method, args.seed_start)
    policy, post, corrected, envs, seeds = rollout
    n = len(seeds)
    near = np.zeros(n, dtype=bool)
    rec = [
        {"seed": s, "entry_step": None, "steps_in": 0, "exits": 0, "corr_in": [], "corr_out": [], "t": 0}
        for s in seeds
    ]

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        action = corrected(obs, active)
        if policy.planned_chunk is not None:
            planned = post(policy.planned_chunk).cpu().numpy()[:, policy.last_step]
            size = np.linalg.norm(action - planned, axis=-1)
            for i in np.flatnonzero(active):
                rec[i]["corr_in" if near[i] else "corr_out"].append(float(size[i]))
        return action

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        b, g = info["block_pose"], info["goal_pose"]
        turn = np.degrees(abs((b[2] - g[2] + np.pi) % (2 * np.pi) - np.pi))
        now = bool(np.hypot(b[0] - g[0], b[1] - g[1]) < args.radius and turn < args.angle)
        r = rec[i]
        if now and r["entry_step"] is None:
            r["entry_step"] = r["t"]
        r["steps_in"] += int(now)
        r["exits"] += int(near[i] and not now)
        r["t"] += 1
        near[i] = now

    out = run_lockstep(envs, seeds, act, 300, on_step)
    for env in envs:
        env.close()
    for r, ok, score in zip(rec, out.successes, out.max_rewards, strict=True):
        r["success"] = bool(ok)
        r["score"] = float(score)
        for k in ("corr_in", "corr_out"):
            r[k] = float(np.mean(r[k])) if r[k] else None
    return rec


def summary(rec: list[dict]) -> str:
    """One table row: success, reached the region, median entry step, success given reached, steps in,
    episodes that left it again, mean correction in / out."""
    reached = [r for r in rec if r["entry_step"] is not None]
    med = lambda xs: float(np.median(xs)) if xs else float("nan")  # noqa: E731
    corr = [med([r[k] for r in rec if r[k] is not None]) for k in ("corr_in", "corr_out")]
    return " | ".join(
        [
            f"{100 * np.mean([r['success'] for r in rec]):.0f} %",
            f"{len(reached)}/{len(rec)}",
            f"{med([r['entry_step'] for r in reached]):.0f}",
            f"{100 * np.mean([r['success'] for r in reached]) if reached else float('nan'):.0f} %",
            f"{med([r['steps_in'] for r in reached]):.0f}",
            f"{sum(r['exits'] > 0 for r in reached)}",
            f"{corr[0]:.2f} / {corr[1]:.2f}",
        ]
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state-demos")
    p.add_argument("--condition", default="constant_0.5")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed-start", type=int, default=100_000)
    p.add_argument("--methods", nargs="+", default=["open_loop", "object_anchored", "dcdp"])
    p.add_argument("--radius", type=float, default=20.0)
    p.add_argument("--angle", type=float, default=20.0)
    p.add_argument("--out", default=None)
    a = p.parse_args()
    torch.set_num_threads(1)
    records = {}
    print(
        f"| {a.condition}, {a.episodes} seeds | success | reached the region | median entry step "
        "| success when reached | median steps in | left it again | median correction in / out px |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for method in a.methods:
        records[method] = trace(a, method)
        print(f"| {method} | {summary(records[method])} |", flush=True)
    ref = a.methods[0]
    for method in a.methods[1:]:
        pairs = zip(records[ref], records[method], strict=True)
        lost = [(r0, r) for r0, r in pairs if r0["success"] and not r["success"]]
        never = sum(r["entry_step"] is None for _, r in lost)
        later = [r["entry_step"] - r0["entry_step"] for r0, r in lost if r["entry_step"] is not None]
        print(
            f"{ref} succeeds, {method} fails: {len(lost)} seeds; "
            f"{method} never reached the region on {never}; "
            f"entered later by a median of {np.median(later) if later else float('nan'):.0f} steps "
            f"(steps in region: {ref} {np.median([r0['steps_in'] for r0, _ in lost]) if lost else 0:.0f}, "
            f"{method} {np.median([r['steps_in'] for _, r in lost]) if lost else 0:.0f})"
        )
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(a.out)), suffix=".json")
        with os.fdopen(fd, "w") as f:
            json.dump({"args": vars(a), "records": records}, f, indent=1)
        os.replace(tmp, a.out)


if __name__ == "__main__":
    main()
