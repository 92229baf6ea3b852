"""The benchmark's results file: reading it, which stored cells are reused, the guard against replacing
cells of another episode count, and merging this run's cells into the file under a lock."""

from __future__ import annotations

import copy
import json
from pathlib import Path

from lerobot_dcdp.benchmark.identity import LEAD_IDENTITY


def fresh_cell(cell: dict | None, ident: dict, seeds: list[int], max_steps: int) -> bool:
    """Whether a stored base/corrector cell (or latency entry) can be reused.

    A cell is reused only for the same corrector (DCDP), gate and scene lead (DCDP, gated anchoring), base,
    seeds and step limit; the baselines never call the corrector or the gate, so for them only the base has
    to be the same.

    Args:
        cell: The stored cell, or ``None``.
        ident: The identity of the folder about to run (``load_model``).
        seeds: The seeds this run asks for.
        max_steps: The step limit this run asks for.

    Returns:
        True when the cell matches this run.
    """
    if not cell:
        return False
    i = cell.get("identity", {})
    method = cell.get("method")
    same_corrector = method not in ("dcdp", None) or i.get("corrector_sha256") == ident["corrector_sha256"]
    led = method in ("dcdp", "gated_anchored", None)
    same_gate = not led or i.get("completion_gate_sha256") == ident.get("completion_gate_sha256")
    same_lead = not led or all(i.get(k, d) == ident.get(k, d) for k, d in LEAD_IDENTITY.items())
    return (
        same_corrector
        and same_gate
        and same_lead
        and i.get("base_weights_sha256") == ident["base_weights_sha256"]
        and cell.get("seeds", [None])[0] == seeds[0]
        and cell.get("max_steps") == max_steps
        and cell.get("episodes", len(seeds)) == len(seeds)
    )


def fresh_expert_cell(cell: dict | None, ident: dict, seeds: list[int], max_steps: int) -> bool:
    """A stored expert cell is reused only for the same expert settings, seeds and step limit."""
    return bool(
        cell
        and cell.get("identity") == ident
        and cell.get("seeds", [None])[0] == seeds[0]
        and cell.get("max_steps") == max_steps
        and cell.get("episodes") == len(seeds)
    )


def episode_conflicts(cells: dict, wanted: dict[str, int]) -> list[str]:
    """Stored cells that a run asking ``wanted`` (cell key -> episodes) would replace by a different count."""
    return [
        f"{key} ({cells[key].get('episodes')} episodes stored, {n} asked)"
        for key, n in wanted.items()
        if key in cells and cells[key].get("episodes") != n
    ]


def conflict_message(out: Path, conflicts: list[str]) -> str:
    """The error ``dcdp-benchmark`` exits with when ``out`` holds cells of another episode count."""
    return (
        f"dcdp-benchmark: error: {out} holds cells of another episode count, which this run would "
        "replace: "
        + "; ".join(conflicts[:5])
        + (" ..." if len(conflicts) > 5 else "")
        + ". Write to another file (--out, --report) or pass --force to replace them."
    )


def merge_results(disk: dict, ours: dict, loaded: dict) -> dict:
    """The ``cells``/``latency``/``models`` tables to write: what is on disk now, overridden only by entries
    this run changed since it read the file (``loaded``), so that two benchmarks writing other cells of the
    same file side by side never put back each other's stale copies."""
    merged = {}
    for k in ("cells", "latency", "models"):
        before = loaded.get(k, {})
        changed = {key: v for key, v in ours.get(k, {}).items() if before.get(key) != v}
        merged[k] = {**disk.get(k, {}), **changed}
    return merged


class ResultsFile:
    """One run's view of a results file: ``results`` (what this run writes) and a copy of the tables as
    last read or written (what :func:`merge_results` compares against).

    Attributes:
        path: The JSON file.
        results: The results this run adds to; always has ``cells`` and ``latency``.
    """

    def __init__(self, path: Path):
        """Read ``path`` (an absent file: no cells, no latency)."""
        self.path = path
        self.results: dict = json.loads(path.read_text()) if path.exists() else {"cells": {}, "latency": {}}
        self.results.setdefault("cells", {})
        self.results.setdefault("latency", {})
        self._loaded = copy.deepcopy(self.results)

    def save(self) -> None:
        """Merge this run's cells into the file on disk (other benchmarks may write meanwhile)."""
        import fcntl

        out = self.path
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out.with_suffix(".lock"), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            disk = json.loads(out.read_text()) if out.exists() else {}
            merged = merge_results(disk, self.results, self._loaded)
            self.results.update(merged)
            self._loaded.update(copy.deepcopy(merged))
            tmp = out.with_suffix(".json.tmp")
            tmp.write_text(json.dumps(self.results, indent=1))
            tmp.replace(out)
