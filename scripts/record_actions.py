"""Record the actions of shipped correctors in every execution / planning mode, to compare two code versions.

A refactor that must not change behaviour: run this before and after it and compare the two files
(``--compare A B`` prints the largest action difference and whether the episode scores match per run).

    .venv/bin/python scripts/record_actions.py runs/actions_before.pt        # on the old commit
    .venv/bin/python scripts/record_actions.py runs/actions_after.pt         # on the new one
    .venv/bin/python scripts/record_actions.py --compare runs/actions_before.pt runs/actions_after.pt
"""

from __future__ import annotations

import argparse

import torch

from lerobot_dcdp.benchmark import shipped_model
from lerobot_dcdp.benchmark.rollout import Condition, rollout
from lerobot_dcdp.benchmark.run import load_model, set_mode

MODELS = {
    "diffusion": "pusht-dcdp-state",
    "paper_recipe": "pusht-dcdp-state-paper-recipe",
    "act_demos": "pusht-dcdp-act-state-demos",
}
#: (execution, inference_delay, planning, fast_inference)
RUNS = [
    (m, d, "sync", True)
    for m in ("open_loop", "closed_loop", "temporal_ensemble", "object_anchored", "dcdp")
    for d in (0, 2)
]
RUNS += [
    ("dcdp", 0, "sync", False),
    ("dcdp", 2, "async", True),
    ("open_loop", 2, "async", True),
    ("object_anchored", 3, "async", True),
    ("dcdp", 0, "async", True),
]


def record(path: str) -> None:
    torch.set_num_threads(1)
    out = {}
    condition = Condition("constant_2.0", "constant", 2.0)
    for label, name in MODELS.items():
        policy, pre, post, _ = load_model(shipped_model(name))
        actions: list[torch.Tensor] = []
        select = policy.select_action

        def recorded(batch, select=select, policy=policy, actions=actions):
            a = select(batch)
            actions.append(a.clone())
            if len(actions) % 13 == 5 and policy.config.planning == "sync":  # the query changes nothing
                actions.append(policy.predict_action_chunk(batch).clone())
            return a

        policy.select_action = recorded
        for mode, delay, planning, fast in RUNS:
            if mode == "object_anchored" and not policy.config.anchor_feature:
                continue
            policy.config.planning, policy.config.planning_clock = planning, "steps"
            policy.fast_inference = fast
            set_mode(policy, mode, delay)
            actions.clear()
            result = rollout(policy, pre, post, condition, [100000, 100001], max_steps=40)
            out[(label, mode, delay, planning, fast)] = (
                torch.cat([a.reshape(-1) for a in actions]),
                result.max_rewards,
            )
        policy.close()
    torch.save(out, path)
    print(f"wrote {len(out)} runs to {path}")


def compare(a_path: str, b_path: str) -> None:
    a, b = torch.load(a_path, weights_only=False), torch.load(b_path, weights_only=False)
    if a.keys() != b.keys():
        raise SystemExit(f"different runs: {sorted(set(a) ^ set(b))}")
    for key in a:
        (xa, ra), (xb, rb) = a[key], b[key]
        diff = (xa - xb).abs().max().item() if xa.shape == xb.shape else float("inf")
        print(
            key, f"max |action difference| {diff:.2e}", "scores equal" if ra == rb else f"scores {ra} vs {rb}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", help="file to write the recorded actions to")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"))
    args = parser.parse_args()
    if args.compare:
        compare(*args.compare)
    elif args.out:
        record(args.out)
    else:
        parser.error("give an output file or --compare A B")


if __name__ == "__main__":
    main()
