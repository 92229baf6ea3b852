"""Tables shaped like the paper's Tables 1-2, the score-vs-drift plot and docs/RESULTS.md, from the
benchmark's JSON."""

from __future__ import annotations

from pathlib import Path

METHOD_NAMES = {
    "open_loop": "Open loop (H=8)",
    "closed_loop": "Closed loop (H=1)",
    "temporal_ensemble": "Temporal ensemble (H=1, 0.5)",
    "object_anchored": "Object-anchored chunk (H=8, training-free)",
    "dcdp": "DCDP (H=8)",
}
COLORS = {
    "open_loop": "C0",
    "closed_loop": "C1",
    "temporal_ensemble": "C2",
    "object_anchored": "C4",
    "dcdp": "C3",
}
KINDS = ("constant", "random")
MAGNITUDES = (0.5, 1.0, 1.5, 2.0, 2.5)
CONDITION_ORDER = ["static"] + [f"{k}_{m}" for m in MAGNITUDES for k in KINDS]


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
    """Score ± standard error (success rate ± standard error) per method and condition."""
    cells = results["cells"]
    conds = _conditions(cells, label)
    lines = ["| method | " + " | ".join(conds) + " |", "|" + "---|" * (len(conds) + 1)]
    for m, name in METHOD_NAMES.items():
        row = [fmt(cells.get(f"{label}|{m}|{c}")) for c in conds]
        if any(r != "-" for r in row):
            lines.append(f"| {name} | " + " | ".join(row) + " |")
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
    """The corrector issue's goals, as measured gaps in score (positive = goal met with margin)."""
    cells = results["cells"]

    def get(m: str, c: str) -> dict | None:
        return cells.get(f"{label}|{m}|{c}")

    out = []
    for c in ("constant_2.0", "random_2.0"):
        d, o = get("dcdp", c), get("open_loop", c)
        if d and o:
            out.append(f"- {c}: DCDP - open loop = {d['score'] - o['score']:+.3f} score (goal >= +0.20)")
        for m in ("closed_loop", "temporal_ensemble"):
            x = get(m, c)
            if d and x:
                out.append(f"- {c}: DCDP - {m} = {d['score'] - x['score']:+.3f} score (goal > 0)")
    for c in _conditions(cells, label):
        if c == "static" or float(c.split("_")[1]) < 1.0:
            continue
        d, x = get("dcdp", c), get("object_anchored", c)
        if d and x:
            out.append(f"- {c}: DCDP - object_anchored = {d['score'] - x['score']:+.3f} score (moonshot > 0)")
    d, o = get("dcdp", "static"), get("open_loop", "static")
    if d and o:
        out.append(f"- static: DCDP - open loop = {d['score'] - o['score']:+.3f} score (goal >= -0.01)")
        out.append(
            f"- static: DCDP - open loop = {100 * (d['success_rate'] - o['success_rate']):+.0f} success "
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


def _score_line(ax, pts: list[tuple[float, dict]], method: str) -> None:
    """One method's score ± s.e. over (x, cell) points."""
    ax.errorbar(
        [x for x, _ in pts],
        [cell["score"] for _, cell in pts],
        yerr=[score_se(cell) for _, cell in pts],
        marker="o",
        capsize=3,
        label=METHOD_NAMES[method],
        color=COLORS[method],
    )


def table_delay(results: dict, label: str) -> str:
    """Score ± s.e. (success) per method and condition for each inference delay d, and the score each
    method loses from d = 0 to the largest d."""
    cells = results["cells"]
    delays = _delays(cells, label)
    if len(delays) < 2:
        return ""
    conds = [c for c in _conditions(cells, label) if _cell(cells, label, "open_loop", c, delays[-1])]
    head = ["method", "condition"] + [f"d = {d}" for d in delays] + [f"lost d=0 -> {delays[-1]}"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m, name in METHOD_NAMES.items():
        for c in conds:
            row = [_cell(cells, label, m, c, d) for d in delays]
            if all(r is None for r in row[1:]):
                continue
            lost = f"{row[0]['score'] - row[-1]['score']:+.3f}" if row[0] and row[-1] else "-"
            lines.append(f"| {name} | {c} | " + " | ".join(fmt(r) for r in row) + f" | {lost} |")
    return "\n".join(lines)


def plot_delay(results: dict, path: Path) -> bool:
    """Score (± s.e.) vs inference delay per method, one panel per condition and model; False when no
    delayed cell exists."""
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
    panels = [
        (label, c)
        for label in labels
        for c in _conditions(cells, label)
        if any(_cell(cells, label, m, c, d) for m in METHOD_NAMES for d in _delays(cells, label) if d)
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.3 * len(panels), 3.4), squeeze=False)
    for ax, (label, c) in zip(axes[0], panels, strict=True):
        for m in METHOD_NAMES:
            pts = [(d, _cell(cells, label, m, c, d)) for d in _delays(cells, label)]
            pts = [(d, cell) for d, cell in pts if cell]
            if len(pts) >= 2:
                _score_line(ax, pts, m)
        ax.set_title(f"{label}: {c}", fontsize=9)
        ax.set_xlabel("inference delay d (control steps)")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("score (avg max reward)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def plot(results: dict, path: Path) -> None:
    """Score (± standard error) vs drift magnitude, per method, for constant and random drift."""
    try:
        import matplotlib
    except ImportError as err:  # an optional dependency
        raise ImportError(
            "the benchmark plots need matplotlib: pip install 'lerobot_policy_dcdp[benchmark]'"
        ) from err

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = sorted({c["model"] for c in results["cells"].values()})
    fig, axes = plt.subplots(len(labels), 2, figsize=(11, 3.8 * len(labels)), squeeze=False)
    for row, label in enumerate(labels):
        for col, kind in enumerate(KINDS):
            ax = axes[row][col]
            conds = [("static", 0.0)] + [(f"{kind}_{m}", m) for m in MAGNITUDES]
            for m in METHOD_NAMES:
                pts = [(x, results["cells"].get(cell_key(label, m, c))) for c, x in conds]
                pts = [(x, cell) for x, cell in pts if cell]
                if pts:
                    _score_line(ax, pts, m)
            ax.set_title(f"{label}, {kind} drift")
            ax.set_xlabel("block drift (px / control step)")
            ax.set_ylabel("score (avg max reward)")
            ax.set_ylim(0, 1.02)
            ax.set_xlim(-0.1, 2.6)
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def protocol(results: dict) -> str:
    """The protocol line, written from what the cells actually ran."""
    cells = list(results["cells"].values())
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
    )


def plot_paths(json_path: Path) -> tuple[Path, Path]:
    """The score-vs-drift and score-vs-delay plots beside a results file: ``score_vs_*.png`` for
    ``benchmark.json``, ``<stem>_score_vs_*.png`` for any other (an ablation keeps the main plots)."""
    prefix = "" if json_path.stem == "benchmark" else f"{json_path.stem}_"
    return json_path.parent / f"{prefix}score_vs_drift.png", json_path.parent / f"{prefix}score_vs_delay.png"


def write_report(results: dict, report: Path, json_path: Path) -> None:
    plot_path, delay_path = plot_paths(json_path)
    plot(results, plot_path)
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
        f"- raw numbers: `{json_path}`; plot: `{plot_path}`",
        "",
    ]
    for label, ident in results.get("models", {}).items():
        cells = [c for c in results["cells"].values() if c["model"] == label]
        n = cells[0]["episodes"] if cells else "?"
        parts += [
            f"## {label}",
            "",
            f"Base `{ident['base']}` ({ident['base_type']}, "
            f"weights sha256 `{ident['base_weights_sha256'][:12]}`), "
            f"corrector `{ident['corrector']}` ({ident['corrector_params']:,} parameters, sha256 "
            f"`{ident['corrector_sha256'][:12]}`), {n} episodes per cell.",
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
        delayed = table_delay(results, label)
        if delayed:
            parts += [
                "### Table 3: a base that answers late (`--policy.inference_delay=d`)",
                "",
                "The chunk used from step t was planned from the observation of step t-d; the entries for "
                "the steps already past are skipped. Score ± s.e. (success rate ± s.e.).",
                "",
                delayed,
                "",
            ]
    parts += [f"![score vs drift]({Path('..') / plot_path})", ""]
    if has_delay:
        parts += [f"![score vs delay]({Path('..') / delay_path})", ""]
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text("\n".join(parts))
