"""Tables shaped like the paper's Tables 1-2, the score- and success-vs-drift plots and docs/RESULTS.md, from
the benchmark's JSON."""

from __future__ import annotations

from pathlib import Path

METHOD_NAMES = {
    "open_loop": "Open loop (H=8)",
    "closed_loop": "Closed loop (H=1)",
    "temporal_ensemble": "Temporal ensemble (H=1, 0.5)",
    "object_anchored": "Object-anchored chunk (H=8, training-free)",
    "gated_anchored": "Object-anchored chunk + completion gate (H=8, no corrector)",
    "dcdp": "DCDP (H=8)",
}
#: rows that depend on what the model folder learned (corrector, gate): never borrowed from another model
OWN_ROWS = ("dcdp", "gated_anchored")
#: the rows judged against open loop by issue 22's goals, with their names in that table
JUDGED_ROWS = {"dcdp": "DCDP", "gated_anchored": "gated anchoring"}
COLORS = {
    "open_loop": "C0",
    "closed_loop": "C1",
    "temporal_ensemble": "C2",
    "object_anchored": "C4",
    "gated_anchored": "C5",
    "dcdp": "C3",
}
#: The ceiling row (the privileged scripted expert, ``--methods expert``): cells ``expert|expert|<cond>``,
#: run once per condition (no corrector, no base) and shown in every model's table.
EXPERT = "expert"
EXPERT_COLOR = "k"
KINDS = ("constant", "random")
MAGNITUDES = (0.5, 0.75, 1.0, 1.5, 2.0, 2.5)
CONDITION_ORDER = ["static"] + [f"{k}_{m}" for m in MAGNITUDES for k in KINDS]
#: Issue 22: drifts where an episode can still succeed (DCDP success >= open loop + 15 points there) ...
ATTAINABLE_MAX_DRIFT = 1.0
ATTAINABLE_GAIN_POINTS = 15.0
#: ... and no harm anywhere (DCDP >= open loop - 4 success points and - 0.01 score).
NO_HARM_POINTS, NO_HARM_SCORE = -4.0, -0.01


def expert_name(cell: dict | None = None) -> str:
    """The ceiling row's label (its chunk length read from the cell when given)."""
    chunk = (cell or {}).get("identity", {}).get("chunk", 8)
    return f"Privileged expert (true state, {chunk}-step chunks): ceiling, not a policy"


def magnitude(condition: str) -> float:
    """Drift in px per control step of a condition name (``static``: 0)."""
    return 0.0 if condition == "static" else float(condition.split("_")[1])


def _conditions(cells: dict, label: str) -> list[str]:
    present = {c["condition"] for c in cells.values() if c["model"] == label}
    return [c for c in CONDITION_ORDER if c in present]


def score_se(cell: dict) -> float:
    """Standard error of the mean score over the cell's episodes."""
    import numpy as np

    x = np.asarray(cell.get("max_rewards") or [cell["score"]], dtype=float)
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def success_se(cell: dict) -> float:
    """Standard error of the success rate (binomial), in the rate's units."""
    p, n = cell["success_rate"], cell.get("episodes", 1)
    return (p * (1 - p) / n) ** 0.5


def fmt(cell: dict | None) -> str:
    if cell is None:
        return "-"
    return (
        f"{cell['score']:.3f} ± {score_se(cell):.3f} "
        f"({100 * cell['success_rate']:.0f} ± {100 * success_se(cell):.0f} %)"
    )


