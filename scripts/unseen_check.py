"""Open loop vs DCDP (or the gated anchoring; and object anchoring) on drifts, directions and seeds no table
uses.

The benchmark's rollouts (same envs, lock-step loop and per-batch seeding as ``dcdp-benchmark``) with a
drift direction other than the protocol's 45 degrees (``constant``) or another direction set (``random``), a
magnitude between the protocol's, and seeds from 300000 (the tables use 100000..). Prints one row per
condition: score ± s.e. and success per method, and DCDP (without a ``dcdp`` method: ``gated_anchored``) -
open loop and - object anchoring (where run) on the same seeds (± the paired s.e.); with several conditions,
a last line pools those differences over all their episodes.

Usage: .venv/bin/python scripts/unseen_check.py [--policy models/pusht-dcdp-state-demos-late] [--episodes 30]
           [--seed-start 300000] [--conditions static constant:1.75:200 random:1.25 constant:0.6:300]
  a condition is ``static``, ``constant:<px/step>:<direction deg>`` or ``random:<px/step>`` (directions drawn
  from {0, 60, 120, 180, 240, 300} degrees, not the authors' set).
"""

from __future__ import annotations

import argparse

import numpy as np

UNSEEN_DIRECTIONS = [0.0, 60.0, 120.0, 180.0, 240.0, 300.0]


def parse_condition(text: str) -> tuple:
    """``(Condition, extra env kwargs)`` for one ``--conditions`` entry.

    Raises:
        ValueError: naming the entry and the accepted forms.
    """
    from lerobot_dcdp.benchmark.rollout import Condition

    parts = text.split(":")
    if parts == ["static"]:
        return Condition("static"), {}
    if parts[0] == "constant" and len(parts) == 3:
        return Condition(text, "constant", float(parts[1])), {"direction_deg": float(parts[2])}
    if parts[0] == "random" and len(parts) == 2:
        return Condition(text, "random", float(parts[1])), {"directions_deg": UNSEEN_DIRECTIONS}
    raise ValueError(f"condition {text!r}: expected static, constant:<px>:<deg> or random:<px>")


def main() -> None:
    import torch

    from lerobot_dcdp.benchmark.rollout import rollout
    from lerobot_dcdp.benchmark.run import load_model, set_mode

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-state-demos-late")
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--seed-start", type=int, default=300_000)
    p.add_argument("--methods", nargs="+", default=["open_loop", "object_anchored", "dcdp"])
    p.add_argument(
        "--conditions", nargs="+", default=["static", "constant:1.75:200", "random:1.25", "constant:0.6:300"]
    )
    a = p.parse_args()
    if a.episodes < 2:
        p.error("--episodes must be >= 2 (a standard error needs two)")
    torch.set_num_threads(1)
    policy, pre, post, _ = load_model(a.policy)
    seeds = list(range(a.seed_start, a.seed_start + a.episodes))
    print(f"policy {a.policy}, {a.episodes} episodes per cell from seed {a.seed_start}")
    judged = next((m for m in ("dcdp", "gated_anchored") if m in a.methods), None)
    # the judged method against open loop and, where run, the plain rule (its teacher), on the same seeds
    references = [m for m in ("open_loop", "object_anchored") if judged and m in a.methods and m != judged]
    difference = [f"{judged} - {m.replace('_', ' ')} (score, success points)" for m in references]
    print("| " + " | ".join(["condition", *a.methods, *difference]) + " |")
    print("|---" * (len(a.methods) + 1 + len(difference)) + "|")
    pooled: dict[str, list[np.ndarray]] = {ref: [] for ref in references}
    for text in a.conditions:
        cond, kwargs = parse_condition(text)
        res = {}
        for m in a.methods:
            set_mode(policy, m)
            res[m] = rollout(policy, pre, post, cond, seeds, env_kwargs=kwargs)
        cells = []
        for m in a.methods:
            r, rate = np.array(res[m].max_rewards), 100 * res[m].success_rate
            cells.append(f"{r.mean():.3f} ± {r.std(ddof=1) / np.sqrt(len(r)):.3f} ({rate:.0f} %)")
        diff = []
        for ref in references:
            d = np.array(res[judged].max_rewards) - np.array(res[ref].max_rewards)
            s = 100 * (res[judged].success_rate - res[ref].success_rate)
            won = np.array(res[judged].successes, float) - np.array(res[ref].successes, float)
            pooled[ref].append(np.stack([d, won]))
            diff.append(f"{d.mean():+.3f} ± {d.std(ddof=1) / np.sqrt(len(d)):.3f}, {s:+.0f}")
        print("| " + " | ".join([text, *cells, *diff]) + " |", flush=True)
    for ref, parts in pooled.items():  # every condition's episodes together: one paired difference
        if len(parts) > 1:
            d, s = np.concatenate(parts, axis=1)
            met = sum(p[0].mean() >= 0.03 for p in parts)
            print(
                f"pooled over {len(parts)} conditions ({d.size} paired episodes), {judged} - {ref}: score "
                f"{d.mean():+.3f} ± {d.std(ddof=1) / np.sqrt(d.size):.3f}, success {100 * s.mean():+.1f} "
                f"points; >= +0.03 in {met} of {len(parts)} conditions"
            )


if __name__ == "__main__":
    main()
