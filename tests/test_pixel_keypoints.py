"""The frame -> object-keypoints reader (`dcdp-fit-pixel-keypoints`) learns positions from pixels alone."""

import json

import numpy as np
import pytest
import torch

from lerobot_dcdp.model.pixel_keypoints import (
    PixelKeypointNet,
    PixelKeypointsConfig,
    keypoint_error,
    load_reader,
)
from lerobot_dcdp.train.fit_pixel_keypoints import main, split_episodes


def _square_frames(n: int, size: int = 32, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Frames (n, size, size, 3) uint8 with a bright 6x6 square; keypoints (n, 4): two opposite corners."""
    rng = np.random.default_rng(seed)
    corners = rng.integers(2, size - 8, size=(n, 2))
    images = np.zeros((n, size, size, 3), np.uint8)
    for i, (x, y) in enumerate(corners):
        images[i, y : y + 6, x : x + 6] = 220
    keypoints = np.concatenate([corners, corners + 6], axis=1).astype(np.float32)
    return images, keypoints


def _write_dataset(root, episodes: int = 5, frames: int = 40) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    images, keypoints = _square_frames(episodes * frames)
    ds = LeRobotDataset.create(
        repo_id="local/squares",
        fps=10,
        root=root,
        features={
            "observation.image": {
                "dtype": "image",
                "shape": (32, 32, 3),
                "names": ["height", "width", "channels"],
            },
            "observation.environment_state": {"dtype": "float32", "shape": (4,), "names": None},
            "action": {"dtype": "float32", "shape": (2,), "names": None},
        },
        use_videos=False,
    )
    for e in range(episodes):
        for t in range(frames):
            i = e * frames + t
            ds.add_frame(
                {
                    "observation.image": images[i],
                    "observation.environment_state": keypoints[i],
                    "action": np.zeros(2, np.float32),
                    "task": "find the square",
                }
            )
        ds.save_episode()
    ds.finalize()


def test_net_maps_frames_of_any_leading_shape_to_raw_keypoints():
    net = PixelKeypointNet(
        PixelKeypointsConfig(image_shape=(3, 32, 32), n_outputs=4, shift=[1, 2, 3, 4], scale=[2.0] * 4)
    )
    out = net(torch.rand(2, 3, 3, 32, 32))
    assert out.shape == (2, 3, 4)
    x = torch.rand(4, 3, 32, 32)
    torch.testing.assert_close(net(x), net.standardised(x) * 2.0 + torch.tensor([1.0, 2, 3, 4]))
    with pytest.raises(ValueError, match="shift must have n_outputs=4"):
        PixelKeypointsConfig(n_outputs=4, shift=[0.0])


def test_keypoint_error_is_the_mean_point_distance():
    a = torch.tensor([[0.0, 0.0, 0.0, 0.0]])
    b = torch.tensor([[3.0, 4.0, 0.0, 0.0]])
    assert keypoint_error(a, b).item() == pytest.approx(2.5)


def test_split_holds_out_the_last_episodes_and_refuses_too_few():
    episodes = torch.tensor([0, 0, 1, 1, 2, 2])
    train, val = split_episodes(episodes, 1)
    assert val.tolist() == [False, False, False, False, True, True] and (train == ~val).all()
    with pytest.raises(ValueError, match="needs more episodes"):
        split_episodes(episodes, 3)


def test_cli_fits_a_reader_far_better_than_the_mean_and_it_reloads(tmp_path, capsys):
    _write_dataset(tmp_path / "squares")
    out = tmp_path / "reader"
    main(
        [
            "--repo-id",
            "local/squares",
            "--root",
            str(tmp_path / "squares"),
            "--out",
            str(out),
            "--steps",
            "400",
            "--batch-size",
            "32",
            "--lr",
            "3e-3",
            "--val-episodes",
            "1",
        ]
    )
    fit = json.loads((out / "fit.json").read_text())
    assert fit["val_frames"] == 40 and fit["frames"] == 200
    assert fit["val_error"] < 0.35 * fit["zero_error"], fit  # it reads the square's place from the pixels
    net, image_key, target_key = load_reader(out)
    assert (image_key, target_key) == ("observation.image", "observation.environment_state")
    images, keypoints = _square_frames(16, seed=7)
    x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255
    with torch.no_grad():
        err = keypoint_error(net(x), torch.from_numpy(keypoints)).item()
    assert err < 0.5 * fit["zero_error"]
    assert "held-out keypoint error" in capsys.readouterr().out


def test_cli_names_a_missing_feature(tmp_path):
    _write_dataset(tmp_path / "squares", episodes=2, frames=5)
    with pytest.raises(SystemExit, match="has no 'observation.images.wrist'"):
        main(
            [
                "--repo-id",
                "local/squares",
                "--root",
                str(tmp_path / "squares"),
                "--out",
                str(tmp_path / "r"),
                "--image-key",
                "observation.images.wrist",
            ]
        )
    assert not (tmp_path / "r").exists()


def test_precomputed_estimates_are_what_the_pre_processor_step_writes(tmp_path):
    """dcdp-precompute-keypoints: the reader's estimate per frame as a column (cameras dropped on request),
    equal to what the ``dcdp_pixel_keypoints`` step computes from the same frames."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.precompute_keypoints import main as precompute
    from lerobot_dcdp.policy.processor_pixel_keypoints import PixelKeypointsProcessorStep

    _write_dataset(tmp_path / "squares", episodes=2, frames=6)
    reader = tmp_path / "reader"
    main(
        ["--repo-id", "local/squares", "--root", str(tmp_path / "squares"), "--out", str(reader)]
        + ["--steps", "3", "--val-episodes", "0"]
    )
    args = ["--reader", str(reader), "--repo-id", "local/squares", "--root", str(tmp_path / "squares")]
    out = tmp_path / "with_estimate"
    precompute(
        args
        + ["--out-repo-id", "local/sq_est", "--out-root", str(out), "--output-key", "observation.kp"]
        + ["--drop-cameras"]
    )
    copy, source = (
        LeRobotDataset("local/sq_est", root=out),
        LeRobotDataset("local/squares", root=tmp_path / "squares"),
    )
    assert "observation.image" not in copy.meta.features and copy.num_frames == 12
    step = PixelKeypointsProcessorStep.from_folder(reader, output_key="observation.kp")
    for i in (0, 7, 11):
        expected = step.observation({"observation.image": source[i]["observation.image"]})["observation.kp"]
        torch.testing.assert_close(copy[i]["observation.kp"], expected, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(
            copy[i]["observation.environment_state"], source[i]["observation.environment_state"]
        )
    with pytest.raises(SystemExit, match="already holds 'observation.environment_state'"):
        precompute(args + ["--out-repo-id", "local/x", "--out-root", str(tmp_path / "x")])
