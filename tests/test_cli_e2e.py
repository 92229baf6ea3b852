"""The real CLIs as a user runs them: discovery, lerobot-train (stage 1), resume, lerobot-eval (stage 2)."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from helpers import BIN, CLI_ENV, corrector_train_args, run, train_corrector
from safetensors.torch import load_file, save_file

OBS = "environment_state_agent_pos"

#: ``lerobot-train`` that SIGKILLs itself right after its first checkpoint is complete (``last`` updated):
#: a run killed mid-run at a known point, no clean shutdown, whatever the machine's speed.
KILLED_AFTER_FIRST_CHECKPOINT = """
import os, signal, sys
import lerobot.scripts.lerobot_train as lerobot_train
update = lerobot_train.update_last_checkpoint
def update_then_die(checkpoint_dir):
    update(checkpoint_dir)
    os.kill(os.getpid(), signal.SIGKILL)
lerobot_train.update_last_checkpoint = update_then_die
sys.argv[0] = "lerobot-train"
lerobot_train.main()
"""


def evaluate(policy_dir: Path, out: Path, *extra: str, ok: bool = True) -> subprocess.CompletedProcess:
    return run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={policy_dir}",
            "--env.type=pusht_perturbed",
            "--env.perturbation=constant",
            "--env.magnitude=1",
            f"--env.obs_type={OBS}",
            "--env.episode_length=12",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            "--eval.use_async_envs=false",
            f"--output_dir={out}",
            "--policy.device=cpu",
            *extra,
        ],
        cwd=out.parent,
        ok=ok,
    )


def test_discovery_through_lerobot() -> None:
    code = (
        "from lerobot.utils.import_utils import register_third_party_plugins as r; r();"
        "from lerobot.policies.factory import get_policy_class, make_policy_config;"
        "from lerobot.envs.configs import EnvConfig;"
        "from lerobot.processor import ProcessorStepRegistry as P;"
        "print(get_policy_class('dcdp').__name__, EnvConfig.get_choice_class('pusht_perturbed').__name__,"
        " P.get('dcdp_split_state').__name__)"
    )
    proc = run([sys.executable, "-c", code], cwd=Path.cwd())
    assert proc.stdout.split()[-3:] == ["DCDPPolicy", "PushTPerturbedEnvConfig", "SplitStateProcessorStep"]


def test_train_help_describes_every_dcdp_option() -> None:
    """``lerobot-train --policy.type=dcdp --help`` describes each option (the option groups' ``Args:``) and
    lists its flat flag."""
    import dataclasses

    from lerobot_dcdp.policy import config_options

    proc = run([str(BIN / "lerobot-train"), "--policy.type=dcdp", "--help"], cwd=Path.cwd())
    for group in config_options.OPTION_GROUPS:
        for f in dataclasses.fields(group):
            assert f"        {f.name}: " in proc.stdout, f.name
            assert f"--policy.{f.name} " in proc.stdout, f.name


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["diffusion", "act"])
def test_train_then_eval(kind, request, demo_root, tmp_path) -> None:
    base = request.getfixturevalue(f"{kind}_base")
    # the diffusion corrector is the session's shared lerobot-train run (same command); ACT's is trained here
    if kind == "diffusion":
        ckpt = request.getfixturevalue("trained_corrector")
    else:
        ckpt = train_corrector(base, demo_root, tmp_path / "train")
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["type"] == "dcdp" and cfg["base_policy_type"] == kind and len(cfg["base_weights_sha256"]) == 64
    weights = load_file(ckpt / "model.safetensors")
    base_weights = load_file(base / "model.safetensors")
    assert not set(weights) & set(base_weights)
    # the checkpoint normalises with the base's statistics, not the dataset's: the base's pre-processor,
    # behind the step that splits a robot's flattened state (for lerobot-rollout) and the one that checks
    # every input's shape before LeRobot's normaliser sees it
    name = "policy_preprocessor.json"
    saved, base_pre = (json.loads((d / name).read_text())["steps"] for d in (ckpt, base))
    assert saved[:2] == [
        {
            "registry_name": "dcdp_split_state",
            "config": {"splits": [["observation.state", 2], ["observation.environment_state", 16]]},
        },
        {
            "registry_name": "dcdp_check_observation",
            "config": {"shapes": {"observation.state": [2], "observation.environment_state": [16]}},
        },
    ]
    assert len(saved) == len(base_pre) + 2
    for ours, theirs in zip(saved[2:], base_pre, strict=True):
        assert ours["config"] == theirs["config"] and ours["registry_name"] == theirs["registry_name"]
        assert ("state_file" in ours) == ("state_file" in theirs)
        if "state_file" in theirs:
            a, b = load_file(ckpt / ours["state_file"]), load_file(base / theirs["state_file"])
            assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    for mode in ("dcdp", "open_loop") if kind == "diffusion" else ("dcdp", "temporal_ensemble"):
        out = tmp_path / f"eval_{mode}"
        evaluate(ckpt, out, f"--policy.execution={mode}")
        full = json.loads((out / "eval_info.json").read_text())
        info, per_episode = full["overall"], full["per_task"][0]["metrics"]["max_rewards"]
        assert info["n_episodes"] == 2 and len(per_episode) == 2
        assert info["avg_max_reward"] == pytest.approx(sum(per_episode) / 2)
        if kind == "act":  # ACT and the corrector are deterministic at inference: our harness must agree
            assert per_episode == pytest.approx(_harness_max_rewards(ckpt, mode), abs=1e-6)


def _harness_max_rewards(ckpt: Path, mode: str) -> list[float]:
    """The benchmark harness's per-episode max reward for what ``evaluate`` runs (seeds 1000, 1001)."""
    from lerobot_dcdp.benchmark.rollout import Condition, rollout
    from lerobot_dcdp.benchmark.run import load_model

    policy, pre, post, _ = load_model(str(ckpt))
    policy.config.execution = mode
    return rollout(policy, pre, post, Condition("c", "constant", 1.0), [1000, 1001], max_steps=12).max_rewards


@pytest.mark.slow
def test_killed_training_resumes_from_checkpoint(diffusion_base, demo_root, tmp_path) -> None:
    """A run SIGKILLed mid-run (right after its step-2 checkpoint, 99998 steps to go) resumes from that
    checkpoint with ``--resume`` and trains on from it."""
    out = tmp_path / "train"
    args = corrector_train_args(diffusion_base, demo_root, out, steps=100000, save_freq=2)
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_AFTER_FIRST_CHECKPOINT, *args[1:]],
        capture_output=True,
        text=True,
        timeout=600,
        env=CLI_ENV,
        cwd=tmp_path,
    )
    assert killed.returncode == -signal.SIGKILL, killed.stdout[-3000:] + killed.stderr[-6000:]
    last = (out / "checkpoints" / "last").resolve()
    assert last.name == "000002" and sorted(p.name for p in (out / "checkpoints").iterdir()) == [
        "000002",
        "last",
    ]
    step = json.loads((last / "training_state" / "training_step.json").read_text())["step"]
    assert step == 2
    before = load_file(last / "pretrained_model" / "model.safetensors")
    run(
        [
            str(BIN / "lerobot-train"),
            "--resume=true",
            f"--config_path={last / 'pretrained_model' / 'train_config.json'}",
            f"--steps={step + 2}",
        ],
        cwd=tmp_path,
    )
    final = out / "checkpoints" / f"{step + 2:06d}"
    assert json.loads((final / "training_state" / "training_step.json").read_text())["step"] == step + 2
    after = load_file(final / "pretrained_model" / "model.safetensors")
    assert set(after) == set(before) and any(not torch.equal(after[k], before[k]) for k in before)


