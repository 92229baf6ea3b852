"""The pusht_expert teleoperator driving pusht_perturbed by itself (no policy): success and score per drift.

Usage: .venv/bin/python scripts/teleop_alone.py MAGNITUDE REPLAN_EVERY EPISODES [FOLLOW_BLOCK]
  (constant drift at 45 degrees, seeds from 100000, 300 steps max; MAGNITUDE 0 = no drift; FOLLOW_BLOCK 1:
  the teleoperator's --teleop.follow_block=true)
"""

from __future__ import annotations

import sys
import time

import numpy as np

from lerobot_dcdp.envs.pusht_perturbed import make_perturbed_env
from lerobot_dcdp.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
from lerobot_dcdp.teleoperators import PushTExpert, PushTExpertConfig


def main() -> None:
    magnitude, replan, episodes = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
    follow = len(sys.argv) > 4 and sys.argv[4] == "1"
    teleop = PushTExpert(PushTExpertConfig(replan_every=replan, follow_block=follow))
    teleop.connect()
    success, score, started, steps = [], [], time.time(), 0
    for seed in range(100_000, 100_000 + episodes):
        env = make_perturbed_env(
            obs_type="environment_state_agent_pos",
            max_episode_steps=300,
            perturbation="constant" if magnitude > 0 else "none",
            magnitude=magnitude,
            direction_deg=45.0,
        )
        obs, _ = env.reset(seed=seed)
        teleop.reset()
        best, done = 0.0, False
        for _ in range(300):
            feedback = dict(zip(AGENT_NAMES, obs["agent_pos"], strict=True))
            feedback.update(zip(KEYPOINT_NAMES, obs["environment_state"], strict=True))
            teleop.send_feedback(feedback)
            action = teleop.get_action()
            steps += 1
            obs, reward, terminated, truncated, info = env.step(np.array([action["x.pos"], action["y.pos"]]))
            best = max(best, reward)
            if info.get("is_success"):
                done = True
                break
            if terminated or truncated:
                break
        success.append(done)
        score.append(best)
        env.close()
    print(
        f"magnitude {magnitude} replan_every {replan} follow_block {follow}: success {np.mean(success):.2f} "
        f"score {np.mean(score):.3f} ({1000 * (time.time() - started) / steps:.1f} ms/step, "
        f"{teleop.plans} plans)"
    )


if __name__ == "__main__":
    main()
