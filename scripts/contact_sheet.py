"""Contact sheets of the episodes a method fails: frames every ``--every`` steps, one PNG per failed seed.

Runs one condition (``near_misses.condition_rollout``: a benchmark condition or ``unseen_check.py``'s
``constant:<px>:<deg>`` / ``random:<px>``) with a folder in one execution mode, renders the env every
``--every`` steps, and writes for each failed episode a 4-column sheet of ``--frames`` frames from frame
``--first`` on (the step number in each tile) to ``--out``/sheet_<seed>.png: to watch where the finish fails.

Usage: .venv/bin/python scripts/contact_sheet.py --policy models/pusht-act-state-anchored-gated
           --condition constant:0.6:300 --seed-start 300100 --episodes 6 --method gated_anchored
           [--every 12] [--first 8] [--frames 16] [--out runs/sheets]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    import cv2
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True)
    p.add_argument("--condition", default="constant_0.5")
    p.add_argument("--seed-start", type=int, default=100_000)
    p.add_argument("--episodes", type=int, default=6)
    p.add_argument("--method", default="dcdp")
    p.add_argument("--every", type=int, default=12)
    p.add_argument("--first", type=int, default=8)
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--out", default="runs/sheets")
    a = p.parse_args()
    torch.set_num_threads(1)
    _, _, act, envs, seeds = condition_rollout(a.policy, a.condition, a.episodes, a.method, a.seed_start)
    frames = {i: [] for i in range(len(seeds))}
    steps = np.zeros(len(seeds), dtype=int)
    best = np.zeros(len(seeds))

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        steps[i] += 1
        best[i] = max(best[i], info["coverage"])
        if steps[i] % a.every == 0:
            frames[i].append((int(steps[i]), envs[i].render()))

    out = run_lockstep(envs, seeds, act, 300, on_step)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    for i, seed in enumerate(seeds):
        print(f"seed {seed}: success {out.successes[i]}, best coverage {best[i]:.3f}, {steps[i]} steps")
        if out.successes[i] or not frames[i]:
            continue
        tiles = []
        for step, frame in frames[i][a.first : a.first + a.frames]:
            tile = cv2.resize(np.ascontiguousarray(frame), (160, 160))
            cv2.putText(tile, str(step), (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 0, 0), 1)
            tiles.append(tile)
        if not tiles:
            continue
        tiles += [np.zeros_like(tiles[0])] * (-len(tiles) % 4)
        sheet = np.concatenate([np.concatenate(tiles[j : j + 4], 1) for j in range(0, len(tiles), 4)], 0)
        cv2.imwrite(str(Path(a.out) / f"sheet_{seed}.png"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    for env in envs:
        env.close()


if __name__ == "__main__":
    main()
