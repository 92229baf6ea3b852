"""Per-tick time of a corrector driving the simulated PushT robot in real time, sync vs async planning.

The loop is the one LeRobot's sync inference engine runs per tick (robot observation -> one flattened
``observation.state`` -> ``prepare_observation_for_inference`` -> the policy's pre-processor ->
``select_action`` -> post-processor -> ``send_action``), paced at ``--fps`` on the wall clock. LeRobot's
rollout prints only the ticks that overran their period; this prints the distribution of every tick.

Usage: .venv/bin/python scripts/tick_times.py [--policy models/pusht-dcdp-state] [--fps 10 30] [--seconds 30]
           [--planning sync async async_pinned async_idle] [--planner-cpus 1] [--repeats 2] [--out FILE]
           [--gc] [--schedstat]
  --gc: also time every garbage-collector pass (``gc.callbacks``) and report the passes and the collector's
  time inside the slowest tick (does the collector make the worst tick?).
  --schedstat: split every policy tick over 5 ms into the control thread's time on a CPU, its time runnable
  but waiting for one (``/proc/thread-self/schedstat``: preempted by this machine's other threads) and the
  rest (blocked, or the CPU taken by the hypervisor: the guest's steal, which the run's ``/proc/stat`` shows).
  async_pinned: async with the worker on ``--planner-cpus`` and the control loop on the other CPUs
  (``--policy.planner_cpus``); async_idle: async with the worker under ``SCHED_IDLE``
  (``--policy.planner_priority=idle``), unpinned. ``--repeats``: each row that many times, interleaved (the
  spread between runs).
  The header records the process's scheduling policy: ``chrt -f 20 python scripts/tick_times.py ...`` runs the
  loop (and the worker) at real-time FIFO priority.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
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


def schedstat() -> tuple[int, int]:
    """The calling thread's time on a CPU and time runnable but waiting for one, ns (Linux schedstat)."""
    with open("/proc/thread-self/schedstat") as f:
        on_cpu, waiting, _ = f.read().split()
    return int(on_cpu), int(waiting)


def steal_ticks() -> int:
    """The machine's stolen time so far (all CPUs, clock ticks; ``/proc/stat``)."""
    with open("/proc/stat") as f:
        return int(f.readline().split()[8])


