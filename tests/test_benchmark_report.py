"""The benchmark's bookkeeping: cell reuse rules and the generated tables, on a hand-made results dict."""

from __future__ import annotations

from lerobot_dcdp.benchmark.report import table1, table2, write_report
from lerobot_dcdp.benchmark.run import _fresh

IDENT = {
    "corrector_sha256": "c1",
    "base_weights_sha256": "b1",
    "base": "models/b",
    "base_type": "diffusion",
    "corrector": "models/c",
    "corrector_params": 10,
}


def cell(method: str, cond: str, sr: float, score: float, rewards: list[float] | None = None) -> dict:
    return {
        "max_rewards": rewards if rewards is not None else [score, score],
        "model": "m",
        "method": method,
        "condition": cond,
        "episodes": 2,
        "seeds": [100000, 100001],
        "max_steps": 300,
        "success_rate": sr,
        "score": score,
        "identity": IDENT,
    }


def results() -> dict:
    return {
        "cells": {
            "m|open_loop|static": cell("open_loop", "static", 0.5, 0.9),
            "m|dcdp|static": cell("dcdp", "static", 1.0, 0.95),
            "m|open_loop|constant_2.0": cell("open_loop", "constant_2.0", 0.0, 0.5, [0.4, 0.6]),
            "m|dcdp|constant_2.0": cell("dcdp", "constant_2.0", 0.5, 0.8),
            "m|object_anchored|constant_2.0": cell("object_anchored", "constant_2.0", 0.0, 0.75),
        },
        "latency": {
            "m|open_loop": {"model": "m", "method": "open_loop", "mean_ms": 4.0, "p95_ms": 5.0},
            "m|dcdp": {"model": "m", "method": "dcdp", "mean_ms": 4.2, "p95_ms": 5.5},
            "m|closed_loop": {"model": "m", "method": "closed_loop", "mean_ms": 33.6, "p95_ms": 40.0},
        },
        "models": {"m": IDENT},
        "command": "dcdp-benchmark --episodes 2",
        "machine": {"cpu": "test", "cores": 2},
    }


def test_tables_and_report(tmp_path) -> None:
    r = results()
    t1 = table1(r, "m")
    # score +- standard error (success +- standard error); s.e. of [0.4, 0.6] = 0.1
    assert "| Open loop (H=8) | 0.900 ± 0.000 (50 ± 35 %) | 0.500 ± 0.100 (0 ± 0 %) |" in t1
    assert "| DCDP (H=8) | 0.950 ± 0.000 (100 ± 0 %) | 0.800 ± 0.000 (50 ± 35 %) |" in t1
    assert "| Object-anchored chunk (H=8, training-free) | - | 0.750" in t1
    t2 = table2(r, "m")
    assert "DCDP / open loop = 1.050" in t2 and "closed loop / DCDP = 8.00" in t2
    write_report(r, tmp_path / "RESULTS.md", tmp_path / "benchmark.json")
    text = (tmp_path / "RESULTS.md").read_text()
    assert "dcdp-benchmark --episodes 2" in text
    assert "constant_2.0: DCDP - open loop = +0.300 score (goal >= +0.20)" in text
    assert "constant_2.0: DCDP - object_anchored = +0.050 score" in text
    assert "static: DCDP - open loop = +50 success points" in text
    # the protocol line is written from the cells, not hard-coded
    assert "2 episodes per cell from seed 100000" in text and "300 steps max" in text
    assert (tmp_path / "score_vs_drift.png").stat().st_size > 0


