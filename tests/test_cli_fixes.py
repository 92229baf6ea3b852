"""Regression tests of CLI bugs: ``dcdp-finetune-rl --env.type=pusht_perturbed`` and the held-out report of
``dcdp-fit-completion-gate`` on a small dataset."""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch
from helpers import make_dcdp_policy

OBS = "environment_state_agent_pos"


def _residual_corrector(diffusion_base: Path, demo_root: Path, out: Path) -> Path:
    """A tiny residual corrector saved with its processors (a ``--policy`` folder for dcdp-finetune-rl)."""
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual", n_action_steps=4)
    policy.save_pretrained(out)
    for processor in make_dcdp_pre_post_processors(policy.config):
        processor.save_pretrained(out)
    return out


def test_finetune_rl_runs_on_the_pusht_perturbed_env_flag(
    diffusion_base, demo_root, tmp_path, capsys
) -> None:
    """``--env.type=pusht_perturbed`` is registered for the command, and its config's own step limit
    (``--env.episode_length``) gives way to ``--max-steps`` instead of reaching make_perturbed_env twice."""
    from lerobot_dcdp.train.finetune_rl import main

    start = _residual_corrector(diffusion_base, demo_root, tmp_path / "start")
    out = tmp_path / "rl"
    main(
        [
            f"--policy={start}",
            f"--output-dir={out}",
            "--iterations=1",
            "--envs=1",
            "--max-steps=6",
            "--minibatch=8",
            "--critic-warmup=0",
            "--env.type=pusht_perturbed",
            f"--env.obs_type={OBS}",
            "--env.episode_length=50",
        ]
    )
    assert "load it with --policy.path" in capsys.readouterr().out
    (line,) = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert line["iteration"] == 0 and 0 < line["env_steps"] <= 6  # the episode ends at --max-steps
    assert (out / "checkpoints" / "last" / "pretrained_model" / "config.json").is_file()


def test_rollout_env_keeps_the_config_and_takes_the_drift_and_step_limit() -> None:
    from lerobot_dcdp.data.corrections import DriftSpec
    from lerobot_dcdp.sim.envs.pusht_perturbed import PushTPerturbedEnvConfig
    from lerobot_dcdp.train.finetune_rl import rollout_env

    config = PushTPerturbedEnvConfig(obs_type=OBS, episode_length=50, perturbation="none")
    spec = DriftSpec("constant", magnitude=1.5, direction_deg=90.0, directions_deg=(0.0,), resample_every=50)
    env = rollout_env(config, spec, 7)
    try:
        assert env.spec.max_episode_steps == 7
        assert env.get_wrapper_attr("perturbation") == "constant"
        assert env.get_wrapper_attr("magnitude") == 1.5
        assert env.unwrapped.obs_type == OBS
    finally:
        env.close()


def test_fit_gate_counts_its_held_out_episodes_and_the_report_says_when_there_are_none() -> None:
    from lerobot_dcdp.model.completion_gate import CompletionGate
    from lerobot_dcdp.train.fit_completion_gate import fit_gate, held_out_report

    torch.manual_seed(0)
    x = torch.randn(30, 3)
    near = x[:, 0] > 0
    episodes = torch.arange(3).repeat_interleave(10)
    stats = fit_gate(CompletionGate({"s": 3}), x, near, episodes, steps=5, val_fraction=0.1)
    assert stats["val_episodes"] == 0 and math.isnan(stats["val_accuracy"])
    report = held_out_report({**stats, "episodes": 3}, 0.1)
    assert "nan" not in report
    assert report.startswith("no held-out episode (--val-fraction 0.1 of 3 episodes rounds down to none)")
    assert f"training accuracy {stats['train_accuracy']:.3f}" in report
    assert "--val-fraction 0)" in held_out_report({**stats, "episodes": 3}, 0.0)

    stats = fit_gate(CompletionGate({"s": 3}), x, near, episodes, steps=5, val_fraction=0.4)
    assert stats["val_episodes"] == 1
    report = held_out_report({**stats, "episodes": 3}, 0.4)
    assert (
        report.startswith(f"1 held-out episodes: accuracy {stats['val_accuracy']:.3f}")
        and "nan" not in report
    )


def test_fit_completion_gate_reports_no_held_out_episode_on_a_small_dataset(
    diffusion_base, demo_root, tmp_path, capsys
) -> None:
    """Two episodes with the default --val-fraction 0.1: none is held out, and the summary says so (it
    printed ``accuracy nan``)."""
    from lerobot_dcdp.train.fit_completion_gate import main

    data = ["--repo-id", "local/test", "--root", str(demo_root)]
    key = "observation.environment_state"
    main(
        [
            "--base",
            str(diffusion_base),
            "--anchor-feature",
            key,
            *data,
            "--out",
            str(tmp_path / "g"),
            "--steps",
            "5",
        ]
    )
    printed = capsys.readouterr().out
    assert "nan" not in printed
    assert (
        "no held-out episode (--val-fraction 0.1 of 2 episodes rounds down to none): training accuracy"
        in printed
    )
