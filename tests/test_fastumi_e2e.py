"""End to end on FastUMI data: convert, train a tiny ACT base, then DCDP stage 1 on images (ResNet18)."""

from __future__ import annotations

import json

import pytest
from helpers import tiny_train_flags
from test_cli_e2e import BIN, run
from test_fastumi import write_episode

from lerobot_dcdp.data.fastumi.convert import convert_fastumi


@pytest.mark.slow
def test_fastumi_to_act_base_to_dcdp_with_images(tmp_path) -> None:
    for i in range(2):
        write_episode(
            tmp_path / "raw" / "pick" / f"episode_{i}.hdf5",
            num=30,
            cols=8,
            cams={"front": ((0, 0, 255), 48, 64)},
        )
    data = tmp_path / "data"
    convert_fastumi(tmp_path / "raw", "local/umi", data, image_size=32)
    common = tiny_train_flags("local/umi", data)
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=act",
            *common,
            f"--output_dir={tmp_path / 'act'}",
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
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={base}",
            *common,
            f"--output_dir={tmp_path / 'dcdp'}",
            "--policy.correction=reconstruct",  # no object pose in this data: the paper's image path
            "--policy.n_history=3",
            "--policy.n_action_steps=4",
            "--policy.feature_dim=32",
            "--policy.n_heads=4",
        ],
        cwd=tmp_path,
    )
    ckpt = tmp_path / "dcdp" / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["base_policy_type"] == "act"
    assert "observation.images.front" in cfg["input_features"]
    from safetensors.torch import load_file

    weights = load_file(ckpt / "model.safetensors")
    assert any(k.startswith("corrector.frame_encoder.image.") for k in weights)  # ResNet18 built, saved
