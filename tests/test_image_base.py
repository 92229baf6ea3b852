"""Image path: image-only PushT demos -> diffusion base + ResNet18 (no download) -> recorded image
corrections -> a keypoint reader and a residual corrector reading it, and the paper's image corrector (the
base's own image encoder, ``backbone='auto'``'s choice), trained by lerobot-train -> stage 2 of the execution
modes in lerobot-eval under pixels only."""

from __future__ import annotations

import json

import pytest
from helpers import BIN, run, tiny_train_flags


@pytest.mark.slow
def test_image_base_and_image_corrector_train_and_evaluate(image_demo_root, tmp_path) -> None:
    data = image_demo_root
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
    _record_image_corrections(ckpt, tmp_path / "corrections")
    _keypoint_reader_corrector(ckpt, tmp_path / "corrections", tmp_path)

    # the corrector on images: by default its frames go through the base's own trained image encoder
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={ckpt}",
            *tiny_train_flags("local/img", data),
            f"--output_dir={tmp_path / 'dcdp'}",
            "--policy.correction=reconstruct",  # images only, no object keypoints: the paper's recipe
            "--policy.feature_dim=32",
            "--policy.n_heads=4",
        ],
        cwd=tmp_path,
    )
    corrector = tmp_path / "dcdp" / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((corrector / "config.json").read_text())
    assert cfg["backbone"] == "base_encoder" and "observation.image" in cfg["input_features"]
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


@pytest.mark.slow
def test_stock_vqbet_base_is_wrapped_generically(image_demo_root, tmp_path) -> None:
    """LeRobot's third chunking policy: a stock VQ-BeT (one image + state, 5-frame history) trained by
    lerobot-train, wrapped with no VQ-BeT-specific code; open loop through the wrapper takes the base's own
    select_action actions, and every execution mode runs in lerobot-eval."""
    import torch

    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    data = image_demo_root
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=vqbet",
            *tiny_train_flags("local/img", data, steps=3),
            f"--output_dir={tmp_path / 'vqbet'}",
            "--policy.pretrained_backbone_weights=null",
            "--policy.crop_shape=[84,84]",
            "--policy.n_vqvae_training_steps=2",
            "--policy.vqvae_n_embed=8",
            "--policy.vqvae_embedding_dim=32",
            "--policy.vqvae_enc_hidden_dim=32",
            "--policy.gpt_n_layer=1",
            "--policy.gpt_n_head=2",
            "--policy.gpt_hidden_dim=32",
            "--policy.gpt_input_dim=32",
            "--policy.gpt_output_dim=32",
            "--policy.spatial_softmax_num_keypoints=8",
        ],
        cwd=tmp_path,
    )
    base = tmp_path / "vqbet" / "checkpoints" / "last" / "pretrained_model"
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={base}",
            *tiny_train_flags("local/img", data),
            f"--output_dir={tmp_path / 'dcdp'}",
            "--policy.correction=reconstruct",
            "--policy.n_action_steps=5",  # VQ-BeT returns action_chunk_size = 5 actions per call
            "--policy.feature_dim=32",
            "--policy.n_heads=4",
        ],
        cwd=tmp_path,
    )
    corrector = tmp_path / "dcdp" / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((corrector / "config.json").read_text())
    assert cfg["base_policy_type"] == "vqbet"

    # open loop through the wrapper == the base's own select_action, frame by frame (both deterministic)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors

    policy = DCDPPolicy.from_pretrained(corrector)
    policy.config.execution = "open_loop"
    policy.eval().reset()
    pre, _ = make_pre_post_processors(policy.config, pretrained_path=str(corrector))
    own = DCDPPolicy.from_pretrained(corrector).base  # a second copy of the base, run as LeRobot runs it
    own.reset()
    ds = LeRobotDataset("local/img", root=data)
    for i in range(12):
        obs = pre({k: ds[i][k].unsqueeze(0) for k in ("observation.image", "observation.state")})
        torch.manual_seed(i)  # VQ-BeT samples its codes: the same draws for both
        ours = policy.select_action(dict(obs))
        torch.manual_seed(i)
        torch.testing.assert_close(ours, own.select_action(dict(obs)))
    for mode in ("dcdp", "open_loop", "closed_loop", "temporal_ensemble"):
        _eval_one_image_episode(
            corrector,
            tmp_path / f"eval_{mode}",
            f"--policy.execution={mode}",
            "--env.type=pusht_perturbed",
            "--env.perturbation=constant",
            "--env.magnitude=2",
            "--env.episode_length=8",
        )


