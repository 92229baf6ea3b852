"""How far each corrector moves the base's planned action, at rest and under drift (a diagnosis aid).

Runs each corrector (``--policy.execution=dcdp``) on ``pusht_perturbed`` (keypoint observations, seeds from
100000, 300 steps max, constant drift at 45 degrees) and prints, per condition, the mean and 90th percentile
of |executed action - planned action at that step| in pixels, the share of steps where it exceeds 10 px
and the block's mean motion (keypoint centroid, px) over the steps with such corrections and over the others,
with the episodes' score (the best reward,
i.e. max clip(coverage / 0.95, 0, 1), as the benchmark's) and success.

Usage: .venv/bin/python scripts/correction_size.py EPISODES MAGNITUDE [MAGNITUDE ...] -- POLICY [POLICY ...]
  (MAGNITUDE 0 = no drift)
       .venv/bin/python scripts/correction_size.py --trace SEED STEPS MAGNITUDE POLICY
  (one episode's first STEPS steps: step in chunk, correction (x, y) px, the block's motion px)
"""

from __future__ import annotations

import sys

import numpy as np
import torch


def run(
    policy_dir: str, magnitude: float, episodes: int, first_seed: int = 100_000, trace_steps: int = 0
) -> tuple[np.ndarray, np.ndarray, list, list]:
    """Corrections and the block's motion in that step (px, every step of every episode), scores and
    successes of one corrector on one drift (``trace_steps``: print the first steps of each episode)."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.envs.pusht_perturbed import DEFAULT_DIRECTIONS_DEG
    from lerobot_dcdp.pusht.corrections import DriftSpec, episode_env, load_policy

    policy, pre, post = load_policy(policy_dir, None, "dcdp", "observation.environment_state")
    sizes, moves, scores, successes = [], [], [], []
    kind = "constant" if magnitude > 0 else "none"
    drift = DriftSpec(kind, magnitude, 45.0, DEFAULT_DIRECTIONS_DEG, 50)  # the env's own defaults
    for seed in range(first_seed, first_seed + episodes):
        env = episode_env(None, drift, 300)  # keypoint observations, as the recorder's episodes
        obs, _ = env.reset(seed=seed)
        torch.manual_seed(seed)
        policy.reset()
        best, success = 0.0, False
        for t in range(300):
            batch = preprocess_observation({k: np.asarray(v)[None] for k, v in obs.items()})
            with torch.no_grad():
                action = post(policy.select_action(pre(dict(batch)))).cpu().numpy()[0]
                planned = post(policy.planned_chunk).cpu().numpy()[0, policy.last_step]
            sizes.append(float(np.linalg.norm(action - planned)))
            before = np.asarray(obs["environment_state"]).reshape(-1, 2).mean(0)
            obs, reward, terminated, truncated, info = env.step(action)
            after = np.asarray(obs["environment_state"]).reshape(-1, 2).mean(0)
            moves.append(float(np.linalg.norm(after - before)))
            if t < trace_steps:
                d = action - planned
                print(f"{t:3d} step {policy.last_step} correction ({d[0]:6.1f}, {d[1]:6.1f})", end=" ")
                print(f"block {moves[-1]:.2f}")
            best = max(best, float(reward))
            success = success or bool(info.get("is_success", False))
            if terminated or truncated:
                break
        env.close()
        scores.append(best)  # the env's reward is already clip(coverage / 0.95, 0, 1)
        successes.append(success)
    return np.asarray(sizes), np.asarray(moves), scores, successes


def main() -> None:
    torch.set_num_threads(1)
    if sys.argv[1:2] == ["--trace"]:
        seed, steps, magnitude = int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
        run(sys.argv[5], magnitude, 1, first_seed=seed, trace_steps=steps)
        return
    if "--" not in sys.argv:
        sys.exit(__doc__)
    cut = sys.argv.index("--")
    episodes, magnitudes = int(sys.argv[1]), [float(m) for m in sys.argv[2:cut]]
    torch.set_num_threads(1)
    print(
        "| corrector | drift px/step | mean correction px | p90 px | > 10 px | block motion px/step there "
        "/ elsewhere | score | success |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for path in sys.argv[cut + 1 :]:
        for m in magnitudes:
            sizes, moves, scores, successes = run(path, m, episodes)
            big = sizes > 10.0
            there = f"{moves[big].mean():.2f}" if big.any() else "-"
            print(
                f"| {path} | {m} | {sizes.mean():.2f} | {np.percentile(sizes, 90):.2f} | "
                f"{100 * big.mean():.1f} % | {there} / {moves[~big].mean():.2f} | "
                f"{np.mean(scores):.3f} | {100 * np.mean(successes):.0f} % |",
                flush=True,
            )


if __name__ == "__main__":
    main()