def test_cells_are_reused_only_for_the_same_models_and_protocol() -> None:
    c = cell("dcdp", "static", 1.0, 1.0)
    seeds = [100000, 100001]
    assert _fresh(c, IDENT, seeds, 300)
    assert not _fresh(c, {**IDENT, "corrector_sha256": "other"}, seeds, 300)
    assert not _fresh(c, {**IDENT, "base_weights_sha256": "other"}, seeds, 300)
    assert not _fresh(c, IDENT, [5, 6], 300) and not _fresh(c, IDENT, seeds, 200)
    # a baseline never calls the corrector: a new corrector on the same base reuses it
    assert _fresh(cell("open_loop", "static", 0.5, 0.9), {**IDENT, "corrector_sha256": "other"}, seeds, 300)
    assert not _fresh(None, IDENT, seeds, 300)


def test_delay_table_and_plot(tmp_path) -> None:
    from lerobot_dcdp.benchmark.report import table_delay
    from lerobot_dcdp.benchmark.run import cell_key

    r = results()
    assert table_delay(r, "m") == ""  # no delayed cell: no table
    for method, d, score in [("open_loop", 4, 0.3), ("dcdp", 4, 0.7), ("open_loop", 2, 0.4)]:
        r["cells"][cell_key("m", method, "constant_2.0", d)] = {
            **cell(method, "constant_2.0", 0.0, score),
            "inference_delay": d,
        }
    assert cell_key("m", "dcdp", "static") == "m|dcdp|static"
    t = table_delay(r, "m")
    assert "| condition | d = 0 | d = 2 | d = 4 | lost d=0 -> 4 |" in t
    # open loop loses 0.5 - 0.3, DCDP 0.8 - 0.7; the d = 0 cells are the main table's
    assert "| Open loop (H=8) | constant_2.0 | 0.500 ± 0.100 (0 ± 0 %) | 0.400" in t and "| +0.200 |" in t
    assert "| DCDP (H=8) | constant_2.0 | 0.800 ± 0.000 (50 ± 35 %) | - | 0.700" in t and "| +0.100 |" in t
    # a folder whose only delayed rows are its own (no open loop of its own, like a gated folder) gets them
    for d, score in [(0, 0.9), (4, 0.6)]:
        r["cells"][cell_key("g", "gated_anchored", "constant_2.0", d)] = {
            **cell("gated_anchored", "constant_2.0", 0.5, score),
            "model": "g",
            "inference_delay": d,
        }
    g = table_delay(r, "g")
    assert "| Object-anchored chunk + completion gate (H=8, no corrector) | constant_2.0 | 0.900" in g
    assert "| +0.300 |" in g and "Open loop" not in g  # no base known: nothing borrowed
    r["models"]["g"] = IDENT  # the same base and seeds as "m": its open-loop rows stand in
    g = table_delay(r, "g")
    assert "| Open loop (H=8) | constant_2.0 | 0.500 ± 0.100 (0 ± 0 %) | 0.300" in g
    write_report(r, tmp_path / "RESULTS.md", tmp_path / "benchmark.json")
    assert "Table 3: a base that answers late" in (tmp_path / "RESULTS.md").read_text()
    assert "## Real time" not in (tmp_path / "RESULTS.md").read_text()
    assert (tmp_path / "score_vs_delay.png").stat().st_size > 0


def test_the_report_shows_the_real_time_summaries_unchanged(tmp_path) -> None:
    """The scripts' summaries in the real-time folder appear in the report as they were written (in name
    order, headings moved down); an empty or absent folder adds nothing."""
    folder = tmp_path / "realtime"
    write_report(results(), tmp_path / "RESULTS.md", tmp_path / "benchmark.json", folder)
    assert "## Real time" not in (tmp_path / "RESULTS.md").read_text()
    folder.mkdir()
    (folder / "b_deadlines.md").write_text(
        "# Deadlines\n\n```\n# a comment in a command\n```\n| mode | ticks |\n|---|---|\n| dcdp | 599 |\n"
    )
    (folder / "a_clients.md").write_text("corrector `x`\n\n| fps | client |\n|---|---|\n| 10 | stock |\n")
    write_report(results(), tmp_path / "RESULTS.md", tmp_path / "benchmark.json", folder)
    text = (tmp_path / "RESULTS.md").read_text()
    assert "## Real time: asynchronous planning" in text and "| 10 | stock |" in text
    assert "| dcdp | 599 |" in text
    assert "\n# a comment in a command\n" in text  # a code block is left as it is
    order = [text.index(h) for h in ("### `a_clients.md`", "### `b_deadlines.md`", "#### Deadlines")]
    assert order == sorted(order)