def table1(results: dict, label: str) -> str:
    """Score ± standard error (success rate ± standard error) per method and condition; the privileged
    expert's row (when its cells exist) last, labelled as a ceiling."""
    cells = results["cells"]
    conds = _conditions(cells, label)
    lines = ["| method | " + " | ".join(conds) + " |", "|" + "---|" * (len(conds) + 1)]
    for m, name in METHOD_NAMES.items():
        row = [fmt(cells.get(f"{label}|{m}|{c}")) for c in conds]
        if any(r != "-" for r in row):
            lines.append(f"| {name} | " + " | ".join(row) + " |")
    experts = [cells.get(cell_key(EXPERT, EXPERT, c)) for c in conds]
    if any(experts):
        first = next(e for e in experts if e)
        row = [
            fmt(e) + ("" if not e or e["episodes"] == first["episodes"] else f", n={e['episodes']}")
            for e in experts
        ]
        lines.append(f"| *{expert_name(first)}* | " + " | ".join(row) + " |")
    return "\n".join(lines)


def table_expert(results: dict) -> str:
    """The privileged expert's cells as one row (score ± s.e. (success ± s.e.), episodes); empty if none."""
    cells = results["cells"]
    conds = [c for c in CONDITION_ORDER if cell_key(EXPERT, EXPERT, c) in cells]
    if not conds:
        return ""
    row = [cells[cell_key(EXPERT, EXPERT, c)] for c in conds]
    return "\n".join(
        [
            "| row | " + " | ".join(conds) + " |",
            "|" + "---|" * (len(conds) + 1),
            f"| *{expert_name(row[0])}* | " + " | ".join(fmt(c) for c in row) + " |",
            "| episodes | " + " | ".join(str(c["episodes"]) for c in row) + " |",
        ]
    )


def paired_diff(new: dict, old: dict, key: str) -> tuple[float, float]:
    """Mean of ``new - old`` over the episodes (``key``: ``max_rewards`` or ``successes``) and its standard
    error: paired over the seeds when both cells ran the same seeds, else from the two cells' own s.e."""
    import numpy as np

    a = np.asarray(new.get(key) or [], dtype=float)
    b = np.asarray(old.get(key) or [], dtype=float)
    if len(a) == len(b) > 1 and new.get("seeds") == old.get("seeds"):
        d = a - b
        return float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d)))
    if key == "successes":
        return new["success_rate"] - old["success_rate"], (success_se(new) ** 2 + success_se(old) ** 2) ** 0.5
    return new["score"] - old["score"], (score_se(new) ** 2 + score_se(old) ** 2) ** 0.5


def baseline_cell(results: dict, label: str, method: str, condition: str, delay: int = 0) -> dict | None:
    """``label``'s own cell of ``method``, else -- for a baseline, which uses nothing the folder learned --
    the cell of another model on the same base (weights hash) and the same seeds as ``label``'s own judged
    cell (``JUDGED_ROWS``)."""
    cells = results["cells"]
    own = cells.get(cell_key(label, method, condition, delay))
    if own is not None or method in OWN_ROWS:
        return own
    models = results.get("models", {})
    base = models.get(label, {}).get("base_weights_sha256")
    mine = next(
        (c for m in JUDGED_ROWS if (c := cells.get(cell_key(label, m, condition, delay))) is not None), None
    )
    for other, ident in models.items():
        cell = cells.get(cell_key(other, method, condition, delay))
        if (
            other != label
            and cell is not None
            and base is not None
            and ident.get("base_weights_sha256") == base
            and (mine is None or cell.get("seeds") == mine.get("seeds"))
        ):
            return cell
    return None


