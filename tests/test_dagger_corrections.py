"""``dcdp-dagger-to-corrections``: a recording in the format of ``lerobot-rollout --strategy.type=dagger``
(the pusht_sim robot's flattened state, the action sent, ``intervention``) becomes a corrections dataset
the stock ``lerobot-train`` trains the residual corrector on."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import tiny_train_flags

from lerobot_dcdp.data.dagger_corrections import chunk_starts

BIN = Path(sys.executable).parent
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}


def test_chunks_start_every_horizon_and_when_the_robot_takes_over_again() -> None:
    person = np.array([0, 0, 0, 0, 0, 1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=bool)
    assert chunk_starts(person, 3).tolist() == [0, 0, 0, 3, 3, 3, 6, 6, 8, 8, 8, 11, 11, 11]
    assert chunk_starts(np.zeros(5, dtype=bool), 8).tolist() == [0] * 5
    with pytest.raises(ValueError, match="horizon must be >= 1"):
        chunk_starts(person, 0)


def _record_dagger_like(root: Path, episodes: int = 2, length: int = 24) -> None:
    """What LeRobot's DAgger strategy writes for pusht_sim: the robot's features through LeRobot's own
    hw_to_dataset_features, plus ``intervention``; the scripted teleoperator drives frames 8..15."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.feature_utils import hw_to_dataset_features

    from lerobot_dcdp.sim.robots import PushTSim, PushTSimConfig
    from lerobot_dcdp.sim.teleoperators import PushTExpert, PushTExpertConfig

    robot = PushTSim(PushTSimConfig(calibration_dir=root.parent / "calib", realtime=False, seed=3))
    features = {
        **hw_to_dataset_features(robot.observation_features, "observation"),
        **hw_to_dataset_features(robot.action_features, "action"),
        "intervention": {"dtype": "bool", "shape": (1,), "names": None},
    }
    ds = LeRobotDataset.create("user/rollout_dagger", fps=10, features=features, root=root, use_videos=False)
    teleop = PushTExpert(PushTExpertConfig(calibration_dir=root.parent / "calib", replan_every=4))
    teleop.connect()
    for _ in range(episodes):
        robot.connect()
        teleop.reset()
        for t in range(length):
            obs = robot.get_observation()
            person = 8 <= t < 16
            teleop.send_feedback(obs)
            action = teleop.get_action() if person else {"x.pos": obs["x.pos"] + 5.0, "y.pos": obs["y.pos"]}
            robot.send_action(action)
            ds.add_frame(
                {
                    "observation.state": np.array([obs[k] for k in robot.observation_features], np.float32),
                    "action": np.array([action["x.pos"], action["y.pos"]], np.float32),
                    "intervention": np.array([person]),
                    "task": "Push the T-shaped block onto the T-shaped target.",
                }
            )
        ds.save_episode()
        robot.disconnect()
    ds.finalize()


