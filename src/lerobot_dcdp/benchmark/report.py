"""``docs/RESULTS.md`` (or a screen's report) from the benchmark's JSON: the protocol and provenance lines,
one section per model (Tables 1-3 and the goals, from :mod:`~lerobot_dcdp.benchmark.tables`), the plots
(:mod:`~lerobot_dcdp.benchmark.plots`) and the real-time summaries.

The tables, plots and cell helpers are re-exported here, where the benchmark's callers import them from.
"""

from __future__ import annotations

from pathlib import Path

from lerobot_dcdp.benchmark.cells import (
    CONDITION_ORDER,
    EXPERT,
    JUDGED_ROWS,
    KINDS,
    MAGNITUDES,
    METHOD_NAMES,
    OWN_ROWS,
    baseline_cell,
    cell_key,
    expert_name,
    magnitude,
)
from lerobot_dcdp.benchmark.image_goals import image_goals
from lerobot_dcdp.benchmark.plots import COLORS, EXPERT_COLOR, plot, plot_delay, plot_paths, success_plot_path
from lerobot_dcdp.benchmark.stats import paired_diff, score_se, success_se
from lerobot_dcdp.benchmark.tables import (
    ATTAINABLE_GAIN_POINTS,
    ATTAINABLE_MAX_DRIFT,
    NO_HARM_POINTS,
    NO_HARM_SCORE,
    fmt,
    gaps,
    mild_goals,
    table1,
    table2,
    table_delay,
    table_expert,
)

__all__ = [
    "ATTAINABLE_GAIN_POINTS",
    "ATTAINABLE_MAX_DRIFT",
    "COLORS",
    "CONDITION_ORDER",
    "EXPERT",
    "EXPERT_COLOR",
    "JUDGED_ROWS",
    "KINDS",
    "MAGNITUDES",
    "METHOD_NAMES",
    "NO_HARM_POINTS",
    "NO_HARM_SCORE",
    "OWN_ROWS",
    "baseline_cell",
    "cell_key",
    "expert_name",
    "expert_protocol",
    "fmt",
    "folder_line",
    "gaps",
    "mild_goals",
    "magnitude",
    "paired_diff",
    "plot",
    "plot_delay",
    "plot_paths",
    "protocol",
    "realtime_section",
    "score_se",
    "shown_path",
    "success_plot_path",
    "success_se",
    "table1",
    "table2",
    "table_delay",
    "table_expert",
    "write_report",
]


#: how the protocol line names each env observation type (``""``: a cell stored before they were recorded)
OBSERVATIONS = {
    "": "state + keypoint",
    "environment_state_agent_pos": "state + keypoint",
    "pixels_agent_pos": "camera (96x96) + agent position",
    "pixels_environment_state_agent_pos": "camera (96x96) + agent position + simulator keypoint",
}


def protocol(results: dict) -> str:
    """The protocol line, written from what the cells actually ran (the expert's cells: their own line)."""
    cells = [c for c in results["cells"].values() if c["model"] != EXPERT]
    experts = [c for c in results["cells"].values() if c["model"] == EXPERT]
    if not cells:
        cells = experts
    if not cells:
        return "- protocol: (no cells)"
    eps = sorted({c["episodes"] for c in cells})
    starts = sorted({c["seeds"][0] for c in cells})
    steps = sorted({c["max_steps"] for c in cells})
    # cells stored before the image protocol carry no obs_type: they read state + keypoints
    obs = sorted({OBSERVATIONS.get(c.get("obs_type", ""), c.get("obs_type")) for c in cells})
    return (
        f"- protocol: PushT (gym-pusht), {' / '.join(obs)} observations, {'/'.join(map(str, eps))} episodes "
        f"per cell from seed {'/'.join(map(str, starts))} (one episode per seed), "
        f"{'/'.join(map(str, steps))} steps max, an episode ends on coverage > 0.95; block drift applied "
        "once per control step (random: direction redrawn every 50 steps from the authors' set); "
        "policy noise "
        "seeded per batch; score = mean over episodes of max_t clip(coverage_t / 0.95, 0, 1) "
        "(LeRobot's `avg_max_reward`), ± its standard error; success = coverage > 0.95 at some step."
        + (expert_protocol(experts) if experts else "")
    )


