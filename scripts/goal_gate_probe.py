"""Probe: does correcting the chunk near the goal cost the final alignment? (privileged; a diagnosis aid)

Runs one benchmark condition (same envs, seeds and seeding as ``near_misses.py``) with a corrector's
execution mode (``object_anchored`` or ``dcdp``) and, per env and step, executes either the corrected action
or, while the gate holds, the base's planned action unchanged. Gates: ``goal`` (privileged): the block is
within ``--radius`` px and ``--angle`` degrees of the goal pose (read from the env); ``plan_span``
(goal-free): the plan's actions from this step to the chunk's last executed one stay within ``--span`` px of
this step's (the base is making a small adjustment). Prints score and success with and without the gate, and
open loop's, and for ``plan_span`` how often the gate held on steps near the goal and elsewhere.

Usage: .venv/bin/python scripts/goal_gate_probe.py [--policy models/pusht-dcdp-state-demos]
           [--condition constant_0.5] [--episodes 100] [--methods object_anchored dcdp]
           [--gate goal|plan_span] [--radius 20] [--angle 20] [--span 10]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def run(args: argparse.Namespace, method: str, gate: bool) -> tuple[float, float, str]:
    """Mean score and success of one (method, gate) on ``args.condition``, and how often the gate held."""
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep

    rollout = condition_rollout(args.policy, args.condition, args.episodes, method)
    policy, post, corrected, envs, seeds = rollout
    near = np.zeros(len(seeds), dtype=bool)  # block near the goal after the last step
    held = {True: [], False: []}  # plan_span gate per active step, by whether the block was near the goal
    horizon = policy.config.n_action_steps

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        action = corrected(obs, active)
        if gate and policy.planned_chunk is not None:
            chunk = post(policy.planned_chunk).cpu().numpy()
            s = policy.last_step
            keep = near
            if args.gate == "plan_span":
                ahead = chunk[:, s : max(horizon, s + 1)] - chunk[:, s : s + 1]
                keep = np.linalg.norm(ahead, axis=-1).max(1) < args.span
                for i in np.flatnonzero(active):
                    held[bool(near[i])].append(bool(keep[i]))
            action = np.where(keep[:, None], chunk[:, s], action)  # every env's row (ended ones ignored)
        return action

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        b, g = info["block_pose"], info["goal_pose"]
        turn = np.degrees(abs((b[2] - g[2] + np.pi) % (2 * np.pi) - np.pi))
        near[i] = np.hypot(b[0] - g[0], b[1] - g[1]) < args.radius and turn < args.angle

    out = run_lockstep(envs, seeds, act, 300, on_step)
    for env in envs:
        env.close()
    rates = " / ".join(f"{100 * np.mean(held[k]):.0f} %" if held[k] else "-" for k in (True, False))
    return float(np.mean(out.max_rewards)), float(np.mean(out.successes)), rates


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state-demos")
    p.add_argument("--condition", default="constant_0.5")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--methods", nargs="+", default=["object_anchored", "dcdp"])
    p.add_argument("--radius", type=float, default=20.0)
    p.add_argument("--angle", type=float, default=20.0)
    p.add_argument("--gate", choices=["goal", "plan_span"], default="goal")
    p.add_argument("--span", type=float, default=10.0)
    a = p.parse_args()
    torch.set_num_threads(1)
    print(f"| {a.condition}, {a.episodes} seeds | score | success | gate held near the goal / elsewhere |")
    print("|---|---|---|---|")
    rows = [("open_loop", False)] + [(m, g) for m in a.methods for g in (False, True)]
    what = "near the goal" if a.gate == "goal" else f"while it moves < {a.span:g} px"
    for method, gate in rows:
        score, success, rates = run(a, method, gate)
        name = f"{method}, plan kept {what}" if gate else method
        print(f"| {name} | {score:.3f} | {100 * success:.0f} % | {rates if gate else ''} |", flush=True)


if __name__ == "__main__":
    main()
