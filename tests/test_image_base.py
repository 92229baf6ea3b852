"""Image path of a base: image-only PushT demos -> diffusion + ResNet18 (no download) -> one eval episode."""

from __future__ import annotations

import json

import pytest
from helpers import tiny_train_flags
from test_cli_e2e import BIN, run

from lerobot_dcdp.pusht.demos import record_demonstrations


@pytest.mark.slow
def test_image_diffusion_base_trains_and_evaluates(tmp_path) -> None:
    data = tmp_path / "img"
    record_demonstrations(data, "local/img", episodes=1, seed=3, images=True, keypoints=False, progress=False)
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=diffusion",
            *tiny_train_flags("local/img", data),
            f"--output_dir={tmp_path / 'train'}",
            "--policy.pretrained_backbone_weights=null",
            "--policy.crop_shape=[84,84]",
            "--policy.horizon=16",
            "--policy.n_obs_steps=2",
            "--policy.n_action_steps=8",
            "--policy.down_dims=[16,32]",
            "--policy.noise_scheduler_type=DDIM",
            "--policy.num_inference_steps=2",
        ],
        cwd=tmp_path,
    )
    ckpt = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    assert "observation.image" in json.loads((ckpt / "config.json").read_text())["input_features"]
    out = tmp_path / "eval"
    run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={ckpt}",
            "--env.type=pusht",
            "--env.obs_type=pixels_agent_pos",
            "--env.episode_length=8",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={out}",
        ],
        cwd=tmp_path,
    )
    assert json.loads((out / "eval_info.json").read_text())["overall"]["n_episodes"] == 1
