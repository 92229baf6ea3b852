"""Where DCDP's extra per-step time goes at batch 1: mean ms of planning steps (a base call) and of the other
steps, open loop vs DCDP, episodes interleaved (dcdp-latency's loop: processors + select_action + env step).

Usage: .venv/bin/python scripts/diagnostics/step_time_split.py [corrector] [episodes]
"""

import sys
import time

import numpy as np
import torch

from lerobot_dcdp.benchmark.rollout import CONDITIONS, rollout
from lerobot_dcdp.pusht.corrections import load_policy

torch.set_num_threads(1)
path = sys.argv[1] if len(sys.argv) > 1 else "models/pusht-dcdp-state"
episodes = int(sys.argv[2]) if len(sys.argv) > 2 else 4
policy, pre, post = load_policy(path, None, "dcdp", "observation.environment_state")
static = next(c for c in CONDITIONS if c.name == "static")
h = policy.config.n_action_steps
kernel_ms: list[float] = []
select_ms: list[float] = []
_kernel, _select = policy._kernel_step, policy.select_action


def timed_kernel(batch):
    t0 = time.perf_counter()
    out = _kernel(batch)
    kernel_ms.append((time.perf_counter() - t0) * 1e3)
    return out


def timed_select(batch):
    t0 = time.perf_counter()
    out = _select(batch)
    if policy.config.execution == "dcdp" and policy.last_step != 0:
        select_ms.append((time.perf_counter() - t0) * 1e3)
    return out


policy._kernel_step, policy.select_action = timed_kernel, timed_select  # timing wrappers, this script only
times = {"open_loop": [], "dcdp": []}
for ep in range(episodes):
    for mode in times:
        policy.config.execution = mode
        r = rollout(policy, pre, post, static, [100_000 + ep], 300)
        times[mode].append(np.asarray(r.step_times_ms))
for mode, runs in times.items():
    plan = np.concatenate([t[h::h] for t in runs])  # step 0 pays one-off allocations
    other = np.concatenate([np.delete(t, np.arange(0, len(t), h)) for t in runs])
    allv = np.concatenate([t[1:] for t in runs])
    print(
        f"{mode:10s} planning steps {plan.mean():7.3f} ms (n={len(plan)})  "
        f"other steps {other.mean():6.3f} ms (median {np.median(other):.3f})  all {allv.mean():6.3f} ms"
    )
print(
    f"inside the loop: select_action on non-planning DCDP steps {np.mean(select_ms):.3f} ms, "
    f"of which the compiled kernel call {np.mean(kernel_ms):.3f} ms (median {np.median(kernel_ms):.3f}, "
    f"n={len(kernel_ms)})"
)
