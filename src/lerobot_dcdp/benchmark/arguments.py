"""``dcdp-benchmark``'s command line: the argument parser, and the protocol's values for the flags not
given."""

from __future__ import annotations

import argparse
from pathlib import Path

from lerobot_dcdp.benchmark.cells import EXPERT
from lerobot_dcdp.benchmark.protocols import BID_WEAK, DEFAULT_MODELS, METHODS, protocols

#: the parser's description: the first line of :mod:`lerobot_dcdp.benchmark.run`'s docstring
DESCRIPTION = "``dcdp-benchmark``: every execution mode x every perturbation, 50 fixed seeds, one protocol."
#: the flags a protocol fills in when they are not given
PRESET_FLAGS = ("methods", "conditions", "episodes", "latency_steps", "videos", "out", "report")


def build_parser(presets: dict[str, dict]) -> argparse.ArgumentParser:
    """The argument parser of ``dcdp-benchmark`` (the flags a protocol fills in default to ``None``).

    Args:
        presets: The named protocols (:func:`~lerobot_dcdp.benchmark.protocols.protocols`).

    Returns:
        The parser.
    """
    from lerobot_dcdp.benchmark.rollout import CONDITIONS, EXPERT_CHUNK

    p = argparse.ArgumentParser(prog="dcdp-benchmark", description=DESCRIPTION)
    p.add_argument(
        "--protocol",
        choices=sorted(presets),
        default="main",
        help="main: 50 episodes, every drift (default); mild: 100 episodes at 0-1 px/step; image: the image "
        "base and its corrector from pixels, 100 episodes (mild and image: own results file and report)",
    )
    p.add_argument(
        "--model",
        action="append",
        default=None,
        metavar="LABEL=DIR",
        help="a corrector checkpoint to benchmark (repeatable); default: the protocol's shipped ones",
    )
    p.add_argument(
        "--methods",
        nargs="+",
        default=None,
        choices=METHODS + [EXPERT],
        help=f"'{EXPERT}': the privileged scripted expert (true state, chunks of --expert-chunk), once per "
        "condition",
    )
    p.add_argument(
        "--conditions",
        nargs="+",
        default=None,
        choices=[c.name for c in CONDITIONS],
        help="PushT perturbations: static or <constant|random>_<px per step> (default: the protocol's)",
    )
    p.add_argument(
        "--delays", nargs="+", type=int, default=[0], help="inference delays d (control steps) to run"
    )
    p.add_argument("--episodes", type=int, default=None, help="per cell (main: 50, mild: 100)")
    p.add_argument("--expert-episodes", type=int, default=None, help="per expert cell (default: --episodes)")
    p.add_argument("--expert-chunk", type=int, default=EXPERT_CHUNK, help="steps the expert runs per plan")
    p.add_argument(
        "--seed-start", type=int, default=100_000, help="seed of the first episode; one seed per episode"
    )
    p.add_argument("--max-steps", type=int, default=300, help="control steps per episode at most")
    p.add_argument("--batch-size", type=int, default=50, help="envs rolled out together")
    p.add_argument("--latency-steps", type=int, default=None, help="batch-1 steps timed per method (0: skip)")
    p.add_argument("--latency-rounds", type=int, default=10, help="episodes per method, interleaved")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    p.add_argument(
        "--device",
        default=None,
        help="where the policies run (default: each folder's, CPU for the shipped ones; e.g. cuda: BID "
        "samples 30 chunks per step)",
    )
    p.add_argument("--videos", type=int, default=None, help="side-by-side open_loop|dcdp videos to render")
    p.add_argument("--out", default=None, help="results file (main: results/benchmark.json)")
    p.add_argument(
        "--report",
        default=None,
        help="generated report (main: docs/RESULTS.md; with --out: the results file's name with .md)",
    )
    p.add_argument(
        "--bid-weak",
        action="append",
        default=None,
        metavar="LABEL=DIR",
        help="BID's weak reference policy for a model (repeatable); default: the shipped early checkpoint "
        "of the diffusion base for the diffusion models; a model without one runs BID without it",
    )
    p.add_argument("--force", action="store_true", help="recompute finished cells (and replace any cell)")
    return p


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line, with ``--protocol``'s values for the flags not given.

    Besides the flags, the namespace holds ``realtime`` (the protocol's real-time summaries folder, or
    ``None``), ``models`` (label -> folder: the ``--model`` ones, else the protocol's shipped folders that
    exist), ``model_methods`` (label -> the methods the protocol runs for it; empty for ``--model``) and
    ``bid_weak`` (label -> BID's weak reference policy folder).

    Args:
        argv: The arguments (default: ``sys.argv[1:]``).

    Returns:
        The parsed and completed arguments.

    Raises:
        SystemExit: on a bad flag (argparse's message).
    """
    presets = protocols()
    p = build_parser(presets)
    a = p.parse_args(argv)
    preset = presets[a.protocol]
    if a.out is not None and a.report is None:  # a screen of one's own never rewrites the shipped report
        a.report = str(Path(a.out).with_suffix(".md"))
    for key in PRESET_FLAGS:
        if getattr(a, key) is None:
            setattr(a, key, preset[key])
    a.realtime = preset["realtime"]
    if a.expert_episodes is None:
        a.expert_episodes = a.episodes
    for key in ("episodes", "expert_episodes", "expert_chunk"):
        if getattr(a, key) < 1:
            p.error(f"--{key.replace('_', '-')} must be >= 1")
    a.models = (
        dict(m.split("=", 1) for m in a.model)
        if a.model
        else {k: v for k, v in (preset["models"] or DEFAULT_MODELS).items() if Path(v).is_dir()}
    )
    # explicit correctors run every requested method; the protocol's own, those it names for them
    a.model_methods = {} if a.model else preset["model_methods"]
    a.bid_weak = (
        dict(m.split("=", 1) for m in a.bid_weak)
        if a.bid_weak
        else {k: v for k, v in BID_WEAK.items() if Path(v).is_dir()}
    )
    return a