def expert_protocol(experts: list[dict]) -> str:
    """What the expert row is, and how many episodes its cells ran."""
    eps = sorted({c["episodes"] for c in experts})
    chunk = experts[0].get("identity", {}).get("chunk", 8)
    return (
        f"\n- ceiling row (`{EXPERT}`): the privileged scripted expert (`lerobot_dcdp.sim.pusht_expert`) "
        "reads the simulator's true state (block pose, agent position and velocity), plans a push "
        f"primitive on an exact copy of the static physics, executes {chunk} steps of it and plans again; "
        "it does not know the drift and has no learned part. "
        f"{'/'.join(map(str, eps))} episodes per cell, same seeds and step limit, run once per condition "
        f"(not per base). A reference for what a chunked controller ({chunk} steps) with perfect state "
        "reaches, not a policy under test."
    )


def shown_path(path: str) -> str:
    """A model path as the report shows it: relative to the source checkout when it lies inside it (the
    shipped defaults are absolute paths), else as given."""
    p = Path(path)
    if not p.is_absolute():
        return path
    try:
        return str(p.resolve().relative_to(Path(__file__).resolve().parents[3]))
    except ValueError:
        return path


def realtime_section(realtime_dir: Path) -> list[str]:
    """The real-time measurements as report lines: every ``*.md`` in ``realtime_dir``, in name
    order, as written by the script that made it (``scripts/client_scores.sh``,
    ``scripts/rollout_deadlines.sh``, ``scripts/tick_times.py``), headings moved three levels down; none when
    the folder is absent or empty."""
    files = sorted(realtime_dir.glob("*.md")) if realtime_dir.is_dir() else []
    if not files:
        return []
    parts = [
        "## Real time: asynchronous planning and the base on LeRobot's policy server",
        "",
        f"Not `dcdp-benchmark`'s rollouts: the summaries in `{shown_path(str(realtime_dir))}`, written by "
        "`scripts/rollout_deadlines.sh` (`rollout_deadlines_*`), `scripts/client_scores.sh` "
        "(`client_scores_*`) and `scripts/tick_times.py` (`tick_times*`), copied here with their headings "
        "moved down (real-time runs on `pusht_sim`; "
        "how to read them: `docs/ROLLOUT.md`).",
        "",
    ]
    for f in files:
        body, fenced = [], False
        for line in f.read_text().splitlines():
            fenced ^= line.startswith("```")
            body.append("###" + line if line.startswith("#") and not fenced else line)
        parts += [f"### `{f.name}`", "", *body, ""]
    return parts


def folder_line(ident: dict, cells: list[dict]) -> str:
    """What a model folder holds: a corrector, or (no DCDP cell, a gated-anchoring one) the bare base's
    completion gate around a corrector that never runs."""
    methods = {c["method"] for c in cells}
    lead = (
        f", scene lead {ident['lead_steps']} steps (window {ident['lead_window']}) in its DCDP and gated rows"
        if ident.get("lead_steps")
        else ""
    )
    if "dcdp" not in methods and "gated_anchored" in methods:
        gate = ident.get("completion_gate_sha256", "?")[:12]
        return (
            f"completion gate `{shown_path(ident['corrector'])}` (sha256 `{gate}`; no corrector runs){lead}"
        )
    return (
        f"corrector `{shown_path(ident['corrector'])}` ({ident['corrector_params']:,} parameters, sha256 "
        f"`{ident['corrector_sha256'][:12]}`){lead}"
    )


def _header(results: dict, json_path: Path, plot_path: Path, success_path: Path) -> list[str]:
    """The report's title and provenance lines: command, machine, commit, protocol, where the data is."""
    m = results.get("machine", {})
    return [
        "# Results: DCDP on perturbed PushT",
        "",
        "Generated by `dcdp-benchmark` (`src/lerobot_dcdp/benchmark/`); do not edit by hand.",
        "Why each folder ships, what did not work and what is still open: `docs/FINDINGS.md`.",
        "",
        f"- command: `{results.get('command', 'dcdp-benchmark')}`",
        f"- machine: {m.get('cpu', '?')}, {m.get('cores', '?')} cores, torch {m.get('torch', '?')} "
        f"({m.get('torch_threads', '?')} thread), Python {m.get('python', '?')}, no GPU",
        f"- git commit: `{results.get('git_commit', '?')}`",
        protocol(results),
        f"- raw numbers: `{json_path}`; plots: `{plot_path}` (score), `{success_path}` (success)",
        "",
    ]


