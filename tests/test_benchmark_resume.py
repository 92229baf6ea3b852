"""A benchmark cut off inside a cell resumes at the cell's next batch and stores what one uninterrupted run
stores (the shipped diffusion corrector, 3 episodes of a few steps, one episode per batch)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import lerobot_dcdp.benchmark.rollout as rollout_module
from lerobot_dcdp.benchmark.cell_checkpoint import CellCheckpoint
from lerobot_dcdp.benchmark.run import main

SHIPPED = Path(__file__).resolve().parents[1] / "models" / "pusht-dcdp-state"
KEY = "m|open_loop|constant_2.0"
ARGV = [
    *("--model", f"m={SHIPPED}", "--methods", "open_loop", "--conditions", "constant_2.0"),
    *("--episodes", "3", "--batch-size", "1", "--max-steps", "12", "--latency-steps", "0", "--videos", "0"),
]


class CutOff(RuntimeError):
    """Stands for the session ending part-way through a cell."""


def _spy(monkeypatch, cut_at: int | None = None) -> list[list[int]]:
    """Record the seeds of every batch rolled out; raise at batch ``cut_at`` (1-based)."""
    real, calls = rollout_module.rollout, []

    def rollout(policy, pre, post, cond, seeds, *args, **kwargs):
        calls.append(list(seeds))
        if len(calls) == cut_at:
            raise CutOff
        return real(policy, pre, post, cond, seeds, *args, **kwargs)

    monkeypatch.setattr(rollout_module, "rollout", rollout)
    return calls


def _run(out: Path) -> dict:
    main(ARGV + ["--out", str(out), "--report", str(out.with_suffix(".md"))])
    return json.loads(out.read_text())["cells"][KEY]


def test_a_cut_off_cell_resumes_at_its_next_batch_and_stores_the_whole_runs_cell(
    tmp_path, monkeypatch
) -> None:
    whole = _run(tmp_path / "whole.json")

    out = tmp_path / "cut.json"
    calls = _spy(monkeypatch, cut_at=3)
    with pytest.raises(CutOff):
        _run(out)
    assert calls == [[100000], [100001], [100002]]
    partial = out.with_suffix(".partial") / "m__open_loop__constant_2.0.json"
    assert [b["seeds"] for b in json.loads(partial.read_text())["batches"]] == [[100000], [100001]]
    assert not out.exists() or KEY not in json.loads(out.read_text())["cells"]

    calls = _spy(monkeypatch)
    resumed = _run(out)
    assert calls == [[100002]]  # the two finished batches are not rolled out again
    for field in ("successes", "max_rewards", "score", "success_rate", "mean_steps", "episodes", "seeds"):
        assert resumed[field] == whole[field], field
    assert resumed["batch_size"] == 1 and not out.with_suffix(".partial").exists()


def test_batches_of_other_settings_are_not_reused(tmp_path) -> None:
    from lerobot_dcdp.benchmark.rollout import RolloutResult

    settings = {"identity": {"base_weights_sha256": "a"}, "seeds": [1, 2], "batch_size": 1, "max_steps": 5}
    done = [RolloutResult(seeds=[1], successes=[True], max_rewards=[1.0], steps=[3], step_times_ms=[2.0])]
    CellCheckpoint(tmp_path / "r.json", KEY, settings).save(done, 4.0)
    batches, wall = CellCheckpoint(tmp_path / "r.json", KEY, settings).load()
    assert [b.seeds for b in batches] == [[1]] and batches[0].successes == [True] and wall == 4.0
    for change in ({"batch_size": 2}, {"max_steps": 6}, {"identity": {"base_weights_sha256": "b"}}):
        assert CellCheckpoint(tmp_path / "r.json", KEY, {**settings, **change}).load() == ([], 0.0), change
