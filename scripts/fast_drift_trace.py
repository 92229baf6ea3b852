"""Where a fast-drift episode's score is made or lost: per episode, how near the block came and where it went.

Runs one condition (``near_misses.condition_rollout``: a benchmark condition or ``unseen_check.py``'s
``constant:<px>:<deg>`` / ``random:<px>``) with a folder in one or more execution modes on the same seeds and,
for each episode, prints the best coverage and the step it came at, the block's nearest approach to the goal
(mean keypoint distance), the share of steps the drift was clipped by the arena's wall (the block pinned at a
wall), the share of steps the agent was within 40 px of the block's centre (in reach of it), and the block's
mean keypoint distance to the goal over the last 50 steps, and how far the commanded target lay upstream of
the agent along the drift over the last 100 steps (a push against the drift). Then, per mode, the means, and
the paired score difference of every later mode against the first, with the seeds it moves most.

Usage: .venv/bin/python scripts/fast_drift_trace.py --policy models/pusht-dcdp-act-state-demos-late-gated
           --condition constant_2.0 --methods gated_anchored dcdp [--episodes 50] [--seed-start 100000]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def trace(policy: str, condition: str, episodes: int, method: str, seed_start: int) -> dict[str, np.ndarray]:
    """One rollout of ``method``; per-episode arrays keyed by what they hold."""
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep
    from lerobot_dcdp.pusht.geometry import GOAL_KP, keypoints

    _, _, planned, envs, seeds = condition_rollout(policy, condition, episodes, method, seed_start)
    n = len(seeds)
    last_action: dict[str, np.ndarray] = {}

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        last_action["now"] = planned(obs, active)
        return last_action["now"]

    cover: dict[int, list] = {i: [] for i in range(n)}
    dist: dict[int, list] = {i: [] for i in range(n)}
    pinned = np.zeros(n)
    reach = np.zeros(n)
    push: dict[int, list] = {i: [] for i in range(n)}

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        pose = np.asarray(info["block_pose"], dtype=float)
        cover[i].append(info["coverage"])
        dist[i].append(float(np.linalg.norm(keypoints(pose) - GOAL_KP, axis=-1).mean()))
        pinned[i] += bool(np.any(info.get("perturbation_clipped", False)))
        reach[i] += np.hypot(*(np.asarray(obs["agent_pos"], dtype=float) - pose[:2])) < 40.0
        drift = np.asarray(info["perturbation_offset"], dtype=float)
        if np.hypot(*drift) > 0:  # how far the commanded target lies upstream of the agent, along the drift
            up = -drift / np.hypot(*drift)
            agent = np.asarray(obs["agent_pos"], dtype=float)
            push[i].append(float((last_action["now"][i, :2] - agent) @ up))

    out = run_lockstep(envs, seeds, act, 300, on_step)
    steps = np.array([len(cover[i]) for i in range(n)])
    return {
        "seed": np.array(seeds),
        "score": np.array(out.max_rewards),
        "success": np.array(out.successes, dtype=float),
        "best_step": np.array([int(np.argmax(cover[i])) + 1 for i in range(n)]),
        "nearest": np.array([min(dist[i]) for i in range(n)]),
        "last50": np.array([np.mean(dist[i][-50:]) for i in range(n)]),
        "pinned": pinned / steps,
        "reach": reach / steps,
        "steps": steps,
        "push": np.array([np.mean(push[i][-100:]) if push[i] else np.nan for i in range(n)]),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True)
    p.add_argument("--condition", default="constant_2.0")
    p.add_argument("--methods", nargs="+", default=["gated_anchored", "dcdp"])
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--seed-start", type=int, default=100_000)
    p.add_argument("--quiet", action="store_true", help="only the means and the paired differences")
    a = p.parse_args()
    torch.set_num_threads(1)
    runs = {m: trace(a.policy, a.condition, a.episodes, m, a.seed_start) for m in a.methods}
    for m, r in runs.items():
        if not a.quiet:
            for j, seed in enumerate(r["seed"]):
                print(
                    f"{m} seed {seed}: score {r['score'][j]:.3f} at step {r['best_step'][j]:3d}, "
                    f"nearest {r['nearest'][j]:6.1f} px, last 50 {r['last50'][j]:6.1f} px, "
                    f"pinned {100 * r['pinned'][j]:3.0f} %, agent in reach {100 * r['reach'][j]:3.0f} %, "
                    f"target upstream {r['push'][j]:+5.1f} px"
                )
        print(
            f"{m}: score {r['score'].mean():.3f}, success {100 * r['success'].mean():.0f} %, "
            f"nearest {np.median(r['nearest']):.1f} px (median), last 50 {np.median(r['last50']):.1f} px, "
            f"pinned {100 * r['pinned'].mean():.0f} % of steps (episodes > 10 %: "
            f"{int((r['pinned'] > 0.1).sum())}), agent in reach {100 * r['reach'].mean():.0f} %"
        )
        low = r["score"] < 0.7
        if low.any():
            print(
                f"{m}: {int(low.sum())} episodes below 0.7: pinned {100 * r['pinned'][low].mean():.0f} %, "
                f"in reach {100 * r['reach'][low].mean():.0f} %, "
                f"nearest {np.median(r['nearest'][low]):.1f} px; "
                f"the rest: pinned {100 * r['pinned'][~low].mean():.0f} %, "
                f"in reach {100 * r['reach'][~low].mean():.0f} %"
            )
    first, r0 = next(iter(runs.items()))
    for m1, r1 in list(runs.items())[1:]:
        d = r1["score"] - r0["score"]
        order = np.argsort(d)
        print(
            f"{m1} - {first}: score {d.mean():+.3f} ± {d.std(ddof=1) / np.sqrt(len(d)):.3f} (paired), "
            f"success {100 * (r1['success'] - r0['success']).mean():+.1f} points; "
            f"per seed, the score moves by more than 0.3 in {int((np.abs(d) > 0.3).sum())} of {len(d)}"
        )
        print("largest losses: " + ", ".join(f"{r0['seed'][j]} {d[j]:+.2f}" for j in order[:8]))
        print("largest gains: " + ", ".join(f"{r0['seed'][j]} {d[j]:+.2f}" for j in order[::-1][:8]))


if __name__ == "__main__":
    main()
