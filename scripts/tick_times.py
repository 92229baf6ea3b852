"""Per-tick time of a corrector driving the simulated PushT robot in real time, sync vs async planning.

The loop is the one LeRobot's sync inference engine runs per tick (robot observation -> one flattened
``observation.state`` -> ``prepare_observation_for_inference`` -> the policy's pre-processor ->
``select_action`` -> post-processor -> ``send_action``), paced at ``--fps`` on the wall clock. LeRobot's
rollout prints only the ticks that overran their period; this prints the distribution of every tick.

Usage: .venv/bin/python scripts/tick_times.py [--policy models/pusht-dcdp-state] [--fps 30] [--seconds 30]
           [--planning sync async] [--gc]
  --gc: also time every garbage-collector pass (``gc.callbacks``) and report the passes and the collector's
  time inside the slowest tick (does the collector make the worst tick?).
"""

from __future__ import annotations

import argparse
import gc
import time

import numpy as np
import torch


class GCTimer:
    """Start and end (``perf_counter``) of every garbage-collector pass while installed."""

    def __init__(self) -> None:
        self.passes: list[tuple[float, float, int]] = []
        self._start = 0.0

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._start = time.perf_counter()
        else:
            self.passes.append((self._start, time.perf_counter(), info["generation"]))

    def inside(self, start: float, end: float) -> float:
        """Milliseconds of collection that started within ``[start, end)``."""
        return 1000 * sum(b - a for a, b, _ in self.passes if start <= a < end)


def run(policy_path: str, planning: str, fps: int, seconds: float, gc_timer: GCTimer | None = None) -> dict:
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
    ticks, policy_ms, tick_ms, spans = int(seconds * fps), [], [], []
    if gc_timer is not None:
        gc.callbacks.append(gc_timer)
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
        spans.append((t0, time.perf_counter()))
        policy_ms.append(1000 * (spans[-1][1] - t0))
        robot.send_action({"x.pos": float(action[0]), "y.pos": float(action[1])})
        tick_ms.append(1000 * (time.perf_counter() - started))
        next_tick += period
        time.sleep(max(0.0, next_tick - time.perf_counter()))
    policy.close()
    if gc_timer is not None:
        gc.callbacks.remove(gc_timer)
    slowest = 1 + int(np.argmax(policy_ms[1:]))
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
    if gc_timer is not None:
        durations = [1000 * (b - a) for a, b, _ in gc_timer.passes]
        stats["gc"] = (
            f"{len(durations)} passes (gen 0/1/2: "
            f"{'/'.join(str(sum(g == k for *_, g in gc_timer.passes)) for k in range(3))}), "
            f"longest {max(durations, default=0.0):.2f} ms; in the slowest tick "
            f"({policy_ms[slowest]:.2f} ms): {gc_timer.inside(*spans[slowest]):.2f} ms"
        )
    robot.disconnect()
    return stats


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state")
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--planning", nargs="+", default=["sync", "async"])
    p.add_argument("--gc", action="store_true", help="time the garbage collector's passes too")
    a = p.parse_args()
    torch.set_num_threads(1)
    print(
        "| planning | fps | ticks | policy ms median | p99 | max (after the first tick) | first tick ms | "
        "whole tick max ms | overruns | robot late actions |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for planning in a.planning:
        s = run(a.policy, planning, a.fps, a.seconds, GCTimer() if a.gc else None)
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
        if "gc" in s:
            print(f"  garbage collector ({planning}): {s['gc']}", flush=True)


if __name__ == "__main__":
    main()