def test_merge_keeps_cells_another_run_wrote_meanwhile() -> None:
    """Two benchmarks writing other cells of one file: neither restores its stale copy of the other's."""
    from lerobot_dcdp.benchmark.run import merge_results

    start = {"cells": {"a": {"score": 1}, "b": {"score": 2}}, "latency": {}, "models": {"m": {"sha": "old"}}}
    ours = {"cells": {"a": {"score": 10}, "b": {"score": 2}}, "latency": {}, "models": {"m": {"sha": "new"}}}
    disk = {"cells": {"a": {"score": 1}, "b": {"score": 20}, "c": {"score": 3}}, "latency": {"x": 1}}
    merged = merge_results(disk, ours, start)
    # a: ours (changed here); b: the other run's (ours is the stale copy we read); c, x: only on disk
    assert merged["cells"] == {"a": {"score": 10}, "b": {"score": 20}, "c": {"score": 3}}
    assert merged["latency"] == {"x": 1} and merged["models"] == {"m": {"sha": "new"}}
    assert merge_results({}, ours, {}) == {k: ours[k] for k in ("cells", "latency", "models")}


def test_an_ablation_run_never_overwrites_the_main_plots() -> None:
    from pathlib import Path

    from lerobot_dcdp.benchmark.report import plot_paths

    assert [p.name for p in plot_paths(Path("results/benchmark.json"))] == [
        "score_vs_drift.png",
        "score_vs_delay.png",
    ]
    assert [p.name for p in plot_paths(Path("results/ablation.json"))] == [
        "ablation_score_vs_drift.png",
        "ablation_score_vs_delay.png",
    ]


def test_the_image_protocol_reports_its_own_goals(tmp_path) -> None:
    """Cells whose DCDP read pixels only get issue 49's table (the privileged rule found by its base), in
    place of the main protocol's gaps."""
    r = results()
    for c in r["cells"].values():
        c["obs_type"] = "pixels_agent_pos"
        c["successes"] = [c["success_rate"]] * 2
    r["cells"]["m|open_loop|static"]["successes"] = [1.0, 0.0]
    priv = {**cell("gated_anchored", "constant_2.0", 1.0, 0.9), "model": "p"}
    priv["obs_type"] = "pixels_environment_state_agent_pos"
    r["cells"]["p|gated_anchored|constant_2.0"] = priv
    r["models"]["p"] = IDENT
    write_report(r, tmp_path / "RESULTS.md", tmp_path / "benchmark.json")
    text = (tmp_path / "RESULTS.md").read_text()
    assert "## Issue 49 goals" in text and "(goal >= +0.20)" not in text
    assert "| image base at rest: success >= 50% | 50% | met (+0.00) |" in text
    assert "| image base at rest: score >= 0.90 | 0.900 | met (+0.000) |" in text
    # paired over the seeds: [0.8, 0.8] - [0.4, 0.6] = +0.300 ± 0.100
    assert "| constant_2.0: DCDP - open loop >= +0.15 score | +0.300 ± 0.100 | met (+0.150) |" in text
    assert "| random_2.0: DCDP - open loop >= +0.15 score | - | - |" in text
    assert (
        "| moonshot, constant_2.0: DCDP - privileged gated anchoring >= -0.05 score | -0.100 ± 0.000 | "
        "**missed** (-0.050) |" in text
    )
    # state cells (no obs_type) keep the main protocol's gaps
    write_report(results(), tmp_path / "STATE.md", tmp_path / "state.json")
    assert "Issue 49" not in (tmp_path / "STATE.md").read_text()