def _ceiling_section(results: dict) -> list[str]:
    """The privileged expert's own section (none without expert cells)."""
    ceiling = table_expert(results)
    if not ceiling:
        return []
    return [
        "## Ceiling: the privileged scripted expert",
        "",
        "Not a policy under test: it reads the simulator's true state (see the protocol above). "
        "Its row is repeated, in italics, at the foot of every model's Table 1.",
        "",
        ceiling,
        "",
    ]


def _model_section(results: dict, label: str, ident: dict, gaps_too: bool = True) -> list[str]:
    """One model's section: what it is, Tables 1 and 2, the gaps to the main protocol's goals (unless
    ``gaps_too`` is false), the mild protocol's goals for each judged row it has, and Table 3 when it ran
    delayed cells."""
    cells = [c for c in results["cells"].values() if c["model"] == label]
    n = cells[0]["episodes"] if cells else "?"
    parts = [
        f"## {label}",
        "",
        f"Base `{ident['base']}` ({ident['base_type']}, "
        f"weights sha256 `{ident['base_weights_sha256'][:12]}`), " + folder_line(ident, cells) + ", "
        f"{n} episodes per cell.",
        "",
        "### Table 1: score ± s.e. (success rate ± s.e.)",
        "",
        table1(results, label),
        "",
        "### Table 2: per-step latency (batch 1, CPU)",
        "",
        table2(results, label),
        "",
    ]
    if gaps_too:
        parts += ["### Gaps to the goals", "", gaps(results, label) or "(not enough cells)", ""]
    for method, name in JUDGED_ROWS.items():
        mild = mild_goals(results, label, method)
        if mild:
            title = "" if method == "dcdp" else f" ({name})"
            parts += [
                f"### Issue 22 goals{title}: no harm anywhere, success where it is attainable",
                "",
                mild,
                "",
            ]
    delayed = table_delay(results, label)
    if delayed:
        parts += [
            "### Table 3: a base that answers late (`--policy.inference_delay=d`)",
            "",
            "The chunk used from step t was planned from the observation of step t-d; the entries for "
            "the steps already past are skipped. Score ± s.e. (success rate ± s.e.); a baseline row the "
            "folder lacks is its base's on the same seeds.",
            "",
            delayed,
            "",
        ]
    return parts


def _figures(plot_path: Path, success_path: Path, delay_path: Path | None) -> list[str]:
    """The plots, linked from the report (which lives one folder below the checkout, in ``docs/``)."""
    parts = [
        "| score vs drift | success vs drift |",
        "|---|---|",
        f"| ![score vs drift]({Path('..') / plot_path}) | ![success vs drift]({Path('..') / success_path}) |",
        "",
    ]
    if delay_path is not None:
        parts += [f"![score vs delay]({Path('..') / delay_path})", ""]
    return parts


def write_report(results: dict, report: Path, json_path: Path, realtime_dir: Path | None = None) -> None:
    """Draw the plots beside ``json_path`` and write the Markdown report.

    Args:
        results: The benchmark JSON.
        report: The Markdown file to write (its folder is created).
        json_path: The results file: the plots are written beside it and the report names it.
        realtime_dir: The folder of real-time summaries to append, or ``None`` for none.
    """
    plot_path, delay_path = plot_paths(json_path)
    success_path = success_plot_path(json_path)
    plot(results, plot_path)
    plot(results, success_path, metric="success")
    has_delay = plot_delay(results, delay_path)
    parts = _header(results, json_path, plot_path, success_path) + _ceiling_section(results)
    pixels = image_goals(results)  # the image protocol's goals replace the main protocol's gaps
    if pixels:
        parts += ["## Issue 49 goals: corrections from pixels", "", pixels, ""]
    for label, ident in results.get("models", {}).items():
        parts += _model_section(results, label, ident, gaps_too=not pixels)
    parts += _figures(plot_path, success_path, delay_path if has_delay else None)
    if realtime_dir is not None:  # last: not this benchmark's rollouts
        parts += realtime_section(realtime_dir)
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text("\n".join(parts))
