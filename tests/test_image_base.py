"""Image path: image-only PushT demos -> diffusion base + ResNet18 (no download) -> a DCDP corrector on images
(ResNet18 frame backbone) trained with lerobot-train -> stage 2 of every execution mode in lerobot-eval."""

from __future__ import annotations

import json

import pytest
from helpers import tiny_train_flags
from test_cli_e2e import BIN, run

from lerobot_dcdp.pusht.demos import record_demonstrations


@pytest.mark.slow
def test_image_base_and_image_corrector_train_and_evaluate(tmp_path) -> None:
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
    _eval_one_image_episode(ckpt, tmp_path / "eval", "--env.type=pusht", "--env.episode_length=8")

    # the corrector on images: ResNet18 per-frame backbone (random weights, nothing downloaded)
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={ckpt}",
            *tiny_train_flags("local/img", data),
            f"--output_dir={tmp_path / 'dcdp'}",
            "--policy.feature_dim=32",
            "--policy.n_heads=4",
        ],
        cwd=tmp_path,
    )
    corrector = tmp_path / "dcdp" / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((corrector / "config.json").read_text())
    assert cfg["backbone"] == "auto" and "observation.image" in cfg["input_features"]
    for mode in ("dcdp", "open_loop", "closed_loop"):
        _eval_one_image_episode(
            corrector,
            tmp_path / f"eval_{mode}",
            f"--policy.execution={mode}",
            "--env.type=pusht_perturbed",
            "--env.perturbation=constant",
            "--env.magnitude=2",
            "--env.episode_length=10",
        )


def _eval_one_image_episode(policy_dir, out, *flags: str) -> None:
    """One ``lerobot-eval`` episode on PushT pixels (+ agent position), sync env, CPU."""
    run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={policy_dir}",
            *flags,
            "--env.obs_type=pixels_agent_pos",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={out}",
        ],
        cwd=out.parent,
    )
    assert json.loads((out / "eval_info.json").read_text())["overall"]["n_episodes"] == 1
