"""Where the failed episodes end under a constant drift: the block's offset from the goal along the drift.

Runs one constant-drift condition (``near_misses.condition_rollout``: a benchmark condition or
``unseen_check.py``'s ``constant:<px>:<deg>``) with a folder in one execution mode and, for every episode that
does not succeed, prints over its last ``--last`` steps the block's mean offset from the goal pose along the
drift direction (+: downstream) and across it, its spread along the drift, its angle error, and the agent's
mean offset from the block along the drift (+: the agent is downstream of the block, where it can hold the
block against the drift). Then the medians over the failed episodes, and how often (from step 30 on) the
scene lead's estimate of the world's motion was within 20 % of the drift the env applied. A finish that
settles downstream of the goal wanted a longer scene lead; one that settles upstream, a shorter one
(docs/ANALYSIS.md, "Drift directions the tables never use").

Usage: .venv/bin/python scripts/finish_offsets.py --policy models/pusht-act-state-anchored-gated
           --condition constant:0.5:0 [--direction 45] [--seed-start 300000] [--episodes 30]
           [--method gated_anchored] [--lead-steps 8] [--last 100]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def drift_direction(condition: str, default: float) -> float:
    """The drift's direction in degrees: from ``constant:<px>:<deg>``, else ``default`` (the benchmark's
    constant conditions drift at 45 degrees).

    Raises:
        ValueError: a random or static condition (no single direction).
    """
    if condition.startswith(("random", "static")):
        raise ValueError(f"{condition!r}: a constant drift has one direction; this one has none or many")
    parts = condition.split(":")
    return float(parts[2]) if len(parts) == 3 else default


def main() -> None:
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep
    from lerobot_dcdp.pusht.geometry import GOAL_POSE

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True)
    p.add_argument("--condition", default="constant:0.5:0")
    p.add_argument("--direction", type=float, default=45.0, help="for the benchmark's named conditions")
    p.add_argument("--seed-start", type=int, default=300_000)
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--method", default="gated_anchored")
    p.add_argument("--lead-steps", type=int, help="override the folder's scene lead")
    p.add_argument("--last", type=int, default=100, help="steps at the end of an episode to average over")
    a = p.parse_args()
    torch.set_num_threads(1)
    angle = np.radians(drift_direction(a.condition, a.direction))
    along = np.array([np.cos(angle), np.sin(angle)])
    across = np.array([-along[1], along[0]])

    policy, _, planned, envs, seeds = condition_rollout(
        a.policy, a.condition, a.episodes, a.method, a.seed_start, lead_steps=a.lead_steps
    )
    poses: dict[int, list] = {i: [] for i in range(len(seeds))}
    agents: dict[int, list] = {i: [] for i in range(len(seeds))}
    lead_hits: list[bool] = []  # per step from step 30 on: the lead's world motion within 20 % of the drift
    motion = {}

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        action = planned(obs, active)
        motion["now"] = None if policy.lead._motion is None else policy.lead._motion.cpu().numpy()
        return action

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        poses[i].append(np.asarray(info["block_pose"], dtype=float))
        agents[i].append(np.asarray(obs["agent_pos"], dtype=float))
        drift = np.asarray(info["perturbation_offset"], dtype=float)
        if len(poses[i]) > 30 and motion["now"] is not None and np.hypot(*drift) > 0:
            lead_hits.append(bool(np.hypot(*(motion["now"][i] - drift)) <= 0.2 * np.hypot(*drift)))

    out = run_lockstep(envs, seeds, act, 300, on_step)
    rows = []
    for i, seed in enumerate(seeds):
        if out.successes[i]:
            continue
        pose, agent = np.array(poses[i][-a.last :]), np.array(agents[i][-a.last :])
        offset = pose[:, :2] - GOAL_POSE[:2]
        turn = np.degrees((pose[:, 2] - GOAL_POSE[2] + np.pi) % (2 * np.pi) - np.pi)
        row = (
            (offset @ along).mean(),
            (offset @ across).mean(),
            (offset @ along).std(),
            turn.mean(),
            ((agent - pose[:, :2]) @ along).mean(),
        )
        rows.append(row)
        print(
            f"seed {seed}: best {out.max_rewards[i]:.3f}, block along the drift {row[0]:+6.1f} "
            f"(sd {row[2]:4.1f}) across {row[1]:+6.1f}, angle {row[3]:+5.1f} deg, "
            f"agent - block along the drift {row[4]:+6.1f}"
        )
    print(f"{a.policy} {a.condition} {a.method}: {100 * np.mean(out.successes):.0f} % success")
    if lead_hits:
        print(
            f"the lead's world motion within 20 % of the env's drift on {100 * np.mean(lead_hits):.1f} % of "
            f"{len(lead_hits)} steps (from step 30 on; the env's clipped drift counted as the drift)"
        )
    if rows:
        m = np.median(rows, axis=0)
        print(
            f"{len(rows)} failed, medians: block along the drift {m[0]:+.1f} (+: downstream), across "
            f"{m[1]:+.1f}, angle {m[3]:+.1f} deg, agent - block along the drift {m[4]:+.1f}"
        )


if __name__ == "__main__":
    main()
