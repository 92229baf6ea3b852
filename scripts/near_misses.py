"""How far from the goal the block gets where a method fails: its pose error at each episode's best coverage.

Runs one benchmark condition (same envs, seeds and seeding as ``dcdp-benchmark``) for each method and prints,
for the failed and the successful episodes, the median position error (px) and angle error (degrees) of the
block at its best coverage, the median best coverage, and how many failures came within 0.05 of the success
threshold (coverage >= 0.90). For the successes, how many the agent pushed in (in the success step the
block moved, or turned, beyond the drift the env applied: > 0.05 px / 0.05 degrees) and how many drifted in
untouched.

Usage: .venv/bin/python scripts/near_misses.py [--policy models/pusht-dcdp-state-demos]
           [--condition constant_0.5] [--episodes 50] [--methods open_loop dcdp]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def condition_rollout(
    policy_path: str,
    condition: str,
    episodes: int,
    method: str,
    seed_start: int = 100_000,
    lead_steps: int | None = None,
    delay: int = 0,
) -> tuple:
    """The benchmark's envs for one condition and the corrector in one execution mode, seeded as the benchmark
    seeds a batch; ``lead_steps`` overrides the folder's scene lead (None: the folder's, as the benchmark runs
    it); ``delay``: the base answers that many control steps late (the benchmark's ``--delays``).
    ``condition``: a benchmark condition's name, or ``unseen_check.py``'s ``constant:<px>:<deg>`` /
    ``random:<px>``. Returns ``(policy, post, act, envs, seeds)``: ``post`` the corrector's post-processor,
    ``act`` the policy call ``run_lockstep`` takes."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.benchmark.rollout import CONDITIONS, _stack_obs
    from lerobot_dcdp.benchmark.run import load_model, set_mode
    from lerobot_dcdp.envs.pusht_perturbed import make_perturbed_env

    policy, pre, post, _ = load_model(policy_path)
    if ":" in condition:  # a drift no table uses, in unseen_check.py's form
        from unseen_check import parse_condition

        cond, extra = parse_condition(condition)
    else:
        cond, extra = {c.name: c for c in CONDITIONS}[condition], {}
    seeds = list(range(seed_start, seed_start + episodes))
    set_mode(policy, method, delay)
    if lead_steps is not None:
        policy.config.lead_steps = lead_steps
    envs = [
        make_perturbed_env(
            obs_type="environment_state_agent_pos", max_episode_steps=300, **{**cond.env_kwargs(), **extra}
        )
        for _ in seeds
    ]
    torch.manual_seed(seeds[0])  # as the benchmark seeds a batch
    policy.reset()

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        return post(policy.select_action(pre(preprocess_observation(_stack_obs(obs))))).cpu().numpy()

    return policy, post, act, envs, seeds


def run(policy_path: str, condition: str, episodes: int, method: str) -> dict:
    from lerobot_dcdp.lockstep import run_lockstep

    _, _, act, envs, seeds = condition_rollout(policy_path, condition, episodes, method)
    best = {i: (-1.0, 0.0, 0.0) for i in range(len(seeds))}
    last_pose = {i: None for i in range(len(seeds))}
    pushed_in = {}

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        pose = np.asarray(info["block_pose"], dtype=float)
        if info.get("is_success") and i not in pushed_in and last_pose[i] is not None:
            moved = pose[:2] - last_pose[i][:2] - np.asarray(info["perturbation_offset"])
            turned = np.degrees(abs((pose[2] - last_pose[i][2] + np.pi) % (2 * np.pi) - np.pi))
            pushed_in[i] = bool(np.hypot(*moved) > 0.05 or turned > 0.05)
        last_pose[i] = pose
        if info["coverage"] > best[i][0]:
            b, g = info["block_pose"], info["goal_pose"]
            turn = (b[2] - g[2] + np.pi) % (2 * np.pi) - np.pi
            best[i] = (
                info["coverage"],
                float(np.hypot(b[0] - g[0], b[1] - g[1])),
                float(np.degrees(abs(turn))),
            )

    out = run_lockstep(envs, seeds, act, 300, on_step)
    for env in envs:
        env.close()
    cov, pos, ang = (np.array([best[i][k] for i in best]) for k in range(3))
    ok = np.array(out.successes)
    med = lambda x: float(np.median(x)) if len(x) else float("nan")  # noqa: E731
    return {
        "success": float(ok.mean()),
        "failed": int((~ok).sum()),
        "near_misses": int((cov[~ok] >= 0.90).sum()),
        "failed_pos_px": med(pos[~ok]),
        "failed_ang_deg": med(ang[~ok]),
        "failed_best_coverage": med(cov[~ok]),
        "success_pos_px": med(pos[ok]),
        "success_ang_deg": med(ang[ok]),
        "pushed_in": int(sum(pushed_in.values())),
        "drifted_in": int(len(pushed_in) - sum(pushed_in.values())),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state-demos")
    p.add_argument("--condition", default="constant_0.5")
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--methods", nargs="+", default=["open_loop", "dcdp"])
    a = p.parse_args()
    torch.set_num_threads(1)
    print(
        "| method | success | failed: pos px | deg | best cover | near misses | success: pos px | deg "
        "| successes pushed in / drifted in |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for method in a.methods:
        r = run(a.policy, a.condition, a.episodes, method)
        cells = [
            method,
            f"{100 * r['success']:.0f} %",
            f"{r['failed_pos_px']:.1f}",
            f"{r['failed_ang_deg']:.1f}",
            f"{r['failed_best_coverage']:.3f}",
            f"{r['near_misses']}/{r['failed']}",
            f"{r['success_pos_px']:.1f}",
            f"{r['success_ang_deg']:.1f}",
            f"{r['pushed_in']} / {r['drifted_in']}",
        ]
        print("| " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