def _record_image_corrections(base, root) -> None:
    """``dcdp-record-corrections`` around the image base under drift: the frames are stored as video beside
    the agent position and the simulator's keypoints (the anchoring teacher's labels), and the labels move the
    plan with the block (privileged at recording time only)."""
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    run(
        [
            str(BIN / "dcdp-record-corrections"),
            f"--base={base}",
            f"--root={root}",
            "--repo-id=local/img_corr",
            "--episodes=2",
            "--max-steps=12",
            "--static-fraction=0",
            "--max-magnitude=2.5",
            "--anchor-feature=observation.environment_state",
            "--execution=open_loop",  # the base's stale chunks drive; the labels carry them with the block
            "--env.type=pusht_perturbed",
            "--env.obs_type=pixels_environment_state_agent_pos",
        ],
        cwd=root.parent,
    )
    ds = LeRobotDataset("local/img_corr", root=root)
    feats = ds.meta.features
    assert feats["observation.image"]["dtype"] == "video"
    assert tuple(feats["observation.image"]["shape"]) == (96, 96, 3)
    assert tuple(feats["observation.environment_state"]["shape"]) == (16,)
    assert ds.num_episodes == 2 and ds.num_frames == 24
    frame = ds[5]
    assert frame["observation.image"].shape == (3, 96, 96) and frame["observation.image"].max() > 0.5
    labels = np.stack([ds[i]["action"].numpy() for i in range(ds.num_frames)])
    executed = np.stack([ds[i]["executed_action"].numpy() for i in range(ds.num_frames)])
    assert np.abs(labels - executed).max() > 0.5  # the teacher moved the stale plan with the drifting block


def _keypoint_reader_corrector(base, corrections, tmp_path) -> None:
    """The image corrector: a frame -> keypoints reader fitted on the recorded frames (the simulator's
    keypoints are its targets), then the residual corrector trained by lerobot-train on the recorded
    corrections with the reader in its pre-processor; lerobot-eval runs it, and the training-free anchoring on
    the reader, where the env gives pixels and the agent position only."""
    reader = tmp_path / "reader"
    run(
        [
            str(BIN / "dcdp-fit-pixel-keypoints"),
            "--repo-id=local/img_corr",
            f"--root={corrections}",
            f"--out={reader}",
            "--steps=5",
            "--batch-size=8",
            "--val-episodes=1",
        ],
        cwd=tmp_path,
    )
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={base}",
            *tiny_train_flags("local/img_corr", corrections),
            f"--output_dir={tmp_path / 'dcdp_kp'}",
            f"--policy.keypoint_reader_path={reader}",
            "--policy.anchor_feature=observation.environment_state",
            "--policy.train_max_delay=0",
        ],
        cwd=tmp_path,
    )
    corrector = tmp_path / "dcdp_kp" / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((corrector / "config.json").read_text())
    assert cfg["input_features"]["observation.environment_state"]["shape"] == [16]
    steps = json.loads((corrector / "policy_preprocessor.json").read_text())["steps"]
    names = [s.get("registry_name") for s in steps]
    assert names.index("dcdp_pixel_keypoints") < names.index("dcdp_check_observation")
    assert list(corrector.glob("*dcdp_pixel_keypoints.safetensors"))  # the reader travels with the folder
    reader.rename(tmp_path / "reader_gone")  # the trained folder needs no reader folder
    for mode in ("dcdp", "object_anchored"):
        _eval_one_image_episode(
            corrector,
            tmp_path / f"eval_kp_{mode}",
            f"--policy.execution={mode}",
            "--env.type=pusht_perturbed",
            "--env.perturbation=constant",
            "--env.magnitude=2",
            "--env.episode_length=10",
        )
