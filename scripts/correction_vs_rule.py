"""Does the learned correction follow the analytic rule, and how far? (diagnosis)

Runs one benchmark condition (same envs, seeds and seeding as ``near_misses.py``) with a corrector folder in
``dcdp`` (as the benchmark runs it: its gate and lead) and, at every step, also asks the plain
``object_anchored`` rule what it would do with the same plan, step and (led) observation. Prints, over the
steps the rule moves the planned action by more than ``--min-px``, how much of the rule's change the corrector
makes: the least-squares slope of the corrector's change on the rule's (1: the rule's size; < 1: it shrinks
the correction), the share of the rule's change it leaves out (residual RMS / rule RMS), and both per
step of the chunk. Raw action units (PushT: px), before the gate and the lead's move back. ``--blend w``
executes ``(1 - w)`` x the corrector's action + ``w`` x the rule's (is their mean better than either?).

Usage: .venv/bin/python scripts/correction_vs_rule.py --policy models/pusht-dcdp-act-state-demos-late-gated
           [--condition constant_2.0] [--episodes 50] [--min-px 1]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def main() -> None:
    from lerobot.utils.constants import ACTION
    from near_misses import condition_rollout

    from lerobot_dcdp.lockstep import run_lockstep

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="models/pusht-dcdp-act-state-demos-late-gated")
    p.add_argument("--condition", default="constant_2.0")
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--min-px", type=float, default=1.0)
    p.add_argument(
        "--blend",
        type=float,
        default=0.0,
        help="execute (1 - blend) x the corrector's action + blend x the rule's (0: the corrector)",
    )
    a = p.parse_args()
    torch.set_num_threads(1)
    policy, _, act, envs, seeds = condition_rollout(a.policy, a.condition, a.episodes, "dcdp")
    corrected, rule_mode = policy.modes["dcdp"], policy.modes["object_anchored"]
    corrected.anchored = (
        True  # keep the plan-time keypoints the rule needs (the corrector does not read them)
    )
    rows = []  # (step in chunk, corrector change xy, rule change xy)
    run_corrected = corrected.act

    def both(state, step, batch):
        out = run_corrected(state, step, batch)
        rule = rule_mode.act(state, step, batch)
        plan = state.chunk[:, step]

        def to_raw(x):
            return policy.normalizer(ACTION, x, inverse=True)

        c, r = (to_raw(out) - to_raw(plan))[:, :2], (to_raw(rule) - to_raw(plan))[:, :2]
        rows.extend((step, *ci, *ri) for ci, ri in zip(c.tolist(), r.tolist(), strict=True))
        return out if not a.blend else (1 - a.blend) * out + a.blend * rule

    corrected.act = both
    out = run_lockstep(envs, seeds, act, 300)
    for env in envs:
        env.close()
    d = np.asarray(rows)
    step, c, r = d[:, 0], d[:, 1:3], d[:, 3:5]
    big = np.linalg.norm(r, axis=1) > a.min_px
    print(
        f"{a.policy} {a.condition} blend {a.blend:g}: score {np.mean(out.max_rewards):.3f}, "
        f"success {100 * np.mean(out.successes):.0f} %, "
        f"{big.sum()} of {len(d)} steps the rule moves > {a.min_px:g}"
    )

    def line(mask: np.ndarray, name: str) -> None:
        cc, rr = c[mask & big], r[mask & big]
        if not len(cc):
            return
        slope = float((cc * rr).sum() / (rr * rr).sum())
        rule_rms, corrector_rms = np.sqrt((rr**2).sum(1).mean()), np.sqrt((cc**2).sum(1).mean())
        left = float(np.sqrt(((cc - rr) ** 2).sum(1).mean()) / rule_rms)
        print(
            f"  {name:8s} rule {rule_rms:6.2f}, corrector {corrector_rms:6.2f} RMS; slope {slope:.2f}; "
            f"residual / rule {left:.2f} ({len(cc)} steps)"
        )

    line(np.ones(len(d), bool), "all")
    for s in sorted(set(step.astype(int))):
        line(step == s, f"step {s}")


if __name__ == "__main__":
    main()
