"""How well does the scene lead's estimate of the world's motion match the drift the env applied? (diagnosis)

Runs one benchmark condition (same envs, seeds and seeding as ``near_misses.py``) with a folder as the
benchmark runs it (its own scene lead), records the block's keypoint centroid and the env's drift
(``perturbation_offset``) every step, and compares, step by step once a window has been seen, two estimates
of the world's per-step motion from the last ``--window`` displacements: the per-coordinate median (the
first scene lead) and ``scene_lead.repeated_motion`` (the newest displacement repeated, the last one found
held where none repeats). Prints the mean error (px), its 90th percentile and the share of steps off by more
than 0.5 px (x 8 steps of lead: 4 px). At the walls the block cannot follow the drift, so neither estimate
reaches zero error there.

Usage: .venv/bin/python scripts/lead_estimators.py [--policy models/pusht-dcdp-state-demos-late-gated]
           [--conditions static constant_1.0 random_1.0] [--episodes 50] [--method dcdp]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def record(policy: str, condition: str, episodes: int, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Per episode and step, the block's keypoint centroid (E, T, 2) and the env's drift (E, T, 2) (NaN after
    an episode ends)."""
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep

    _, _, act, envs, seeds = condition_rollout(policy, condition, episodes, method)
    centroid = np.full((len(seeds), 301, 2), np.nan)
    drift = np.full((len(seeds), 301, 2), np.nan)
    steps = np.zeros(len(seeds), dtype=int)

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        steps[i] += 1
        centroid[i, steps[i]] = np.asarray(obs["environment_state"]).reshape(-1, 2).mean(0)
        drift[i, steps[i]] = info["perturbation_offset"]

    run_lockstep(envs, seeds, act, 300, on_step)
    for env in envs:
        env.close()
    return centroid[:, 1:], drift[:, 1:]


def errors(centroid: np.ndarray, drift: np.ndarray, window: int, tolerance: float, repeats: int) -> dict:
    """Each estimate's error against the env's drift (px), over every step with a full window."""
    from lerobot_dcdp.scene_lead import repeated_motion

    moves = np.diff(centroid, axis=1)  # moves[:, t - 1]: the step into t
    out = {"median": [], "repeated": []}
    held = np.zeros((len(moves), 2))
    for t in range(window, moves.shape[1]):
        win = moves[:, t - window : t]  # (E, W, 2), the newest last
        live = ~np.isnan(win).any((1, 2)) & ~np.isnan(drift[:, t]).any(1)
        if not live.any():
            break
        motion, found = repeated_motion(torch.from_numpy(win[live]).transpose(0, 1), tolerance, repeats)
        idx = np.flatnonzero(live)
        held[idx[found.numpy()]] = motion[found].numpy()
        truth = drift[live, t]
        out["median"] += list(np.linalg.norm(np.median(win[live], axis=1) - truth, axis=-1))
        out["repeated"] += list(np.linalg.norm(held[live] - truth, axis=-1))
    return {k: np.asarray(v) for k, v in out.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state-demos-late-gated")
    p.add_argument("--conditions", nargs="+", default=["static", "constant_1.0", "random_1.0"])
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--method", default="dcdp")
    p.add_argument("--window", type=int, default=16)
    p.add_argument("--tolerance", type=float, default=0.05)
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args()
    torch.set_num_threads(1)
    for condition in a.conditions:
        centroid, drift = record(a.policy, condition, a.episodes, a.method)
        pushed = np.linalg.norm(np.diff(centroid, axis=1) - drift[:, 1:], axis=-1)
        pushed = pushed[~np.isnan(pushed)]
        print(f"{condition}: steps the block moved off the drift by > 0.1 px: {np.mean(pushed > 0.1):.1%}")
        for name, e in errors(centroid, drift, a.window, a.tolerance, a.repeats).items():
            print(
                f"  {name:8s} mean {e.mean():.3f} px, p90 {np.quantile(e, 0.9):.3f} px, "
                f"> 0.5 px on {np.mean(e > 0.5):.1%} of {len(e)} steps",
                flush=True,
            )


if __name__ == "__main__":
    main()
