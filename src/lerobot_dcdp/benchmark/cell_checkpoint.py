"""A cell's finished batches on disk, so that a long cell cut off part-way (a BID cell on a CPU runs for
hours) resumes at its next batch instead of starting over.

Each batch seeds the policy's noise from its own first seed (``rollout``), so a batch rolled out after a
resume gives what it would have given in one go: the resumed cell equals the uninterrupted one. The batches
are kept in ``<results file>.partial/<cell>.json`` (written atomically after each batch, removed when the
cell is stored) with everything they depend on; a file written under other settings is ignored.
"""

from __future__ import annotations

import json
from pathlib import Path

from lerobot_dcdp.benchmark.rollout import RolloutResult

#: the fields of a batch that are kept, with their element types (its rendered frames are not kept)
BATCH_FIELDS = {"seeds": int, "successes": bool, "max_rewards": float, "steps": int, "step_times_ms": float}


class CellCheckpoint:
    """The finished batches of one cell, tied to the settings they were rolled out with.

    Attributes:
        path: The JSON file.
        settings: What the batches depend on (identity, seeds, batch size, step limit, mode, condition, ...).
    """

    def __init__(self, results_path: Path, key: str, settings: dict):
        """Args:
        results_path: The results file the cell goes to.
        key: The cell's key in it.
        settings: What a stored batch must have been rolled out with to be reused (JSON-serialisable).
        """
        self.path = results_path.with_suffix(".partial") / (key.replace("|", "__") + ".json")
        self.settings = json.loads(json.dumps(settings))

    def load(self) -> tuple[list[RolloutResult], float]:
        """The batches finished under the same settings and the seconds they took (none: ``[]``, 0)."""
        if not self.path.exists():
            return [], 0.0
        stored = json.loads(self.path.read_text())
        if stored.get("settings") != self.settings:
            return [], 0.0
        return [RolloutResult(**b) for b in stored["batches"]], float(stored["wall_s"])

    def save(self, batches: list[RolloutResult], wall_s: float) -> None:
        """Write the finished batches (atomically: a cut-off write leaves the previous file)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = {
            "settings": self.settings,
            "wall_s": wall_s,
            "batches": [
                {f: [kind(v) for v in getattr(b, f)] for f, kind in BATCH_FIELDS.items()} for b in batches
            ],
        }
        tmp = self.path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(self.path)

    def clear(self) -> None:
        """Remove the file (and the folder once empty): the cell is stored."""
        self.path.unlink(missing_ok=True)
        if self.path.parent.exists() and not any(self.path.parent.iterdir()):
            self.path.parent.rmdir()