def run(
    policy_path: str,
    planning: str,
    fps: int,
    seconds: float,
    gc_timer: GCTimer | None = None,
    planner_cpus: list[int] | None = None,
    sched: bool = False,
    priority: str = "normal",
) -> dict:
    from lerobot.policies.utils import prepare_observation_for_inference

    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors
    from lerobot_dcdp.sim.robots import PushTSim, PushTSimConfig

    policy = DCDPPolicy.from_pretrained(policy_path).eval()
    policy.config.planning = planning
    policy.config.planner_cpus = planner_cpus if planning == "async" else None
    policy.config.planner_priority = priority if planning == "async" else "normal"
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
    whole = []  # (start, end) of every whole tick
    split = []  # per tick with ``sched``: (on a CPU, waiting for one) ms during the policy call
    stolen = steal_ticks()
    for _ in range(ticks):
        started = time.perf_counter()
        obs = robot.get_observation()
        frame = {"observation.state": np.array([obs[k] for k in names], dtype=np.float32)}
        before = schedstat() if sched else (0, 0)
        t0 = time.perf_counter()
        with torch.inference_mode():
            batch = pre(prepare_observation_for_inference(frame, torch.device("cpu")))
            action = post(policy.select_action(batch))[0]
        spans.append((t0, time.perf_counter()))
        if sched:
            after = schedstat()
            split.append(((after[0] - before[0]) / 1e6, (after[1] - before[1]) / 1e6))
        policy_ms.append(1000 * (spans[-1][1] - t0))
        robot.send_action({"x.pos": float(action[0]), "y.pos": float(action[1])})
        whole.append((started, time.perf_counter()))
        tick_ms.append(1000 * (whole[-1][1] - started))
        next_tick += period
        time.sleep(max(0.0, next_tick - time.perf_counter()))
    policy.close()
    if gc_timer is not None:
        gc.callbacks.remove(gc_timer)
    slowest = 1 + int(np.argmax(policy_ms[1:]))
    slowest_whole = 1 + int(np.argmax(tick_ms[1:]))
    stats = {
        "planning": planning,
        "fps": fps,
        "ticks": ticks,
        "policy_ms_median": float(np.median(policy_ms[1:])),
        "policy_ms_p99": float(np.percentile(policy_ms[1:], 99)),
        "policy_ms_max_after_first": float(np.max(policy_ms[1:])),
        "first_tick_ms": float(policy_ms[0]),
        "tick_ms_max_after_first": float(np.max(tick_ms[1:])),
        "policy_ticks_over_5ms": int(sum(t > 5.0 for t in policy_ms[1:])),
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
            f"({policy_ms[slowest]:.2f} ms): {gc_timer.inside(*spans[slowest]):.2f} ms; in the slowest whole "
            f"tick ({tick_ms[slowest_whole]:.2f} ms): {gc_timer.inside(*whole[slowest_whole]):.2f} ms"
        )
    if sched:
        slow = [i for i in range(1, ticks) if policy_ms[i] > 5.0]
        parts = [
            f"{policy_ms[i]:.1f} = {split[i][0]:.1f} on a CPU + {split[i][1]:.1f} waiting for one + "
            f"{policy_ms[i] - split[i][0] - split[i][1]:.1f} other"
            for i in slow
        ]
        stats["sched"] = (
            f"machine steal over the run {(steal_ticks() - stolen) * 1e3 / os.sysconf('SC_CLK_TCK'):.0f} ms; "
            f"policy ticks over 5 ms (ms): {'; '.join(parts) if parts else 'none'}"
        )
    robot.disconnect()
    return stats


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state")
    p.add_argument("--fps", type=int, nargs="+", default=[30])
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument(
        "--planning",
        nargs="+",
        default=["sync", "async"],
        choices=["sync", "async", "async_pinned", "async_idle"],
    )
    p.add_argument("--gc", action="store_true", help="time the garbage collector's passes too")
    p.add_argument("--schedstat", action="store_true", help="split slow ticks by the scheduler's accounts")
    p.add_argument(
        "--planner-cpus",
        type=int,
        nargs="+",
        default=[1],
        help="the async_pinned rows' worker CPUs (--policy.planner_cpus)",
    )
    p.add_argument("--repeats", type=int, default=1, help="runs of each (fps, planning) row, interleaved")
    p.add_argument("--out", default=None, help="also write the table, with this command, to this file")
    a = p.parse_args()
    torch.set_num_threads(1)
    policy_names = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_RR: "SCHED_RR"}
    sched = policy_names.get(os.sched_getscheduler(0), str(os.sched_getscheduler(0)))
    priority = os.sched_getparam(0).sched_priority
    lines = [
        f"policy `{a.policy}`, {a.seconds:g} s per run, constant drift 2.0 px/step, {os.cpu_count()} CPUs, "
        f"scheduler {sched}{f' priority {priority}' if priority else ''} (real-time: started under "
        "`chrt -f <priority>`), "
        f"torch threads 1, load average before: {' '.join(open('/proc/loadavg').read().split()[:3])}, "
        f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}",
        f"command: `python scripts/tick_times.py {' '.join(sys.argv[1:])}`",
        "",
        "| planning | fps | run | ticks | policy ms, after the first tick: median | p99 | max | "
        "policy ticks > 5 ms | first tick ms | whole tick max ms | overruns | robot late actions |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    print("\n".join(lines), flush=True)
    notes = []  # per-run lines printed below the table
    for fps in a.fps:
        for repeat in range(a.repeats):
            for planning in a.planning:
                cpus = a.planner_cpus if planning == "async_pinned" else None
                mode = "async" if planning.startswith("async") else planning
                priority = "idle" if planning == "async_idle" else "normal"
                timer = GCTimer() if a.gc else None
                s = run(a.policy, mode, fps, a.seconds, timer, cpus, a.schedstat, priority)
                label = f"async, planner_cpus={cpus}" if cpus else planning
                label = "async, planner_priority=idle" if priority == "idle" else label
                cells = [
                    label,
                    s["fps"],
                    repeat + 1,
                    s["ticks"],
                    f"{s['policy_ms_median']:.2f}",
                    f"{s['policy_ms_p99']:.2f}",
                    f"{s['policy_ms_max_after_first']:.1f}",
                    s["policy_ticks_over_5ms"],
                    f"{s['first_tick_ms']:.0f}",
                    f"{s['tick_ms_max_after_first']:.1f}",
                    s["overruns"],
                    s["late_actions"],
                ]
                lines.append("| " + " | ".join(map(str, cells)) + " |")
                print(lines[-1], flush=True)
                if "gc" in s:
                    print(f"  garbage collector ({planning}): {s['gc']}", flush=True)
                if "sched" in s:
                    notes.append(f"- scheduler ({label}, {fps} Hz, run {repeat + 1}): {s['sched']}")
                    print(notes[-1], flush=True)
    if a.out:
        tmp = f"{a.out}.tmp"
        with open(tmp, "w") as f:
            f.write("\n".join(lines + ([""] + notes if notes else [])) + "\n")
        os.replace(tmp, a.out)


if __name__ == "__main__":
    main()
