"""The benchmark's cells: the rows and conditions its tables show, each cell's key in the results JSON, and
finding a model's cell (a baseline row borrowed from another model on the same base and seeds)."""

from __future__ import annotations

METHOD_NAMES = {
    "open_loop": "Open loop (H=8)",
    "closed_loop": "Closed loop (H=1)",
    "temporal_ensemble": "Temporal ensemble (H=1, 0.5)",
    "object_anchored": "Object-anchored chunk (H=8, training-free)",
    "gated_anchored": "Object-anchored chunk + completion gate (H=8, no corrector)",
    "dcdp": "DCDP (H=8)",
    "bid": "BID (15 samples + weak policy, every step, training-free)",
}
#: rows that depend on what the model folder learned (corrector, gate): never borrowed from another model
OWN_ROWS = ("dcdp", "gated_anchored")
#: the rows judged against open loop by the mild protocol's goals, with their names in that table
JUDGED_ROWS = {"dcdp": "DCDP", "gated_anchored": "gated anchoring"}
#: The ceiling row (the privileged scripted expert, ``--methods expert``): cells ``expert|expert|<cond>``,
#: run once per condition (no corrector, no base) and shown in every model's table.
EXPERT = "expert"
KINDS = ("constant", "random")
MAGNITUDES = (0.5, 0.75, 1.0, 1.5, 2.0, 2.5)
CONDITION_ORDER = ["static"] + [f"{k}_{m}" for m in MAGNITUDES for k in KINDS]


def expert_name(cell: dict | None = None) -> str:
    """The ceiling row's label (its chunk length read from the cell when given).

    Args:
        cell: An expert cell, or ``None`` for the default chunk of 8 steps.

    Returns:
        The label the tables and plots show for the expert row.
    """
    chunk = (cell or {}).get("identity", {}).get("chunk", 8)
    return f"Privileged expert (true state, {chunk}-step chunks): ceiling, not a policy"


def magnitude(condition: str) -> float:
    """Drift in px per control step of a condition name (``static``: 0)."""
    return 0.0 if condition == "static" else float(condition.split("_")[1])


def cell_key(label: str, method: str, condition: str, delay: int = 0) -> str:
    """A cell's key in the benchmark JSON (a delayed base's cells get a ``|d<delay>`` suffix)."""
    return f"{label}|{method}|{condition}" + (f"|d{delay}" if delay else "")


def find_cell(cells: dict, label: str, method: str, condition: str, delay: int) -> dict | None:
    """``label``'s own cell of ``method`` on ``condition`` at inference delay ``delay``, or ``None``."""
    return cells.get(cell_key(label, method, condition, delay))


def model_conditions(cells: dict, label: str) -> list[str]:
    """The conditions ``label`` has any cell of, in ``CONDITION_ORDER``."""
    present = {c["condition"] for c in cells.values() if c["model"] == label}
    return [c for c in CONDITION_ORDER if c in present]


def model_delays(cells: dict, label: str) -> list[int]:
    """The inference delays ``label`` has any cell at, ascending (a cell without one counts as 0)."""
    return sorted({c.get("inference_delay", 0) for c in cells.values() if c["model"] == label})


def baseline_cell(results: dict, label: str, method: str, condition: str, delay: int = 0) -> dict | None:
    """``label``'s own cell of ``method``, else -- for a baseline, which uses nothing the folder learned --
    the cell of another model on the same base (weights hash) and the same seeds as ``label``'s own judged
    cell (``JUDGED_ROWS``).

    Args:
        results: The benchmark JSON (``cells`` and ``models``).
        label: The model whose row is wanted.
        method: The row.
        condition: The condition's name.
        delay: The inference delay.

    Returns:
        The cell, or ``None`` when neither ``label`` nor a model on its base has it.
    """
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
