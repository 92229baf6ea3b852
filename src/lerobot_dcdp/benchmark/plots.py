"""The report's figures: score and success vs drift magnitude, score vs inference delay, and where they are
written beside a results file (matplotlib, an optional dependency, is imported only to draw)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lerobot_dcdp.benchmark.cells import (
    CONDITION_ORDER,
    EXPERT,
    KINDS,
    MAGNITUDES,
    METHOD_NAMES,
    baseline_cell,
    cell_key,
    expert_name,
    find_cell,
    magnitude,
    model_delays,
)
from lerobot_dcdp.benchmark.stats import score_se, success_se

COLORS = {
    "open_loop": "C0",
    "closed_loop": "C1",
    "temporal_ensemble": "C2",
    "object_anchored": "C4",
    "gated_anchored": "C5",
    "dcdp": "C3",
    "bid": "C6",
}
EXPERT_COLOR = "k"


def _pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend.

    Raises:
        ImportError: matplotlib is not installed (the ``benchmark`` extra).
    """
    try:
        import matplotlib
    except ImportError as err:  # an optional dependency
        raise ImportError(
            "the benchmark plots need matplotlib: pip install 'lerobot_policy_dcdp[benchmark]'"
        ) from err

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _score_line(ax: Any, pts: list[tuple[float, dict]], method: str, metric: str = "score") -> None:
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


def plot_delay(results: dict, path: Path) -> bool:
    """Score (± s.e.) vs inference delay per method: one row of panels per model, one column per condition
    (an empty panel where the model has no delayed cell).

    Args:
        results: The benchmark JSON.
        path: The PNG to write.

    Returns:
        False (and nothing written) when no delayed cell exists, else True.
    """
    plt = _pyplot()
    cells = results["cells"]
    labels = sorted({c["model"] for c in cells.values() if c.get("inference_delay", 0)})
    if not labels:
        return False

    def delayed(label: str, c: str) -> bool:
        return any(
            find_cell(cells, label, m, c, d) for m in METHOD_NAMES for d in model_delays(cells, label) if d
        )

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
                pts = [(d, baseline_cell(results, label, m, c, d)) for d in model_delays(cells, label)]
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


def _drift_panel(ax: Any, results: dict, label: str, kind: str, metric: str, top: float) -> None:
    """One panel of :func:`plot`: ``label``'s methods and the expert's ceiling over ``kind`` drift."""
    cells = results["cells"]
    conds = [("static", 0.0)] + [(f"{kind}_{m}", m) for m in MAGNITUDES]
    for who, m in [(label, m) for m in METHOD_NAMES] + [(EXPERT, EXPERT)]:
        # a corrector without its own baseline rows shows those of its base (``baseline_cell``)
        pts = [
            (
                x,
                cells.get(cell_key(EXPERT, m, c)) if who == EXPERT else baseline_cell(results, who, m, c),
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


def plot(results: dict, path: Path, metric: str = "score") -> None:
    """Score (± standard error) vs drift magnitude, per method, for constant and random drift; with
    ``metric="success"`` the success rate (%, ± its binomial s.e.). The privileged expert's cells, when
    present, are drawn in every model's panels as the ceiling; a corrector without its own baseline rows is
    drawn with its base's (``baseline_cell``).

    Args:
        results: The benchmark JSON.
        path: The PNG to write.
        metric: ``"score"`` or ``"success"``.

    Raises:
        ValueError: ``metric`` is neither.
    """
    if metric not in ("score", "success"):
        raise ValueError(f"metric must be 'score' or 'success', got {metric!r}")
    plt = _pyplot()
    cells = results["cells"]
    labels = sorted({c["model"] for c in cells.values()} - {EXPERT}) or [EXPERT]
    top = max([magnitude(c["condition"]) for c in cells.values()] + [MAGNITUDES[0]])
    fig, axes = plt.subplots(len(labels), 2, figsize=(11, 3.8 * len(labels)), squeeze=False)
    for row, label in enumerate(labels):
        for col, kind in enumerate(KINDS):
            _drift_panel(axes[row][col], results, label, kind, metric, top)
    legend = {}  # every method drawn in any panel, once (a panel may lack some: a gate-only model's)
    for ax in axes.flat:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(name, handle)
    axes[0][0].legend(list(legend.values()), list(legend), fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def success_plot_path(json_path: Path) -> Path:
    """The success-vs-drift plot beside a results file (named like :func:`plot_paths`' plots)."""
    prefix = "" if json_path.stem == "benchmark" else f"{json_path.stem}_"
    return json_path.parent / f"{prefix}success_vs_drift.png"


def plot_paths(json_path: Path) -> tuple[Path, Path]:
    """The score-vs-drift and score-vs-delay plots beside a results file: ``score_vs_*.png`` for
    ``benchmark.json``, ``<stem>_score_vs_*.png`` for any other (an ablation keeps the main plots)."""
    prefix = "" if json_path.stem == "benchmark" else f"{json_path.stem}_"
    return json_path.parent / f"{prefix}score_vs_drift.png", json_path.parent / f"{prefix}score_vs_delay.png"