@pytest.mark.slow
def test_a_dagger_recording_becomes_corrections_that_train(diffusion_base, tmp_path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    rec = tmp_path / "rollout_dagger"
    _record_dagger_like(rec)
    out = tmp_path / "corrections"
    proc = subprocess.run(
        [
            str(BIN / "dcdp-dagger-to-corrections"),
            f"--base={diffusion_base}",
            "--repo-id=user/rollout_dagger",
            f"--root={rec}",
            "--out-repo-id=local/dagger",
            f"--out-root={out}",
            "--n-action-steps=4",
        ],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=tmp_path,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "2 episodes (48 frames, 16 by the person, 12 chunks)" in proc.stdout
    src, ds = LeRobotDataset("user/rollout_dagger", root=rec), LeRobotDataset("local/dagger", root=out)
    assert len(ds) == len(src) == 48
    for i in range(len(ds)):
        a, b = src[i], ds[i]
        state = a["observation.state"]
        assert torch.equal(b["observation.state"], state[:2])  # the flattened robot state, split back
        assert torch.equal(b["observation.environment_state"], state[2:])
        assert torch.equal(b["executed_action"], a["action"])
        t = i % 24
        step = int(b["observation.dcdp_plan_step"])
        assert step == ((t % 4) if t < 16 else (t - 16) % 4)  # replans when the robot takes over at 16
        if bool(a["intervention"]):
            assert torch.equal(b["action"], a["action"])  # the person's action is the label
        else:
            assert torch.equal(b["action"], b["observation.dcdp_plan"].reshape(-1, 2)[step])
    run = subprocess.run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={diffusion_base}",
            "--policy.n_action_steps=4",
            "--policy.feature_dim=32",
            "--policy.n_heads=4",
            f"--output_dir={tmp_path / 'train'}",
            *tiny_train_flags("local/dagger", out),
        ],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=tmp_path,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-4000:]
    assert (tmp_path / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file()


def test_a_recording_without_interventions_is_refused(diffusion_base, demo_root, tmp_path) -> None:
    from lerobot_dcdp.data.dagger_corrections import dagger_to_corrections

    with pytest.raises(ValueError, match="record it with lerobot-rollout --strategy.type=dagger"):
        dagger_to_corrections(diffusion_base, "local/test", demo_root, "x/y", tmp_path / "out")
    with pytest.raises(ValueError, match="autonomous_label must be one of"):
        dagger_to_corrections(
            diffusion_base, "local/test", demo_root, "x/y", tmp_path / "o", autonomous_label="x"
        )


def _record_camera_dagger(root: Path, episodes: int = 3, length: int = 10) -> None:
    """A DAgger recording of a camera robot: a 96x96 video camera seeing a square that moves with the state
    (and a tint that changes every frame, so frames cannot be confused), the action sent and
    ``intervention`` (the person drives frames 3..5 of each episode)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {
        "observation.image": {
            "dtype": "video",
            "shape": (96, 96, 3),
            "names": ["height", "width", "channels"],
        },
        "observation.state": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        "action": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        "intervention": {"dtype": "bool", "shape": (1,), "names": None},
    }
    ds = LeRobotDataset.create("user/cam_dagger", fps=10, features=features, root=root, use_videos=True)
    yy, xx = np.mgrid[0:96, 0:96]
    for e in range(episodes):
        for t in range(length):
            x, y, person = 10 + 6 * t, 20 + 10 * e, 3 <= t < 6
            img = np.stack([xx * 2, yy * 2, np.full_like(xx, 20 + 22 * t)], -1).astype(np.uint8)
            img[y : y + 20, x : x + 20] = (230, 40, 40)
            ds.add_frame(
                {
                    "observation.image": img,
                    "observation.state": np.array([x, y], np.float32),
                    "action": np.array([x + (-3 if person else 6), y], np.float32),
                    "intervention": np.array([person]),
                    "task": "push the square",
                }
            )
        ds.save_episode()
    ds.finalize()


def test_a_camera_dagger_recording_keeps_its_frames_for_an_image_base(tmp_path) -> None:
    from helpers import make_tiny_base
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.dagger_corrections import _cameras, dagger_to_corrections

    rec, out = tmp_path / "rec", tmp_path / "corrections"
    _record_camera_dagger(rec)
    # a stock diffusion base reading the camera and the state (random init: what it plans is not checked)
    base = make_tiny_base("diffusion", tmp_path / "base", rec, images=True, num_inference_steps=2)
    counts = dagger_to_corrections(base, "user/cam_dagger", rec, "local/cam_corr", out, n_action_steps=4)
    assert counts == {"episodes": 3, "frames": 30, "intervention_frames": 9, "chunks": 9}
    src, ds = LeRobotDataset("user/cam_dagger", root=rec), LeRobotDataset("local/cam_corr", root=out)
    camera = ds.meta.features["observation.image"]
    assert camera["dtype"] == "video" and tuple(camera["shape"]) == (96, 96, 3)
    previous = None
    for i in range(len(ds)):
        a, b = src[i], ds[i]
        error = (b["observation.image"] - a["observation.image"]).abs().mean()
        assert error < 0.05  # the recorded frame, re-encoded
        if i % 10:  # and not its predecessor
            assert error < (b["observation.image"] - previous).abs().mean()
        previous = a["observation.image"]
        assert torch.equal(b["observation.state"], a["observation.state"])
        plan, step = b["observation.dcdp_plan"].reshape(-1, 2), int(b["observation.dcdp_plan_step"])
        assert plan.shape == (8, 2) and plan.abs().sum() > 0
        label = a["action"] if bool(a["intervention"]) else plan[step]
        assert torch.equal(b["action"], label)  # the person's action where the person drove
    cfg = PreTrainedConfig.from_pretrained(base)
    with pytest.raises(ValueError, match="the camera 'observation.image', which the recording lacks"):
        _cameras(cfg, {})
    depth = {"dtype": "video", "shape": (96, 96, 1), "names": None, "info": {"is_depth_map": True}}
    with pytest.raises(ValueError, match="camera 'observation.image' .* is not an RGB image"):
        _cameras(cfg, {"observation.image": depth})