@pytest.mark.slow
def test_eval_refuses_a_changed_base(trained_corrector, diffusion_base, tmp_path) -> None:
    """The corrector pointed at a base whose weights differ from those it was trained against (a copy of its
    base with one tensor nudged) is refused by lerobot-eval."""
    base = tmp_path / "base"
    shutil.copytree(diffusion_base, base)
    weights = load_file(base / "model.safetensors")
    name = sorted(weights)[0]
    weights[name] = weights[name] + 1e-3
    save_file(weights, base / "model.safetensors")
    proc = evaluate(trained_corrector, tmp_path / "eval", f"--policy.base_policy_path={base}", ok=False)
    assert proc.returncode != 0
    assert "base_weights_sha256 mismatch" in proc.stdout + proc.stderr


@pytest.mark.slow
def test_accelerate_two_cpu_processes(diffusion_base, demo_root, tmp_path) -> None:
    """LeRobot's multi-GPU path (accelerate + DDP) with 2 CPU processes: the frozen base is outside DDP,
    and an ablation that leaves alpha without gradients raises no unused-parameter error."""
    out = tmp_path / "acc"
    run(
        [
            str(BIN / "accelerate"),
            "launch",
            "--cpu",
            "--num_processes=2",
            "--num_machines=1",
            "--mixed_precision=no",
            "--dynamo_backend=no",
            *corrector_train_args(diffusion_base, demo_root, out, steps=3, save_freq=3, batch=4),
            "--policy.use_diff_cross_attention=false",
            "--policy.use_diff_loss=false",
        ],
        cwd=tmp_path,
    )
    assert (out / "checkpoints" / "000003" / "pretrained_model" / "model.safetensors").is_file()


