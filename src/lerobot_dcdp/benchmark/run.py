"""``dcdp-benchmark``: every execution mode x every perturbation, 50 fixed seeds, one protocol.

For each corrector given with ``--model LABEL=DIR`` (default: the shipped diffusion, paper-recipe, ACT and
demonstrations-only correctors) the base it records is run as ``open_loop`` (H = 8), ``closed_loop`` (H = 1),
``temporal_ensemble`` (H = 1, 0.5), ``object_anchored`` (H = 8, when the corrector names an anchor feature),
``gated_anchored`` (``object_anchored`` with the folder's completion gate, when it has one) and ``dcdp``
(H = 8) on static PushT and under constant / random block drift of 0.5 to 2.5 px per step;
``--delays 0 2 4`` adds a base that answers d control steps late (``inference_delay``); ``--methods bid``
runs Bidirectional Decoding over the base (with ``--bid-weak``, default the shipped weak checkpoint for the
diffusion models; ~25 min of one CPU core per 10 drifting episodes, ``--device cuda`` where there is one);
``--protocol image`` the image base and its corrector from pixels.
Seeds 100000.., 300 steps max, an episode ends on success (coverage > 0.95). Writes ``results/benchmark.json``
(finished cells are kept and not recomputed; a run cut off inside a cell resumes it at its next batch of
``--batch-size`` episodes, from ``<results>.partial/``), the per-step latency at batch 1, a plot,
side-by-side videos and ``docs/RESULTS.md``.

``--protocol mild`` (mild drift) is the protocol where an episode can still succeed: static and constant /
random drift of 0.5, 0.75 and 1.0 px per step, 100 episodes per cell, the demonstrations-only correctors
with open loop, object anchoring and DCDP, the gated correctors and the gated anchorings, plus the ``expert``
row (the privileged scripted expert executing 8-step chunks, a ceiling), into its own
``results/benchmark_mild.json`` and ``docs/RESULTS_MILD.md``. Any flag given explicitly overrides the
protocol's value. A stored cell of another episode count is never replaced without ``--force``.

This module is the command's entry point (:func:`main`); the parts live beside it: ``arguments`` (the
parser), ``protocols`` (the presets and default correctors), ``modes`` (loading a folder, its execution
modes), ``run_cells`` (rollouts, latency, the expert row), ``cell_checkpoint`` (a cell's finished batches),
``results_file`` (reuse, merging, writing),
``identity`` (machine, commit, scene lead), ``videos`` and ``report``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_dcdp.benchmark.arguments import build_parser, parse_args
from lerobot_dcdp.benchmark.cells import EXPERT, cell_key
from lerobot_dcdp.benchmark.identity import LEAD_IDENTITY, git_commit, lead_identity, machine
from lerobot_dcdp.benchmark.modes import load_model, runs, set_mode
from lerobot_dcdp.benchmark.protocols import (
    DEFAULT_METHODS,
    DEFAULT_MODELS,
    METHODS,
    MILD_MODELS,
    model_methods,
    protocols,
)
from lerobot_dcdp.benchmark.results_file import (
    ResultsFile,
    conflict_message,
    episode_conflicts,
    fresh_cell,
    fresh_expert_cell,
    merge_results,
)
from lerobot_dcdp.benchmark.run_cells import run_expert_cells, run_model

# the names callers (``dcdp-latency``, ``dcdp-demo``, the tests) import from this module
__all__ = [
    "DEFAULT_METHODS",
    "DEFAULT_MODELS",
    "EXPERT",
    "LEAD_IDENTITY",
    "METHODS",
    "MILD_MODELS",
    "build_parser",
    "cell_key",
    "episode_conflicts",
    "git_commit",
    "lead_identity",
    "load_model",
    "machine",
    "main",
    "merge_results",
    "model_methods",
    "parse_args",
    "protocols",
    "run_expert_cells",
    "runs",
    "set_mode",
    "wanted_cells",
]
#: the former private names of the cell reuse checks
_fresh = fresh_cell
_fresh_expert = fresh_expert_cell


def wanted_cells(a: argparse.Namespace, seeds: list[int], expert_seeds: list[int]) -> dict[str, int]:
    """Every cell this run may write (cell key -> episodes): each model's methods x conditions x delays,
    and the expert's row when asked."""
    wanted = {
        cell_key(label, m, c, d): len(seeds)
        for label in a.models
        for m in model_methods(a, label)
        for c in a.conditions
        for d in a.delays
    }
    if EXPERT in a.methods:
        wanted.update({cell_key(EXPERT, EXPERT, c): len(expert_seeds) for c in a.conditions})
    return wanted


def main(argv: list[str] | None = None) -> None:
    """Run ``dcdp-benchmark``: every missing cell into the results file, then the report.

    Args:
        argv: The arguments (default: ``sys.argv[1:]``).

    Raises:
        SystemExit: on a bad flag, when no corrector is found, or when the results file holds cells of
            another episode count that this run would replace (without ``--force``).
    """
    from lerobot_dcdp.benchmark.report import write_report
    from lerobot_dcdp.benchmark.rollout import CONDITIONS

    a = parse_args(argv)

    import torch

    torch.set_num_threads(a.threads)
    if not a.models and any(m != EXPERT for m in a.methods):
        sys.exit("dcdp-benchmark: error: no corrector found; pass --model LABEL=DIR")
    out = Path(a.out)
    store = ResultsFile(out)
    results = store.results
    seeds = list(range(a.seed_start, a.seed_start + a.episodes))
    expert_seeds = list(range(a.seed_start, a.seed_start + a.expert_episodes))
    conflicts = [] if a.force else episode_conflicts(results["cells"], wanted_cells(a, seeds, expert_seeds))
    if conflicts:
        sys.exit(conflict_message(out, conflicts))
    results["command"] = "dcdp-benchmark " + " ".join(argv if argv is not None else sys.argv[1:])
    results["machine"] = machine()
    results["git_commit"] = git_commit()
    conds = {c.name: c for c in CONDITIONS}
    for label, path in a.models.items():
        if model_methods(a, label):
            run_model(a, store, label, path, seeds, conds)
    if EXPERT in a.methods:
        run_expert_cells(a, results, conds, expert_seeds, store.save)
    write_report(results, Path(a.report), out, Path(a.realtime) if a.realtime else None)
    print(f"wrote {out} and {a.report}")


if __name__ == "__main__":
    main()
