"""Quick check of the scripted expert's smoothing: success, episode length and action jumps per seed.

Usage: .venv/bin/python scripts/check_expert.py --max-step 20 --episodes 5
"""

import argparse
import time

import numpy as np

from lerobot_dcdp.pusht.demos import run_episode
from lerobot_dcdp.pusht.expert import ExpertConfig


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--max-step", type=float, default=ExpertConfig.max_step)
    p.add_argument("--episodes", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    for seed in range(a.seed, a.seed + a.episodes):
        t0 = time.perf_counter()
        ep = run_episode(seed, hold_steps=0, expert_config=ExpertConfig(max_step=a.max_step))
        jumps = np.linalg.norm(np.diff(ep.action, axis=0), axis=1)
        lead = np.linalg.norm(ep.action - ep.state, axis=1)
        print(
            f"seed {seed} success={ep.success} steps={len(ep.action)} "
            f"median jump {np.median(jumps):.1f} px, median target-agent {np.median(lead):.1f} px "
            f"({time.perf_counter() - t0:.1f} s)"
        )


if __name__ == "__main__":
    main()