def goals_issue22(results: dict, label: str, method: str = "dcdp") -> str:
    """Issue 22's goals, ``method`` (a ``JUDGED_ROWS`` row: DCDP, or the gated anchoring) against open loop
    on the same seeds, per condition: no harm anywhere (success >= -4 points, score >= -0.01) and, where
    success is attainable (constant / random drift up to 1.0 px per step), success >= +15 points. Empty when
    no condition up to 1.0 px/step has both rows."""
    cells = results["cells"]
    name = JUDGED_ROWS[method]
    conds = [
        c
        for c in _conditions(cells, label)
        if cells.get(cell_key(label, method, c)) and baseline_cell(results, label, "open_loop", c)
    ]
    if not any(magnitude(c) <= ATTAINABLE_MAX_DRIFT for c in conds):
        return ""
    lines = [
        f"{name} - open loop on the same seeds, ± the paired standard error (a model without its own "
        "open-loop row: the row of another model on the same base and seeds). Margin = difference - goal "
        "(>= 0: met).",
        "",
        f"| condition | open loop success | {name} success | Δ success (points) | Δ score | no harm: "
        f"Δ success >= {NO_HARM_POINTS:+.0f} | no harm: Δ score >= {NO_HARM_SCORE:+.2f} | "
        f"attainable: Δ success >= +{ATTAINABLE_GAIN_POINTS:.0f} |",
        "|---|---|---|---|---|---|---|---|",
    ]

    def verdict(margin: float, digits: int) -> str:
        return f"{'met' if margin >= 0 else '**missed**'} ({margin:+.{digits}f})"

    for c in conds:
        d, o = cells[cell_key(label, method, c)], baseline_cell(results, label, "open_loop", c)
        ds, ds_se = paired_diff(d, o, "successes")
        dr, dr_se = paired_diff(d, o, "max_rewards")
        attain = (
            verdict(100 * ds - ATTAINABLE_GAIN_POINTS, 0) if 0 < magnitude(c) <= ATTAINABLE_MAX_DRIFT else "-"
        )
        lines.append(
            f"| {c} | {100 * o['success_rate']:.0f} % | {100 * d['success_rate']:.0f} % | "
            f"{100 * ds:+.0f} ± {100 * ds_se:.0f} | {dr:+.3f} ± {dr_se:.3f} | "
            f"{verdict(100 * ds - NO_HARM_POINTS, 0)} | {verdict(dr - NO_HARM_SCORE, 3)} | {attain} |"
        )
    return "\n".join(lines)


def table2(results: dict, label: str) -> str:
    lat = {k: v for k, v in results.get("latency", {}).items() if v["model"] == label}
    if not lat:
        return "(no latency measured)"
    lines = ["| method | per-step latency mean (ms) | p95 (ms) |", "|---|---|---|"]
    for m, name in METHOD_NAMES.items():
        v = lat.get(f"{label}|{m}")
        if v:
            lines.append(f"| {name} | {v['mean_ms']:.2f} | {v['p95_ms']:.2f} |")
    ol, dc, cl = (lat.get(f"{label}|{m}") for m in ("open_loop", "dcdp", "closed_loop"))
    if ol and dc:
        lines.append(f"\nDCDP / open loop = {dc['mean_ms'] / ol['mean_ms']:.3f} (paper: 1.048)")
    if cl and dc:
        lines.append(f"closed loop / DCDP = {cl['mean_ms'] / dc['mean_ms']:.2f}")
    return "\n".join(lines)


def gaps(results: dict, label: str) -> str:
    """The corrector issue's goals, as measured gaps in score (positive = goal met with margin), for the
    folder's judged row: DCDP, or (a gate-only folder without DCDP cells) the gated anchoring."""
    cells = results["cells"]
    method = next(
        (m for m in JUDGED_ROWS if any(c["model"] == label and c["method"] == m for c in cells.values())),
        "dcdp",
    )
    name = JUDGED_ROWS[method]

    def get(m: str, c: str) -> dict | None:
        return baseline_cell(results, label, m, c)

    out = []
    for c in ("constant_2.0", "random_2.0"):
        d, o = get(method, c), get("open_loop", c)
        if d and o:
            out.append(f"- {c}: {name} - open loop = {d['score'] - o['score']:+.3f} score (goal >= +0.20)")
        for m in ("closed_loop", "temporal_ensemble"):
            x = get(m, c)
            if d and x:
                out.append(f"- {c}: {name} - {m} = {d['score'] - x['score']:+.3f} score (goal > 0)")
    for c in _conditions(cells, label):
        if c == "static" or float(c.split("_")[1]) < 1.0:
            continue
        d, x = get(method, c), get("object_anchored", c)
        if d and x:
            out.append(
                f"- {c}: {name} - object_anchored = {d['score'] - x['score']:+.3f} score (moonshot > 0)"
            )
    d, o = get(method, "static"), get("open_loop", "static")
    if d and o:
        out.append(f"- static: {name} - open loop = {d['score'] - o['score']:+.3f} score (goal >= -0.01)")
        out.append(
            f"- static: {name} - open loop = {100 * (d['success_rate'] - o['success_rate']):+.0f} success "
            "points (goal >= -4)"
        )
    return "\n".join(out)


