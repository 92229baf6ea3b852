"""``dcdp-latency``: per-step cost of the corrector alone, with and without the per-frame feature cache.

Cached (what ``select_action`` does): encode the one new frame, run the temporal extractor over the bank
of M cached tokens, one GRU step. Uncached (the authors' code): encode all M frames of the window every
step, then the same. Batch 1, CPU, after a warm-up; prints a Markdown table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch


@torch.no_grad()
def corrector_step_costs(policy, steps: int = 300, warmup: int = 20) -> dict[str, dict[str, float]]:
    cfg = policy.config
    feats = cfg.input_features
    frame = {k: torch.randn(1, *feats[k].shape) for k in policy._frame_keys}
    window = {k: v.unsqueeze(1).repeat(1, cfg.n_history, *([1] * (v.dim() - 1))) for k, v in frame.items()}
    z = torch.zeros(1, cfg.latent_dim)
    policy._z, policy._h = z, policy.decoder.initial_state(z)
    bank = policy.frame_encoder(frame).unsqueeze(1).repeat(1, cfg.n_history, 1)

    def cached() -> None:
        nonlocal bank
        tok = policy.frame_encoder(frame)
        bank = torch.cat([bank[:, 1:], tok.unsqueeze(1)], dim=1)
        f, _ = policy.extractor(bank)
        policy.decode_step(f, 0)

    def uncached() -> None:
        f, _ = policy.extractor(policy.frame_encoder(window))
        policy.decode_step(f, 0)

    out = {}
    for name, fn in (("cached", cached), ("uncached", uncached)):
        for _ in range(warmup):
            fn()
        t = []
        for _ in range(steps):
            t0 = time.perf_counter()
            fn()
            t.append((time.perf_counter() - t0) * 1e3)
        out[name] = {"mean_ms": float(np.mean(t)), "p95_ms": float(np.percentile(t, 95))}
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-latency", description=__doc__.splitlines()[0])
    p.add_argument("--corrector", default="models/pusht-dcdp-state")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", default="results/corrector_latency.json")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    import lerobot_policy_dcdp  # noqa: F401
    from lerobot_dcdp.benchmark.run import machine
    from lerobot_dcdp.modeling_dcdp import DCDPPolicy

    policy = DCDPPolicy.from_pretrained(a.corrector).eval()
    costs = corrector_step_costs(policy, a.steps)
    res = {
        "corrector": a.corrector,
        "n_history": policy.config.n_history,
        "steps": a.steps,
        "costs": costs,
        "corrector_params": sum(p.numel() for p in policy.parameters()),
        "machine": machine(),
        "command": "dcdp-latency " + " ".join(argv or []),
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1))
    print("| corrector step | mean (ms) | p95 (ms) |\n|---|---|---|")
    for k, v in costs.items():
        print(f"| {k} (M={policy.config.n_history}) | {v['mean_ms']:.3f} | {v['p95_ms']:.3f} |")


if __name__ == "__main__":
    main()
