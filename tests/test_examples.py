"""The scripts in examples/, run as a user runs them, with tiny settings so that they never rot."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from lerobot_dcdp.policy.configuration_dcdp import EXECUTION_MODES

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"
SHIPPED = REPO / "models" / "pusht-dcdp-state"
BIN = Path(sys.executable).parent


def load_example(name: str) -> ModuleType:
    """Import ``examples/<name>.py`` (not a package) as a module."""
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_wrap_your_policy(diffusion_base: Path, demo_root: Path, tmp_path: Path, capsys) -> None:
    example = load_example("wrap_your_policy")
    out = tmp_path / "corrector"
    example.main(
        [
            str(diffusion_base),
            *("--repo-id", "local/test", "--root", str(demo_root), "--out", str(out)),
            *("--steps", "2", "--batch-size", "4", "--feature-dim", "32"),
            *("--anchor-feature", "observation.environment_state"),
        ]
    )
    printed = capsys.readouterr().out
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["type"] == "dcdp" and cfg["base_policy_type"] == "diffusion"
    assert (out / "model.safetensors").is_file() and (out / "policy_preprocessor.json").is_file()
    assert "step 2/2" in printed
    for mode in ("open_loop", "closed_loop", "temporal_ensemble", "object_anchored", "dcdp"):
        assert f"{mode} " in printed

    # the saved corrector runs again, from its directory, in every mode (object_anchored too: it names an
    # anchor feature), and reports what it returns; a 2-step corrector on a random base does not replay the
    # recorded actions
    results = example.run_every_mode(out, "local/test", demo_root, episode=1)
    assert list(results) == list(EXECUTION_MODES)
    report = capsys.readouterr().out
    for mode, r in results.items():
        assert math.isfinite(r["mae"]) and r["mae"] > 0, (mode, r)
        assert f"{mode:18s} |action - recorded| {r['mae']:8.3f}" in report, mode


def test_wrap_your_policy_refuses_a_non_policy_dir(tmp_path: Path) -> None:
    example = load_example("wrap_your_policy")
    with pytest.raises(SystemExit):
        example.main([str(tmp_path), "--repo-id", "local/x", "--out", str(tmp_path / "o")])


@pytest.mark.slow
def test_perturbed_eval(tmp_path: Path, capsys) -> None:
    example = load_example("perturbed_eval")
    out = tmp_path / "sweep.png"
    example.main(
        [
            str(SHIPPED),
            *("--modes", "open_loop", "dcdp", "--magnitudes", "0", "2"),
            *("--episodes", "1", "--max-steps", "8", "--out", str(out)),
        ]
    )
    assert out.stat().st_size > 0
    saved = json.loads(out.with_suffix(".json").read_text())
    assert saved["magnitudes"] == [0.0, 2.0] and set(saved["scores"]) == {"open_loop", "dcdp"}
    assert all(0.0 <= s <= 1.0 for ys in saved["scores"].values() for s in ys)
    assert "dcdp               drift  2.0 px/step" in capsys.readouterr().out


def test_perturbed_eval_modes_need_a_dcdp_policy(diffusion_base: Path) -> None:
    example = load_example("perturbed_eval")
    with pytest.raises(ValueError, match="--modes needs a dcdp policy"):
        example.sweep(diffusion_base, [0.0], modes=["dcdp"])


@pytest.mark.slow
def test_fastumi_to_corrector(tmp_path: Path) -> None:
    from test_fastumi import write_episode

    for i in range(2):
        write_episode(tmp_path / "raw" / "pick" / f"episode_{i}.hdf5", num=30, cols=8)
    tiny_act = (
        "--policy.chunk_size=8 --policy.n_action_steps=8 --policy.dim_model=32 --policy.n_heads=2 "
        "--policy.dim_feedforward=64 --policy.n_encoder_layers=1 --policy.n_decoder_layers=1 "
        "--policy.pretrained_backbone_weights=null --num_workers=0"
    )
    tiny_dcdp = (
        "--policy.n_history=3 --policy.n_action_steps=4 --policy.feature_dim=32 --policy.n_heads=4 "
        "--num_workers=0"
    )
    env = {
        **os.environ,
        "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
        "HF_HUB_OFFLINE": "1",
        "OMP_NUM_THREADS": "1",
        "STEPS": "2",
        "BASE_STEPS": "2",
        "BATCH": "4",
        "IMAGE_SIZE": "32",
        "BASE_FLAGS": tiny_act,
        "DCDP_FLAGS": tiny_dcdp,
    }
    work = tmp_path / "work"
    proc = subprocess.run(
        ["bash", str(EXAMPLES / "fastumi_to_corrector.sh"), str(tmp_path / "raw"), str(work)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    info = json.loads((work / "data" / "meta" / "info.json").read_text())
    assert (info["total_episodes"], info["total_frames"]) == (2, 60)
    base = work / "act" / "checkpoints" / "last" / "pretrained_model"
    assert json.loads((base / "config.json").read_text())["type"] == "act"
    # no object keypoints in FastUMI data: no corrector is trained, and the script says why
    assert "no corrector trained: this data holds no object keypoints" in proc.stdout
    assert not (work / "dcdp").exists()

    # what a user who opts into the paper's recipe gets (ANCHOR=none + an explicit correction)
    env.update(ANCHOR="none", DCDP_FLAGS=tiny_dcdp + " --policy.correction=reconstruct")
    proc = subprocess.run(
        [
            "bash",
            str(EXAMPLES / "fastumi_to_corrector.sh"),
            str(tmp_path / "raw"),
            str(tmp_path / "w2"),
            str(base),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    ckpt = tmp_path / "w2" / "dcdp" / "checkpoints" / "last" / "pretrained_model"
    assert f"corrector: {ckpt}" in proc.stdout
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["base_policy_type"] == "act" and "observation.images.front" in cfg["input_features"]


def test_fastumi_to_corrector_usage() -> None:
    proc = subprocess.run(["bash", str(EXAMPLES / "fastumi_to_corrector.sh")], capture_output=True, text=True)
    assert proc.returncode == 2 and "Usage" in proc.stderr