def _delays(cells: dict, label: str) -> list[int]:
    return sorted({c.get("inference_delay", 0) for c in cells.values() if c["model"] == label})


def cell_key(label: str, method: str, condition: str, delay: int = 0) -> str:
    """A cell's key in the benchmark JSON (a delayed base's cells get a ``|d<delay>`` suffix)."""
    return f"{label}|{method}|{condition}" + (f"|d{delay}" if delay else "")


def _cell(cells: dict, label: str, method: str, condition: str, delay: int) -> dict | None:
    return cells.get(cell_key(label, method, condition, delay))


def _score_line(ax, pts: list[tuple[float, dict]], method: str, metric: str = "score") -> None:
    """One method's score ± s.e. (``metric="success"``: success rate in % ± s.e.) over (x, cell) points;
    ``method`` ``expert`` draws the ceiling row (black, dashed)."""
    if metric == "success":
        y = [100 * cell["success_rate"] for _, cell in pts]
        err = [100 * success_se(cell) for _, cell in pts]
    else:
        y, err = [cell["score"] for _, cell in pts], [score_se(cell) for _, cell in pts]
    expert = method == EXPERT
    ax.errorbar(
        [x for x, _ in pts],
        y,
        yerr=err,
        marker="s" if expert else "o",
        linestyle="--" if expert else "-",
        capsize=3,
        label=expert_name(pts[0][1]) if expert else METHOD_NAMES[method],
        color=EXPERT_COLOR if expert else COLORS[method],
    )


