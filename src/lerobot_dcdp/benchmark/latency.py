"""``dcdp-latency``: per-step cost of every execution mode, timed through ``select_action`` itself.

The loop is ``lerobot-eval``'s (pre-processor -> ``select_action`` -> post-processor, one PushT env step),
batch 1 and batch 50, one thread, static PushT, modes interleaved episode by episode so they share the
same machine state. Per mode: mean and p95 per control step over whole episodes (a base call every H
steps included). Then the corrector's own per-step time, split by part (frame encoding + bank update,
dynamic extractor, correction head, or the compiled step kernel that replaces them on CPU, and the
once-per-chunk work), each part timed by calling the policy's own methods on real observations.
Prints Markdown tables and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from lerobot_dcdp.benchmark import shipped_model

MODES = ("open_loop", "dcdp", "object_anchored", "closed_loop", "bid")
#: the modes timed unless ``--modes`` says otherwise (BID, 30 base samples per step, on request)
DEFAULT_MODES = ("open_loop", "dcdp", "object_anchored", "closed_loop")


def time_modes(policy, pre, post, modes, episodes: int, steps: int, batch: int, seed: int) -> dict:
    """Per-step latency of each mode (ms), episodes interleaved across modes."""
    from lerobot_dcdp.benchmark.modes import obs_type
    from lerobot_dcdp.benchmark.rollout import CONDITIONS, rollout

    static = next(c for c in CONDITIONS if c.name == "static")
    times: dict[str, list[float]] = {m: [] for m in modes}
    episode_means: dict[str, list[float]] = {m: [] for m in modes}
    for ep in range(episodes):
        seeds = list(range(seed + ep * batch, seed + (ep + 1) * batch))
        for mode in modes:
            policy.config.execution = mode
            r = rollout(policy, pre, post, static, seeds, steps, obs_type(policy))
            times[mode] += r.step_times_ms[1:]  # the first step pays one-off allocations
            episode_means[mode].append(float(np.mean(r.step_times_ms[1:])))
    return {
        m: {
            "mean_ms": float(np.mean(t)),
            "p95_ms": float(np.percentile(t, 95)),
            "steps": len(t),
            "episode_mean_ms": episode_means[m],
        }
        for m, t in times.items()
    }


def ratio_spread(per: dict, mode: str, reference: str = "open_loop") -> tuple[float, float]:
    """Mean and standard error of the per-episode ratios ``mode / reference`` (each episode of ``mode`` ran
    right after the same seeds under ``reference``): how much the headline ratio moves with machine noise."""
    r = np.asarray(per[mode]["episode_mean_ms"]) / np.asarray(per[reference]["episode_mean_ms"])
    return float(r.mean()), float(r.std(ddof=1) / np.sqrt(len(r))) if len(r) > 1 else float("nan")


@torch.no_grad()
def corrector_parts(policy, pre, steps: int = 300, warmup: int = 20) -> dict[str, float]:
    """Mean ms per control step of each part of the DCDP per-step path (batch 1): the eager parts (frame
    encoding + bank update, dynamic extractor, correction head; ``fast_inference = False``), the compiled
    step that replaces them (``step_kernel.py``, when the corrector has one) and the once-per-chunk work
    (chunk latent, head terms, kernel check) divided by H; with a keypoint reader in the pre-processor (an
    image corrector), the reader's estimate from the frame too."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.benchmark.modes import obs_type
    from lerobot_dcdp.benchmark.rollout import _stack_obs
    from lerobot_dcdp.policy.processor_pixel_keypoints import PixelKeypointsProcessorStep
    from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env

    env = make_perturbed_env(obs_type=obs_type(policy))
    obs, _ = env.reset(seed=100_000)
    raw = preprocess_observation(_stack_obs([obs]))
    batch = pre(dict(raw))
    env.close()
    readers = [s for s in getattr(pre, "steps", []) if isinstance(s, PixelKeypointsProcessorStep)]
    cfg = policy.config
    cfg.execution = "dcdp"
    corrector, kernel = policy.corrector, policy.kernel
    parts: dict[str, list[float]] = {"frame encoding + bank": [], "extractor": [], "head": []}
    for fast in (False, True):
        policy.fast_inference = fast
        policy.reset()
        policy.select_action(dict(batch))  # plans a chunk: z, plan-time state (and the kernel)
        state = policy.state
        if fast and state.kernel is not None:
            parts["whole step, compiled kernel"] = []
        for i in range(warmup + steps):
            step = 1 + i % (cfg.n_action_steps - 1)
            if fast:
                if state.kernel is None:
                    break
                t0 = time.perf_counter()
                kernel.act(state, step, batch)
                if i >= warmup:
                    parts["whole step, compiled kernel"].append((time.perf_counter() - t0) * 1e3)
                continue
            t0 = time.perf_counter()
            corrector.push_frame(state, batch)
            t1 = time.perf_counter()
            corrector.feature(state)
            t2 = time.perf_counter()
            corrector.step(state, step, batch)  # computes F again: the head is this call minus the extractor
            t3 = time.perf_counter()
            if i >= warmup:
                parts["frame encoding + bank"].append((t1 - t0) * 1e3)
                parts["extractor"].append((t2 - t1) * 1e3)
                parts["head"].append(max(0.0, (t3 - t2) - (t2 - t1)) * 1e3)
    state, chunk = policy.state, policy.planned_chunk
    per_chunk = []
    for i in range(warmup + steps // 4):
        t0 = time.perf_counter()
        corrector.begin_chunk(state, chunk)
        if kernel is not None:
            kernel.prepare(state)
        if i >= warmup:
            per_chunk.append((time.perf_counter() - t0) * 1e3 / cfg.n_action_steps)
    policy.fast_inference = True
    for reader in readers:
        frame = raw[reader.image_key]
        parts["keypoint reader (pre-processor)"] = []
        for i in range(warmup + steps):
            t0 = time.perf_counter()
            reader.estimate(frame)
            if i >= warmup:
                parts["keypoint reader (pre-processor)"].append((time.perf_counter() - t0) * 1e3)
    out = {k: float(np.mean(v)) for k, v in parts.items() if v}
    out["per-chunk work / H"] = float(np.mean(per_chunk))
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-latency", description=__doc__.splitlines()[0])
    p.add_argument(
        "--corrector",
        default=shipped_model("pusht-dcdp-state"),
        help="corrector folder to time (default: the shipped diffusion corrector)",
    )
    p.add_argument(
        "--modes",
        nargs="+",
        default=list(DEFAULT_MODES),
        choices=MODES,
        help="execution modes to time (object_anchored only when the corrector names an anchor feature)",
    )
    p.add_argument("--episodes", type=int, default=2, help="episodes per mode and batch size")
    p.add_argument("--steps", type=int, default=300, help="control steps per episode")
    p.add_argument("--batches", type=int, nargs="+", default=[1, 50], help="batch sizes (envs) to time")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    p.add_argument("--device", default=None, help="where the policy runs (default: the folder's)")
    p.add_argument("--bid-weak", default=None, help="BID's weak reference policy folder (with --modes bid)")
    p.add_argument("--out", default="results/latency.json", help="JSON file the timings are written to")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    from lerobot_dcdp.benchmark.identity import git_commit, machine
    from lerobot_dcdp.benchmark.modes import load_model

    policy, pre, post, ident = load_model(a.corrector, a.device)
    policy.use_bid_reference(a.bid_weak)
    modes = [m for m in a.modes if m != "object_anchored" or policy.config.anchor_feature]
    res = {
        "command": "dcdp-latency " + " ".join(argv if argv is not None else sys.argv[1:]),
        "identity": ident,
        "bid_weak_policy": a.bid_weak,
        "machine": machine(),
        "git_commit": git_commit(),
        "per_step": {},
    }
    for b in a.batches:
        res["per_step"][str(b)] = time_modes(policy, pre, post, modes, a.episodes, a.steps, b, 100_000)
    res["corrector_parts_ms"] = corrector_parts(policy, pre)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    for b, per in res["per_step"].items():
        print(f"\nbatch {b}\n\n| mode | mean ms/step | p95 ms/step |\n|---|---|---|")
        for m, v in per.items():
            print(f"| {m} | {v['mean_ms']:.2f} | {v['p95_ms']:.2f} |")
        if "dcdp" in per and "open_loop" in per:
            mean, se = ratio_spread(per, "dcdp")
            n = len(per["dcdp"]["episode_mean_ms"])
            print(
                f"\nDCDP / open loop = {per['dcdp']['mean_ms'] / per['open_loop']['mean_ms']:.3f} "
                f"(per-episode ratios: {mean:.3f} +- {se:.3f} s.e., {n} episodes)"
            )
    print("\n| corrector part (batch 1) | mean ms/step |\n|---|---|")
    for k, v in res["corrector_parts_ms"].items():
        print(f"| {k} | {v:.3f} |")


if __name__ == "__main__":
    main()