@pytest.mark.slow
def test_quantile_normalised_base_through_the_clis(demo_root, tmp_path) -> None:
    """A stock ACT base normalised with QUANTILES / QUANTILE10 (pi0.5-style), trained by lerobot-train: the
    wrapper maps its actions with the base's own quantiles, and every execution mode runs in lerobot-eval."""
    from helpers import tiny_train_flags

    from lerobot_dcdp.model.correction import normalize
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    mapping = '{"VISUAL": "MEAN_STD", "STATE": "QUANTILE10", "ENV": "QUANTILES", "ACTION": "QUANTILES"}'
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=act",
            *tiny_train_flags("local/test", demo_root),
            f"--output_dir={tmp_path / 'act'}",
            f"--policy.normalization_mapping={mapping}",
            "--policy.chunk_size=8",
            "--policy.n_action_steps=8",
            "--policy.dim_model=32",
            "--policy.n_heads=2",
            "--policy.dim_feedforward=64",
            "--policy.n_encoder_layers=1",
            "--policy.n_decoder_layers=1",
            "--policy.pretrained_backbone_weights=null",
        ],
        cwd=tmp_path,
    )
    base = tmp_path / "act" / "checkpoints" / "last" / "pretrained_model"
    ckpt = train_corrector(base, demo_root, tmp_path / "train", steps=2)
    policy = DCDPPolicy.from_pretrained(ckpt)
    mode, stats = policy.normalizer.stats["action"]
    assert mode == "QUANTILES"
    torch.testing.assert_close(policy.corrector.action_low, normalize(stats["min"], stats, mode))
    torch.testing.assert_close(policy.corrector.action_high, normalize(stats["max"], stats, mode))
    for mode in ("dcdp", "open_loop", "closed_loop", "temporal_ensemble", "object_anchored"):
        out = tmp_path / f"eval_{mode}"
        evaluate(ckpt, out, f"--policy.execution={mode}")
        assert json.loads((out / "eval_info.json").read_text())["overall"]["n_episodes"] == 2


@pytest.mark.slow
def test_a_state_corrector_in_a_pixel_env_names_the_obs_type(trained_corrector, tmp_path) -> None:
    proc = evaluate(trained_corrector, tmp_path / "eval", "--env.obs_type=pixels_agent_pos", ok=False)
    assert proc.returncode != 0
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if "Error" in ln and ": " in ln]
    assert lines and "--env.obs_type=environment_state_agent_pos" in lines[-1], (lines, proc.stderr[-3000:])
