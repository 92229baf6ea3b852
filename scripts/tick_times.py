"""Per-tick time of a corrector driving the simulated PushT robot in real time, sync vs async planning.

The loop is the one LeRobot's sync inference engine runs per tick (robot observation -> one flattened
``observation.state`` -> ``prepare_observation_for_inference`` -> the policy's pre-processor ->
``select_action`` -> post-processor -> ``send_action``), paced at ``--fps`` on the wall clock. LeRobot's
rollout prints only the ticks that overran their period; this prints the distribution of every tick.

Usage: .venv/bin/python scripts/tick_times.py [--policy models/pusht-dcdp-state] [--fps 30] [--seconds 30]
           [--planning sync async]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def run(policy_path: str, planning: str, fps: int, seconds: float) -> dict:
    from lerobot.policies.utils import prepare_observation_for_inference

    from lerobot_dcdp.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.processor_dcdp import make_dcdp_pre_post_processors
    from lerobot_dcdp.robots import PushTSim, PushTSimConfig

    policy = DCDPPolicy.from_pretrained(policy_path).eval()
    policy.config.planning = planning
    pre, post = make_dcdp_pre_post_processors(policy.config)
    robot = PushTSim(PushTSimConfig(perturbation="constant", magnitude=2.0, seed=100_000))
    robot.connect()
    names = list(robot.observation_features)
    policy.reset()
    ticks, policy_ms, tick_ms = int(seconds * fps), [], []
    period = 1.0 / fps
    next_tick = time.perf_counter()
    for _ in range(ticks):
        started = time.perf_counter()
        obs = robot.get_observation()
        frame = {"observation.state": np.array([obs[k] for k in names], dtype=np.float32)}
        t0 = time.perf_counter()
        with torch.inference_mode():
            batch = pre(prepare_observation_for_inference(frame, torch.device("cpu")))
            action = post(policy.select_action(batch))[0]
        policy_ms.append(1000 * (time.perf_counter() - t0))
        robot.send_action({"x.pos": float(action[0]), "y.pos": float(action[1])})
        tick_ms.append(1000 * (time.perf_counter() - started))
        next_tick += period
        time.sleep(max(0.0, next_tick - time.perf_counter()))
    policy.close()
    stats = {
        "planning": planning,
        "fps": fps,
        "ticks": ticks,
        "policy_ms_median": float(np.median(policy_ms)),
        "policy_ms_p99": float(np.percentile(policy_ms, 99)),
        "policy_ms_max_after_first": float(np.max(policy_ms[1:])),
        "first_tick_ms": float(policy_ms[0]),
        "tick_ms_max_after_first": float(np.max(tick_ms[1:])),
        "overruns": int(sum(t > 1000 * period for t in tick_ms[1:])),
        "late_actions": robot.late_actions,
        "max_coverage": robot.max_coverage,
    }
    robot.disconnect()
    return stats


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state")
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--planning", nargs="+", default=["sync", "async"])
    a = p.parse_args()
    torch.set_num_threads(1)
    print(
        "| planning | fps | ticks | policy ms median | p99 | max (after the first tick) | first tick ms | "
        "whole tick max ms | overruns | robot late actions |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for planning in a.planning:
        s = run(a.policy, planning, a.fps, a.seconds)
        cells = [
            planning,
            s["fps"],
            s["ticks"],
            f"{s['policy_ms_median']:.2f}",
            f"{s['policy_ms_p99']:.2f}",
            f"{s['policy_ms_max_after_first']:.1f}",
            f"{s['first_tick_ms']:.0f}",
            f"{s['tick_ms_max_after_first']:.1f}",
            s["overruns"],
            s["late_actions"],
        ]
        print("| " + " | ".join(map(str, cells)) + " |", flush=True)


if __name__ == "__main__":
    main()
