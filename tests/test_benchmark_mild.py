"""Issue 22's mild-drift protocol: the 0.75 px/step conditions, ``--protocol mild``, the privileged expert's
ceiling row, the guard against replacing cells of another episode count, the success-vs-drift plot and the
issue-22 goals table (tiny: one or two episodes of a few steps, or hand-made cells)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lerobot_dcdp.benchmark.report import (
    baseline_cell,
    mild_goals,
    success_plot_path,
    table1,
    write_report,
)
from lerobot_dcdp.benchmark.rollout import CONDITIONS, MAIN_CONDITIONS, MILD_CONDITIONS, expert_rollout
from lerobot_dcdp.benchmark.run import episode_conflicts, main, model_methods, parse_args

REPO = Path(__file__).resolve().parents[1]


def test_mild_conditions_and_their_config_files() -> None:
    conds = {c.name: c for c in CONDITIONS}
    assert MILD_CONDITIONS == [
        "static",
        "constant_0.5",
        "random_0.5",
        "constant_0.75",
        "random_0.75",
        "constant_1.0",
        "random_1.0",
    ]
    for kind in ("constant", "random"):
        name = f"{kind}_0.75"
        assert conds[name].env_kwargs() == {"perturbation": kind, "magnitude": 0.75}
        env = json.loads((REPO / "configs" / "env" / f"pusht_{name}.json").read_text())["env"]
        assert env["perturbation"] == kind and env["magnitude"] == 0.75 and env["episode_length"] == 300
    # the main protocol keeps its eleven conditions: 0.75 is the mild protocol's
    assert "constant_0.75" not in MAIN_CONDITIONS and len(MAIN_CONDITIONS) == 11


def test_protocol_presets_and_explicit_flags() -> None:
    main_args = parse_args([])
    assert main_args.episodes == 50 and main_args.conditions == MAIN_CONDITIONS
    assert main_args.out == "results/benchmark.json" and "expert" not in main_args.methods
    mild = parse_args(["--protocol", "mild"])
    assert mild.episodes == 100 and mild.expert_episodes == 100 and mild.conditions == MILD_CONDITIONS
    assert mild.methods == ["open_loop", "object_anchored", "gated_anchored", "dcdp", "expert"]
    assert "bid" not in main_args.methods  # on request only: 30 sampled chunks per step
    assert (mild.out, mild.report) == ("results/benchmark_mild.json", "docs/RESULTS_MILD.md")
    assert mild.latency_steps == 0 and mild.videos == 0
    # the mild protocol's first correctors carry the base's rows, the gated ones only their DCDP row
    assert model_methods(mild, "diffusion_demos") == [
        "open_loop",
        "object_anchored",
        "gated_anchored",
        "dcdp",
    ]
    assert model_methods(mild, "act_demos_late_gated") == ["dcdp"]
    # the bare bases with a completion gate: their gated anchoring only
    assert model_methods(mild, "act_anchored_gated") == ["gated_anchored"]
    assert model_methods(main_args, "diffusion_anchored_gated") == ["gated_anchored"]
    assert model_methods(main_args, "diffusion") == [m for m in main_args.methods if m != "expert"]
    assert model_methods(main_args, "diffusion_demos_late_gated") == ["dcdp"]
    explicit = parse_args(["--model", "act_demos_late_gated=x", "--methods", "open_loop", "dcdp"])
    assert model_methods(explicit, "act_demos_late_gated") == ["open_loop", "dcdp"]
    # a flag given explicitly wins over the preset
    mine = parse_args(["--protocol", "mild", "--episodes", "2", "--conditions", "random_0.75"])
    assert mine.episodes == 2 and mine.expert_episodes == 2 and mine.conditions == ["random_0.75"]
    assert parse_args(["--protocol", "mild", "--expert-episodes", "40"]).expert_episodes == 40
    # a results file of one's own gets its own report, never the protocol's shipped one
    screen = parse_args(["--protocol", "mild", "--out", "runs/screens/mine.json"])
    assert (screen.out, screen.report) == ("runs/screens/mine.json", "runs/screens/mine.md")
    both = parse_args(["--out", "runs/a.json", "--report", "runs/b.md"])
    assert (both.out, both.report) == ("runs/a.json", "runs/b.md")
    with pytest.raises(SystemExit):
        parse_args(["--conditions", "constant_0.6"])
    with pytest.raises(SystemExit):
        parse_args(["--protocol", "mild", "--expert-chunk", "0"])


def test_expert_replans_every_chunk_from_the_true_state(monkeypatch) -> None:
    from lerobot_dcdp.sim.pusht_expert import ScriptedExpert

    calls = []
    original = ScriptedExpert.next_actions

    def counted(self, env, prev):
        acts = original(self, env, prev)
        calls.append(len(acts))
        return acts

    monkeypatch.setattr(ScriptedExpert, "next_actions", counted)
    static = next(c for c in CONDITIONS if c.name == "static")
    r = expert_rollout(static, [100000], max_steps=20, chunk=8)
    # 20 steps in chunks of at most 8: three plans (8 + 8 + 4), none longer than the chunk
    assert r.steps == [20] and len(calls) == 3 and max(calls) <= 8
    assert 0.0 <= r.max_rewards[0] <= 1.0 and r.successes == [False] and r.step_times_ms[0] > 0


def test_first_success_is_the_exhaustive_search(monkeypatch) -> None:
    """The centroid pre-filter answers as testing every pose in turn (the planner's choices depend on it)."""
    from lerobot_dcdp.sim.pusht_expert import ExactSim, first_success
    from lerobot_dcdp.sim.pusht_geometry import GOAL_POSE, keypoint_error

    sim = ExactSim()

    def naive(poses):
        return next(
            (t for t, p in enumerate(poses) if keypoint_error(p) < 2.8 and sim.coverage(p) > 0.95), None
        )

    rng = np.random.default_rng(0)
    for _ in range(20):
        poses = [GOAL_POSE + rng.normal(0, [3.0, 3.0, 0.03]) for _ in range(12)]
        assert first_success(poses, sim) == naive(poses)
    assert first_success([GOAL_POSE + [40.0, 0, 0], GOAL_POSE.copy()], sim) == 1
    assert first_success([GOAL_POSE + [40.0, 0, 0]], sim) is None and first_success([], sim) is None


def _cell(model: str, method: str, cond: str, successes: list[bool], rewards: list[float]) -> dict:
    return {
        "model": model,
        "method": method,
        "condition": cond,
        "episodes": len(successes),
        "seeds": [100000, 100000 + len(successes) - 1],
        "max_steps": 300,
        "success_rate": float(np.mean(successes)),
        "score": float(np.mean(rewards)),
        "successes": successes,
        "max_rewards": rewards,
        "identity": {"chunk": 8} if model == "expert" else {},
    }


def _results() -> dict:
    ident = {
        "base": "models/b",
        "base_type": "diffusion",
        "base_weights_sha256": "b" * 12,
        "corrector": "models/c",
        "corrector_params": 10,
        "corrector_sha256": "c" * 12,
    }
    t, f = True, False
    cells = {
        "m|open_loop|static": _cell("m", "open_loop", "static", [t, t, f, f], [1.0, 1.0, 0.9, 0.9]),
        "m|dcdp|static": _cell("m", "dcdp", "static", [t, t, t, f], [1.0, 1.0, 1.0, 0.9]),
        "m|open_loop|constant_0.75": _cell(
            "m", "open_loop", "constant_0.75", [t, f, f, f], [1, 0.9, 0.9, 0.8]
        ),
        "m|dcdp|constant_0.75": _cell("m", "dcdp", "constant_0.75", [f, f, f, f], [0.98, 0.9, 0.9, 0.8]),
        "expert|expert|static": _cell("expert", "expert", "static", [t, t], [1.0, 1.0]),
        "expert|expert|constant_0.75": _cell("expert", "expert", "constant_0.75", [t, f], [1.0, 0.5]),
    }
    return {
        "cells": cells,
        "latency": {},
        "models": {"m": ident},
        "command": "dcdp-benchmark --protocol mild",
    }


def test_expert_row_goals_table_and_success_plot(tmp_path) -> None:
    r = _results()
    t1 = table1(r, "m")
    assert t1.splitlines()[0] == "| method | static | constant_0.75 |"
    # the ceiling row comes last, labelled, with the expert's own episode count
    assert t1.splitlines()[-1].startswith("| *Privileged expert (true state, 8-step chunks): ceiling")
    assert "| 1.000 ± 0.000 (100 ± 0 %) | 0.750 ± 0.250 (50 ± 35 %) |" in t1.splitlines()[-1]
    goals = mild_goals(r, "m")
    # constant_0.75: success 0 % vs 25 % -> -25 points (paired s.e. of [-1, 0, 0, 0] = 25), missed by 21
    # (no harm) and by 40 (attainable +15); score -0.005 ± 0.005 (no harm: met by +0.005)
    assert (
        "| constant_0.75 | 25 % | 0 % | -25 ± 25 | -0.005 ± 0.005 | **missed** (-21) | met (+0.005) |"
        in goals
    )
    assert "**missed** (-40) |" in goals
    # static: +25 points, no "attainable" goal at rest
    assert "| static | 50 % | 75 % | +25 ± 25 | +0.025 ± 0.025 | met (+29) | met (+0.035) | - |" in goals
    write_report(r, tmp_path / "RESULTS_MILD.md", tmp_path / "benchmark_mild.json")
    text = (tmp_path / "RESULTS_MILD.md").read_text()
    success_png = success_plot_path(tmp_path / "benchmark_mild.json")
    assert success_png.name == "benchmark_mild_success_vs_drift.png" and success_png.stat().st_size > 0
    assert (tmp_path / "benchmark_mild_score_vs_drift.png").stat().st_size > 0
    assert "success vs drift](" in text and "benchmark_mild_success_vs_drift.png" in text
    assert "## Ceiling: the privileged scripted expert" in text and "ceiling row (`expert`)" in text
    assert "### Issue 22 goals" in text
    assert success_plot_path(Path("results/benchmark.json")).name == "success_vs_drift.png"


def test_a_corrector_without_open_loop_rows_is_judged_against_its_bases_rows() -> None:
    r = _results()
    t, f = True, False
    gated = dict(r["models"]["m"], corrector_sha256="d" * 12)
    r["models"]["g"] = gated  # another corrector on the same base, its DCDP row only
    r["cells"]["g|dcdp|constant_0.75"] = _cell("g", "dcdp", "constant_0.75", [t, t, f, f], [1, 1, 0.9, 0.8])
    assert baseline_cell(r, "g", "open_loop", "constant_0.75") is r["cells"]["m|open_loop|constant_0.75"]
    assert baseline_cell(r, "g", "dcdp", "static") is None  # a DCDP row is never borrowed
    # g - m's open loop: success [0, 1, 0, 0] -> +25 points
    assert "| constant_0.75 | 25 % | 50 % | +25 ± 25 |" in mild_goals(r, "g")
    r["models"]["g"] = dict(gated, base_weights_sha256="e" * 12)  # another base: nothing to borrow
    assert baseline_cell(r, "g", "open_loop", "constant_0.75") is None and mild_goals(r, "g") == ""
    r["models"]["g"] = gated
    r["cells"]["g|dcdp|constant_0.75"]["seeds"] = [5, 8]  # other seeds: not paired
    assert baseline_cell(r, "g", "open_loop", "constant_0.75") is None


def test_cells_of_another_episode_count_are_not_replaced_silently(tmp_path, capsys) -> None:
    out = tmp_path / "b.json"
    out.write_text(json.dumps(_results()))
    assert episode_conflicts(_results()["cells"], {"m|dcdp|static": 4, "m|dcdp|random_1.0": 100}) == []
    assert episode_conflicts(_results()["cells"], {"m|dcdp|static": 100}) == [
        "m|dcdp|static (4 episodes stored, 100 asked)"
    ]
    argv = ["--model", "m=/nonexistent", "--methods", "dcdp", "--conditions", "static", "--episodes", "100"]
    with pytest.raises(SystemExit, match="another episode count.*m\\|dcdp\\|static"):
        main(argv + ["--out", str(out), "--report", str(tmp_path / "R.md")])
    with pytest.raises(SystemExit, match="expert\\|expert\\|static"):
        main(["--methods", "expert", "--conditions", "static", "--expert-episodes", "3", "--out", str(out)])
    assert json.loads(out.read_text()) == _results()  # untouched


def test_expert_only_run_writes_its_row(tmp_path) -> None:
    out, report = tmp_path / "mild.json", tmp_path / "MILD.md"
    argv = ["--protocol", "mild", "--methods", "expert", "--conditions", "constant_0.75", "--episodes", "1"]
    main(argv + ["--max-steps", "9", "--out", str(out), "--report", str(report)])
    cells = json.loads(out.read_text())["cells"]
    assert list(cells) == ["expert|expert|constant_0.75"]
    c = cells["expert|expert|constant_0.75"]
    assert (
        c["episodes"] == 1 and c["max_steps"] == 9 and c["magnitude"] == 0.75 and c["identity"]["chunk"] == 8
    )
    assert "Privileged expert (true state, 8-step chunks)" in report.read_text()
    assert (tmp_path / "mild_success_vs_drift.png").stat().st_size > 0


def test_report_shows_shipped_model_paths_relative_to_the_checkout() -> None:
    from lerobot_dcdp.benchmark.report import shown_path

    assert shown_path(str(REPO / "models" / "pusht-dcdp-state-demos")) == "models/pusht-dcdp-state-demos"
    assert shown_path("/elsewhere/model") == "/elsewhere/model"
    assert shown_path("runs/x/pretrained_model") == "runs/x/pretrained_model"


def test_the_gated_anchoring_row_is_its_folders_own_and_judged_like_dcdp(tmp_path) -> None:
    r = _results()
    t, f = True, False
    gate = dict(r["models"]["m"], corrector_sha256="a" * 12, completion_gate_sha256="9" * 12)
    r["models"]["a"] = gate  # a bare base's gate on the same base: its gated-anchoring row only
    r["cells"]["a|gated_anchored|constant_0.75"] = _cell(
        "a", "gated_anchored", "constant_0.75", [t, t, t, f], [1, 1, 1, 0.8]
    )
    # open loop comes from the other folder on the same base and seeds; a gated row is never borrowed
    assert baseline_cell(r, "a", "open_loop", "constant_0.75") is r["cells"]["m|open_loop|constant_0.75"]
    assert baseline_cell(r, "m", "gated_anchored", "constant_0.75") is None
    assert mild_goals(r, "a") == ""  # no DCDP row of its own
    goals = mild_goals(r, "a", "gated_anchored")
    # success [1, 1, 1, 0] - [1, 0, 0, 0] -> +50 points, paired s.e. 29; attainable goal met by +35
    assert "| condition | open loop success | gated anchoring success |" in goals
    assert "| constant_0.75 | 25 % | 75 % | +50 ± 29 |" in goals and "met (+35) |" in goals
    assert "Object-anchored chunk + completion gate" in table1(r, "a")
    r["cells"]["a|gated_anchored|static"] = _cell("a", "gated_anchored", "static", [t, t, t, t], [1, 1, 1, 1])
    write_report(r, tmp_path / "R.md", tmp_path / "b.json")
    text = (tmp_path / "R.md").read_text()
    # its goal gaps judge the gated anchoring: static 4/4 and 1.0 against open loop's 2/4 and 0.95
    assert "- static: gated anchoring - open loop = +0.050 score (goal >= -0.01)" in text
    assert "- static: gated anchoring - open loop = +50 success points (goal >= -4)" in text
    assert "### Issue 22 goals (gated anchoring)" in text
    assert "completion gate `models/c` (sha256 `999999999999`; no corrector runs)" in text


def test_gated_anchoring_cells_need_a_gate_and_are_reused_only_for_the_same_gate() -> None:
    from types import SimpleNamespace

    from lerobot_dcdp.benchmark.run import _fresh, runs, set_mode

    ident = {"corrector_sha256": "c", "completion_gate_sha256": "g", "base_weights_sha256": "b"}
    cell = {
        "method": "gated_anchored",
        "identity": dict(ident, corrector_sha256="other"),  # the unused corrector does not matter
        "seeds": [7],
        "max_steps": 300,
        "episodes": 1,
    }
    assert _fresh(cell, ident, [7], 300)
    assert not _fresh(cell, dict(ident, completion_gate_sha256="h"), [7], 300)
    assert _fresh(dict(cell, method="object_anchored"), dict(ident, completion_gate_sha256="h"), [7], 300)
    config = SimpleNamespace(anchor_feature="observation.environment_state", n_action_steps=8, lead_steps=0)
    bare = SimpleNamespace(config=config, completion_gate=None, source=SimpleNamespace(max_length=16))
    assert runs("object_anchored", bare) and not runs("gated_anchored", bare)
    with pytest.raises(ValueError, match="completion gate"):
        set_mode(bare, "gated_anchored")
    gated = SimpleNamespace(config=config, completion_gate=object(), source=bare.source, reset=lambda: None)
    assert runs("gated_anchored", gated)
    set_mode(gated, "gated_anchored")
    assert (config.execution, config.completion_gate) == ("object_anchored", True)
    set_mode(gated, "object_anchored")  # the benchmark's anchoring row is the plain rule
    assert (config.execution, config.completion_gate) == ("object_anchored", False)
    set_mode(gated, "dcdp")
    assert (config.execution, config.completion_gate) == ("dcdp", True)


def test_a_folders_scene_lead_runs_in_its_own_rows_only_and_keys_their_cells() -> None:
    from types import SimpleNamespace

    from lerobot_dcdp.benchmark.run import _fresh, lead_identity, set_mode
    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig

    config = SimpleNamespace(anchor_feature="observation.environment_state", n_action_steps=8, lead_steps=8)
    policy = SimpleNamespace(
        config=config,
        completion_gate=object(),
        source=SimpleNamespace(max_length=16),
        reset=lambda: None,
        folder_lead_steps=8,  # as load_model records it
    )
    for method, lead in (("gated_anchored", 8), ("object_anchored", 0), ("open_loop", 0), ("dcdp", 8)):
        set_mode(policy, method)
        assert config.lead_steps == lead, method  # the plain rule and the baselines never lead
    ident = {"corrector_sha256": "c", "completion_gate_sha256": "g", "base_weights_sha256": "b"}
    led = dict(ident, lead_steps=8, lead_window=16)
    for method in ("gated_anchored", "dcdp"):
        cell = {"method": method, "identity": ident, "seeds": [7], "max_steps": 300, "episodes": 1}
        assert _fresh(cell, ident, [7], 300)
        assert not _fresh(cell, led, [7], 300)  # a cell run without the lead is not the led folder's
        assert not _fresh(dict(cell, identity=led), dict(led, lead_window=8), [7], 300)
        assert not _fresh(
            dict(cell, identity=led), dict(led, lead_state_feature="observation.pose"), [7], 300
        )
        # a cell stored before the feature was recorded ran with the default one
        assert _fresh(dict(cell, identity=led), dict(led, lead_state_feature="observation.state"), [7], 300)
        assert _fresh(dict(cell, identity=led), led, [7], 300)
        # a cell stored by the first lead (a median, no tolerance recorded) is not the repeated motion's
        repeated = dict(led, lead_tolerance=0.05, lead_repeats=3)
        assert not _fresh(dict(cell, identity=led), repeated, [7], 300)
        assert not _fresh(dict(cell, identity=repeated), dict(repeated, lead_repeats=4), [7], 300)
        assert _fresh(dict(cell, identity=repeated), repeated, [7], 300)
        assert not _fresh(dict(cell, identity=repeated), dict(repeated, lead_tolerance=0.1), [7], 300)
        assert not _fresh(dict(cell, identity=repeated), dict(repeated, lead_noise=0.5), [7], 300)
        # a cell stored before the noise was recorded ran with none
        assert _fresh(dict(cell, identity=repeated), dict(repeated, lead_noise=0.0), [7], 300)
    baseline = {"method": "open_loop", "identity": ident, "seeds": [7], "max_steps": 300, "episodes": 1}
    assert _fresh(baseline, led, [7], 300)  # a baseline never leads: reused whatever the folder's lead
    # what load_model records: every key of the lead from the folder's config, nothing where it does not lead
    folder = DCDPConfig(
        base_policy_path="b", device="cpu", push_to_hub=False, anchor_feature="observation.environment_state"
    )
    assert lead_identity(folder) == {}
    folder.lead_steps, folder.lead_tolerance = 8, 0.1
    assert lead_identity(folder) == {
        "lead_steps": 8,
        "lead_window": 16,
        "lead_state_feature": "observation.state",
        "lead_tolerance": 0.1,
        "lead_repeats": 3,
        "lead_noise": 0.0,
    }
