"""Probe: does correcting the chunk near the goal cost the final alignment? (privileged; a diagnosis aid)

Runs one benchmark condition (same envs, seeds and seeding as ``near_misses.py``) with a corrector's
execution mode (``object_anchored`` or ``dcdp``) and, per env and step, executes either the corrected action
or, while the block is within ``--radius`` px and ``--angle`` degrees of the goal pose (read from the env:
privileged), the base's planned action unchanged. Prints score and success with and without the gate, and
open loop's.

Usage: .venv/bin/python scripts/goal_gate_probe.py [--policy models/pusht-dcdp-state-demos]
           [--condition constant_0.5] [--episodes 100] [--methods object_anchored dcdp]
           [--radius 20] [--angle 20]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def run(args: argparse.Namespace, method: str, gate: bool) -> tuple[float, float]:
    """Mean score and success of one (method, gate) on ``args.condition``."""
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep

    rollout = condition_rollout(args.policy, args.condition, args.episodes, method)
    policy, post, corrected, envs, seeds = rollout
    near = np.zeros(len(seeds), dtype=bool)  # block near the goal after the last step

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        action = corrected(obs, active)
        if gate and policy.planned_chunk is not None:
            planned = post(policy.planned_chunk).cpu().numpy()[:, policy.last_step]
            action = np.where(near[:, None], planned, action)  # every env's row (ended ones ignored)
        return action

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        b, g = info["block_pose"], info["goal_pose"]
        turn = np.degrees(abs((b[2] - g[2] + np.pi) % (2 * np.pi) - np.pi))
        near[i] = np.hypot(b[0] - g[0], b[1] - g[1]) < args.radius and turn < args.angle

    out = run_lockstep(envs, seeds, act, 300, on_step)
    for env in envs:
        env.close()
    return float(np.mean(out.max_rewards)), float(np.mean(out.successes))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state-demos")
    p.add_argument("--condition", default="constant_0.5")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--methods", nargs="+", default=["object_anchored", "dcdp"])
    p.add_argument("--radius", type=float, default=20.0)
    p.add_argument("--angle", type=float, default=20.0)
    a = p.parse_args()
    torch.set_num_threads(1)
    print(f"| {a.condition}, {a.episodes} seeds | score | success |")
    print("|---|---|---|")
    rows = [("open_loop", False)] + [(m, g) for m in a.methods for g in (False, True)]
    for method, gate in rows:
        score, success = run(a, method, gate)
        name = f"{method}, plan kept near the goal" if gate else method
        print(f"| {name} | {score:.3f} | {100 * success:.0f} % |", flush=True)


if __name__ == "__main__":
    main()