def table_delay(results: dict, label: str) -> str:
    """Score ± s.e. (success) per method and condition for each inference delay d, and the score each
    method loses from d = 0 to the largest d; a baseline the folder lacks is its base's (``baseline_cell``).
    """
    cells = results["cells"]
    delays = _delays(cells, label)
    if len(delays) < 2:
        return ""
    # a condition with any method of its own at the largest delay (a gated folder has no open-loop row)
    conds = [
        c
        for c in _conditions(cells, label)
        if any(_cell(cells, label, m, c, delays[-1]) for m in METHOD_NAMES)
    ]
    head = ["method", "condition"] + [f"d = {d}" for d in delays] + [f"lost d=0 -> {delays[-1]}"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m, name in METHOD_NAMES.items():
        for c in conds:
            row = [baseline_cell(results, label, m, c, d) for d in delays]
            if all(r is None for r in row[1:]):
                continue
            lost = f"{row[0]['score'] - row[-1]['score']:+.3f}" if row[0] and row[-1] else "-"
            lines.append(f"| {name} | {c} | " + " | ".join(fmt(r) for r in row) + f" | {lost} |")
    return "\n".join(lines)


def plot_delay(results: dict, path: Path) -> bool:
    """Score (± s.e.) vs inference delay per method: one row of panels per model, one column per condition
    (an empty panel where the model has no delayed cell); False when no delayed cell exists."""
    try:
        import matplotlib
    except ImportError as err:  # an optional dependency
        raise ImportError(
            "the benchmark plots need matplotlib: pip install 'lerobot_policy_dcdp[benchmark]'"
        ) from err

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = results["cells"]
    labels = sorted({c["model"] for c in cells.values() if c.get("inference_delay", 0)})
    if not labels:
        return False

    def delayed(label: str, c: str) -> bool:
        return any(_cell(cells, label, m, c, d) for m in METHOD_NAMES for d in _delays(cells, label) if d)

    conds = [c for c in CONDITION_ORDER if any(delayed(label, c) for label in labels)]
    fig, axes = plt.subplots(
        len(labels), len(conds), figsize=(3.3 * len(conds), 3.0 * len(labels)), squeeze=False
    )
    for row, label in zip(axes, labels, strict=True):
        for ax, c in zip(row, conds, strict=True):
            if not delayed(label, c):
                ax.axis("off")
                continue
            for m in METHOD_NAMES:
                pts = [(d, baseline_cell(results, label, m, c, d)) for d in _delays(cells, label)]
                pts = [(d, cell) for d, cell in pts if cell]
                if len(pts) >= 2:
                    _score_line(ax, pts, m)
            ax.set_title(f"{label}: {c}", fontsize=9)
            ax.set_xlabel("inference delay d (control steps)", fontsize=8)
            ax.set_ylim(0, 1.02)
            ax.grid(alpha=0.3)
        first = next(ax for ax in row if ax.axison)
        first.set_ylabel("score (avg max reward)")
        first.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def plot(results: dict, path: Path, metric: str = "score") -> None:
    """Score (± standard error) vs drift magnitude, per method, for constant and random drift; with
    ``metric="success"`` the success rate (%, ± its binomial s.e.). The privileged expert's cells, when
    present, are drawn in every model's panels as the ceiling; a corrector without its own baseline rows is
    drawn with its base's (``baseline_cell``)."""
    if metric not in ("score", "success"):
        raise ValueError(f"metric must be 'score' or 'success', got {metric!r}")
    try:
        import matplotlib
    except ImportError as err:  # an optional dependency
        raise ImportError(
            "the benchmark plots need matplotlib: pip install 'lerobot_policy_dcdp[benchmark]'"
        ) from err

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = results["cells"]
    labels = sorted({c["model"] for c in cells.values()} - {EXPERT}) or [EXPERT]
    top = max([magnitude(c["condition"]) for c in cells.values()] + [MAGNITUDES[0]])
    fig, axes = plt.subplots(len(labels), 2, figsize=(11, 3.8 * len(labels)), squeeze=False)
    for row, label in enumerate(labels):
        for col, kind in enumerate(KINDS):
            ax = axes[row][col]
            conds = [("static", 0.0)] + [(f"{kind}_{m}", m) for m in MAGNITUDES]
            for who, m in [(label, m) for m in METHOD_NAMES] + [(EXPERT, EXPERT)]:
                # a corrector without its own baseline rows shows those of its base (``baseline_cell``)
                pts = [
                    (
                        x,
                        cells.get(cell_key(EXPERT, m, c))
                        if who == EXPERT
                        else baseline_cell(results, who, m, c),
                    )
                    for c, x in conds
                ]
                pts = [(x, cell) for x, cell in pts if cell]
                if pts:
                    _score_line(ax, pts, m, metric)
            ax.set_title(f"{label}, {kind} drift")
            ax.set_xlabel("block drift (px / control step)")
            if metric == "success":
                ax.set_ylabel("success rate (%)")
                ax.set_ylim(0, 102)
            else:
                ax.set_ylabel("score (avg max reward)")
                ax.set_ylim(0, 1.02)
            ax.set_xlim(-0.1, top + 0.1)
            ax.grid(alpha=0.3)
    legend = {}  # every method drawn in any panel, once (a panel may lack some: a gate-only model's)
    for ax in axes.flat:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(name, handle)
    axes[0][0].legend(list(legend.values()), list(legend), fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
    return (
        f"- protocol: PushT (gym-pusht), state + keypoint observations, {'/'.join(map(str, eps))} episodes "
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
        f"\n- ceiling row (`{EXPERT}`): the privileged scripted expert (`lerobot_dcdp.pusht.expert`) "
        "reads the simulator's true state (block pose, agent position and velocity), plans a push "
        f"primitive on an exact copy of the static physics, executes {chunk} steps of it and plans again; "
        "it does not know the drift and has no learned part. "
        f"{'/'.join(map(str, eps))} episodes per cell, same seeds and step limit, run once per condition "
        f"(not per base). A reference for what a chunked controller ({chunk} steps) with perfect state "
        "reaches, not a policy under test."
    )


def success_plot_path(json_path: Path) -> Path:
    """The success-vs-drift plot beside a results file (named like :func:`plot_paths`' plots)."""
    prefix = "" if json_path.stem == "benchmark" else f"{json_path.stem}_"
    return json_path.parent / f"{prefix}success_vs_drift.png"


def plot_paths(json_path: Path) -> tuple[Path, Path]:
    """The score-vs-drift and score-vs-delay plots beside a results file: ``score_vs_*.png`` for
    ``benchmark.json``, ``<stem>_score_vs_*.png`` for any other (an ablation keeps the main plots)."""
    prefix = "" if json_path.stem == "benchmark" else f"{json_path.stem}_"
    return json_path.parent / f"{prefix}score_vs_drift.png", json_path.parent / f"{prefix}score_vs_delay.png"


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
    """The real-time measurements (issue 23) as report lines: every ``*.md`` in ``realtime_dir``, in name
    order, as written by the script that made it (``scripts/client_scores.sh``,
    ``scripts/rollout_deadlines.sh``, ``scripts/tick_times.py``), headings moved three levels down; none when
    the folder is absent or empty."""
    files = sorted(realtime_dir.glob("*.md")) if realtime_dir.is_dir() else []
    if not files:
        return []
    parts = [
        "## Real time (issue 23): asynchronous planning and the base on LeRobot's policy server",
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


def write_report(results: dict, report: Path, json_path: Path, realtime_dir: Path | None = None) -> None:
    plot_path, delay_path = plot_paths(json_path)
    success_path = success_plot_path(json_path)
    plot(results, plot_path)
    plot(results, success_path, metric="success")
    has_delay = plot_delay(results, delay_path)
    m = results.get("machine", {})
    parts = [
        "# Results: DCDP on perturbed PushT",
        "",
        "Generated by `dcdp-benchmark` (`src/lerobot_dcdp/benchmark/`); do not edit by hand.",
        "What the numbers mean, every attempt and what helped or not: `docs/ANALYSIS.md`.",
        "",
        f"- command: `{results.get('command', 'dcdp-benchmark')}`",
        f"- machine: {m.get('cpu', '?')}, {m.get('cores', '?')} cores, torch {m.get('torch', '?')} "
        f"({m.get('torch_threads', '?')} thread), Python {m.get('python', '?')}, no GPU",
        f"- git commit: `{results.get('git_commit', '?')}`",
        protocol(results),
        f"- raw numbers: `{json_path}`; plots: `{plot_path}` (score), `{success_path}` (success)",
        "",
    ]
    ceiling = table_expert(results)
    if ceiling:
        parts += [
            "## Ceiling: the privileged scripted expert",
            "",
            "Not a policy under test: it reads the simulator's true state (see the protocol above). "
            "Its row is repeated, in italics, at the foot of every model's Table 1.",
            "",
            ceiling,
            "",
        ]
    for label, ident in results.get("models", {}).items():
        cells = [c for c in results["cells"].values() if c["model"] == label]
        n = cells[0]["episodes"] if cells else "?"
        parts += [
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
            "### Gaps to the goals",
            "",
            gaps(results, label) or "(not enough cells)",
            "",
        ]
        for method, name in JUDGED_ROWS.items():
            mild = goals_issue22(results, label, method)
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
    parts += [
        "| score vs drift | success vs drift |",
        "|---|---|",
        f"| ![score vs drift]({Path('..') / plot_path}) | ![success vs drift]({Path('..') / success_path}) |",
        "",
    ]
    if has_delay:
        parts += [f"![score vs delay]({Path('..') / delay_path})", ""]
    if realtime_dir is not None:  # last: not this benchmark's rollouts
        parts += realtime_section(realtime_dir)
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text("\n".join(parts))
