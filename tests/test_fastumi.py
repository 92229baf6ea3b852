"""FastUMI / FastUMI Pro HDF5 -> LeRobotDataset v3 conversion (tiny synthetic episodes, CPU, offline)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from lerobot_dcdp.data.fastumi import convert as convert_mod
from lerobot_dcdp.data.fastumi.convert import compose_pose, convert_fastumi, main, relative_pose
from lerobot_dcdp.data.fastumi.reader import (
    FastUMIFormatError,
    find_episode_files,
    inspect_dataset,
    inspect_episode,
    iter_frames,
)

H, W = 24, 32  # source frames (height, width)
SIZE = 32  # stored frames (smallest size the default AV1 encoder accepts)
BGR_A = (30, 60, 200)  # OpenCV order; stored RGB must be (200, 60, 30)
BGR_B = (200, 120, 20)
COLOUR_TOL = 0.08  # lossy AV1 on a uniform frame


# ------------------------------------------------------------------------------------------------ builders


def quat_z(theta: np.ndarray) -> np.ndarray:
    zeros = np.zeros_like(theta)
    return np.stack([zeros, zeros, np.sin(theta / 2), np.cos(theta / 2)], axis=-1)


def make_poses(num: int, gripper: bool = False, offset: float = 0.0) -> np.ndarray:
    theta = np.linspace(0.0, 0.6, num) + offset
    pos = np.stack(
        [np.linspace(0.0, 0.1, num) + offset, np.full(num, 0.2), 0.3 + 0.01 * np.arange(num) ** 2], axis=-1
    )
    poses = np.concatenate([pos, quat_z(theta)], axis=1)
    if gripper:
        poses = np.concatenate([poses, np.linspace(0.08, 0.02, num)[:, None]], axis=1)
    return poses


def write_arm(group: h5py.Group, num: int, cols: int, cams: dict[str, tuple], offset: float = 0.0) -> None:
    poses = make_poses(num, gripper=cols == 8, offset=offset)
    group.create_dataset("observations/qpos", data=poses)
    group.create_dataset("action", data=poses)
    for cam, (bgr, h, w) in cams.items():
        frames = np.empty((num, h, w, 3), np.uint8)
        frames[:] = np.array(bgr, np.uint8)
        group.create_dataset(
            f"observations/images/{cam}", data=frames, compression="gzip", chunks=(1, h, w, 3)
        )


def write_episode(
    path: Path,
    num: int = 5,
    cols: int = 7,
    cams: dict[str, tuple] | None = None,
    dual: bool = False,
    attrs: dict | None = None,
) -> Path:
    """One synthetic episode; ``cams`` maps camera -> (bgr, height, width)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    cams = cams if cams is not None else {"front": (BGR_A, H, W)}
    with h5py.File(path, "w") as f:
        f.attrs["sim"] = False
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
        if dual:
            write_arm(f.create_group("robot_0"), num, cols, cams, offset=0.0)
            other = {c: (BGR_B, h, w) for c, (_, h, w) in cams.items()}
            write_arm(f.create_group("robot_1"), num, cols, other, offset=1.0)
        else:
            write_arm(f, num, cols, cams)
    return path


def frame_rgb(item: dict, key: str) -> np.ndarray:
    return item[key].numpy().mean(axis=(1, 2))  # (3,) in [0, 1], channel-first tensor


def assert_nothing_left(parent: Path, before: set[Path]) -> None:
    assert set(parent.iterdir()) == before, f"left on disk: {set(parent.iterdir()) - before}"


def load(repo_id: str, root: Path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(repo_id, root=root)


# ---------------------------------------------------------------------------------------------- conversion


def test_fastumi_single_arm_absolute(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    src = tmp_path / "in"
    write_episode(src / "pick_cup" / "episode_0.hdf5", num=5)
    write_episode(src / "pick_cup" / "episode_1.hdf5", num=4)
    out = tmp_path / "ds"
    assert (
        main(["--input", str(src), "--repo-id", "local/fu", "--root", str(out), "--image-size", str(SIZE)])
        == 0
    )
    assert "Wrote 2 episode(s), 9 frames at 20 fps" in capsys.readouterr().out

    ds = load("local/fu", out)
    assert (len(ds), ds.meta.total_episodes, ds.fps) == (9, 2, 20)
    feats = ds.meta.features
    assert feats["observation.state"]["names"] == ["x", "y", "z", "qx", "qy", "qz", "qw"]
    assert feats["action"]["info"]["representation"] == "absolute_tcp_pose"
    assert feats["observation.images.front"]["shape"] == (SIZE, SIZE, 3)
    assert ds.meta.robot_type == "fastumi"
    expected = np.concatenate([make_poses(5), make_poses(4)])
    for i in range(len(ds)):
        item = ds[i]
        np.testing.assert_allclose(item["observation.state"].numpy(), expected[i], atol=1e-6)
        np.testing.assert_allclose(item["action"].numpy(), expected[i], atol=1e-6)
        assert item["task"] == "pick_cup"
        assert item["observation.images.front"].shape == (3, SIZE, SIZE)
        np.testing.assert_allclose(
            frame_rgb(item, "observation.images.front"), np.array(BGR_A[::-1]) / 255, atol=COLOUR_TOL
        )
    assert not (out / "images").exists()

    # An existing output is refused without --force, replaced with it.
    with pytest.raises(FileExistsError, match="--force"):
        convert_fastumi(src, "local/fu", out, image_size=SIZE)
    before = set(tmp_path.iterdir())
    summary = convert_fastumi(src, "local/fu", out, image_size=SIZE, task="grasp", force=True)
    assert summary["tasks"] == ["grasp"] and summary["frames"] == 9
    assert load("local/fu", out)[0]["task"] == "grasp"
    assert_nothing_left(tmp_path, before)


def test_fastumi_pro_delta_actions(tmp_path: Path) -> None:
    src = tmp_path / "fold"
    num = 6
    write_episode(src / "episode_0.hdf5", num=num, cols=8)
    out = tmp_path / "ds"
    summary = convert_fastumi(src, "local/fp", out, image_size=SIZE, action="delta")
    assert summary["layout"] == "fastumi_pro" and summary["tasks"] == ["fold"]

    ds = load("local/fp", out)
    assert ds.meta.features["action"]["names"] == ["dx", "dy", "dz", "dqx", "dqy", "dqz", "dqw", "gripper"]
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["features"]["action"]["info"]["representation"] == "relative_tcp_pose"
    assert "TCP frame" in info["features"]["action"]["info"]["description"]
    assert info["features"]["observation.state"]["names"][-1] == "gripper"

    poses = make_poses(num, gripper=True)
    theta = np.linspace(0.0, 0.6, num)
    actions = np.stack([ds[i]["action"].numpy() for i in range(num)])
    states = np.stack([ds[i]["observation.state"].numpy() for i in range(num)])
    np.testing.assert_allclose(states, poses, atol=1e-6)
    for t in range(num - 1):  # independent check with a z-rotation matrix
        c, s = np.cos(theta[t]), np.sin(theta[t])
        rot_t = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        np.testing.assert_allclose(actions[t, :3], rot_t.T @ (poses[t + 1, :3] - poses[t, :3]), atol=1e-6)
        np.testing.assert_allclose(actions[t, 3:7], quat_z(np.array(theta[t + 1] - theta[t])), atol=1e-6)
        assert actions[t, 7] == pytest.approx(poses[t + 1, 7])
    np.testing.assert_allclose(actions[-1], [0, 0, 0, 0, 0, 0, 1, poses[-1, 7]], atol=1e-7)


def test_fastumi_pro_dual_arm(tmp_path: Path) -> None:
    src = tmp_path / "handover"
    cams = {"front": (BGR_A, H, W), "wrist": (BGR_A, 20, 20)}
    for i in (0, 1):
        write_episode(src / f"episode_{i}.hdf5", num=3, cols=8, cams=cams, dual=True, attrs={"fps": 10})
    out = tmp_path / "ds"
    summary = convert_fastumi(src, "local/dual", out, image_size=SIZE, action="delta")
    assert summary["fps"] == 10 and summary["robot_type"] == "fastumi_pro_bimanual"
    assert summary["cameras"] == [
        "observation.images.robot_0_front",
        "observation.images.robot_0_wrist",
        "observation.images.robot_1_front",
        "observation.images.robot_1_wrist",
    ]
    ds = load("local/dual", out)
    assert (len(ds), ds.fps) == (6, 10)
    names = ds.meta.features["observation.state"]["names"]
    assert names[:2] == ["robot_0_x", "robot_0_y"] and names[8] == "robot_1_x" and len(names) == 16
    assert ds.meta.features["action"]["names"][8:10] == ["robot_1_dx", "robot_1_dy"]
    last = ds[2]["action"].numpy()  # last frame of episode 0: identity per arm, absolute gripper
    g0, g1 = make_poses(3, True)[-1, 7], make_poses(3, True, offset=1.0)[-1, 7]
    np.testing.assert_allclose(last, [0, 0, 0, 0, 0, 0, 1, g0, 0, 0, 0, 0, 0, 0, 1, g1], atol=1e-7)
    item = ds[4]
    expected = np.concatenate([make_poses(3, True)[1], make_poses(3, True, offset=1.0)[1]])
    np.testing.assert_allclose(item["observation.state"].numpy(), expected, atol=1e-6)
    np.testing.assert_allclose(
        frame_rgb(item, "observation.images.robot_0_wrist"), np.array(BGR_A[::-1]) / 255, atol=COLOUR_TOL
    )
    np.testing.assert_allclose(
        frame_rgb(item, "observation.images.robot_1_front"), np.array(BGR_B[::-1]) / 255, atol=COLOUR_TOL
    )


# -------------------------------------------------------------------------------------------------- reader


def test_streaming_reader_chunked_order_and_layouts(tmp_path: Path) -> None:
    path = tmp_path / "t" / "episode_0.hdf5"
    write_episode(path, num=7, cols=8)
    with h5py.File(path, "a") as f:  # 3-frame chunks: blocks must stay in order, last block partial
        del f["observations/images/front"]
        frames = np.zeros((7, 4, 6, 3), np.uint8)
        frames[..., 0] = (np.arange(7) * 30)[:, None, None]  # blue channel (BGR) = 30 t
        f.create_dataset("observations/images/front", data=frames, compression="gzip", chunks=(3, 4, 6, 3))
    spec = inspect_episode(path, "t")
    assert (spec.layout, spec.pose_dim, spec.num_frames) == ("fastumi_pro", 8, 7)
    got = [fr["front"] for fr in iter_frames(spec)]
    assert len(got) == 7 and all(g.shape == (4, 6, 3) for g in got)
    assert [int(g[0, 0, 2]) for g in got] == [30 * t for t in range(7)]  # RGB: blue is last
    assert all(int(g[..., :2].max()) == 0 for g in got)

    assert inspect_episode(path, "t", layout="fastumi").pose_dim == 7  # override drops the gripper
    seven = write_episode(tmp_path / "u" / "episode_0.hdf5", cols=7)
    with pytest.raises(FastUMIFormatError, match=r"observations/qpos.*\(T, 8\)"):
        inspect_episode(seven, "u", layout="fastumi_pro")

    for i in (10, 2, 1):
        write_episode(tmp_path / "order" / f"episode_{i}.hdf5", num=2)
    assert [p.name for p, _ in find_episode_files(tmp_path / "order")] == [
        "episode_1.hdf5",
        "episode_2.hdf5",
        "episode_10.hdf5",
    ]


def test_relative_pose_round_trip() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 2, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    cur = np.concatenate([rng.normal(size=(50, 3)), q[:, 0]], axis=1)
    nxt = np.concatenate([rng.normal(size=(50, 3)), q[:, 1]], axis=1)
    rel = relative_pose(cur, nxt)
    assert (rel[:, 6] >= 0).all()
    back = compose_pose(cur, rel)
    np.testing.assert_allclose(back[:, :3], nxt[:, :3], atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(back[:, 3:] * nxt[:, 3:], axis=1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(relative_pose(cur, cur), np.tile([0, 0, 0, 0, 0, 0, 1.0], (50, 1)), atol=1e-9)


# -------------------------------------------------------------------------------------------------- errors


def _drop(key: str):
    def edit(f: h5py.File) -> None:
        del f[key]

    return edit


def _replace(key: str, fn):
    def edit(f: h5py.File) -> None:
        data = fn(f[key][()])
        del f[key]
        f.create_dataset(key, data=data)

    return edit


def _set(key: str, index: tuple, value: float):
    def edit(f: h5py.File) -> None:
        f[key][index] = value

    return edit


BAD_EDITS = {
    "missing image group": (_drop("observations/images"), "observations/images", "missing image group"),
    "missing action": (_drop("action"), "action", "missing key"),
    "image T mismatch": (
        _replace("observations/images/front", lambda a: np.concatenate([a, a[:1]])),
        "observations/images/front",
        "T mismatch",
    ),
    "action T mismatch": (_replace("action", lambda a: a[:-1]), "action", "T mismatch"),
    "qpos NaN": (_set("observations/qpos", (2, 0), np.nan), "observations/qpos", "non-finite"),
    "non-unit quaternion": (_set("action", (1, 6), 2.0), "action", "norm"),
    "bad qpos columns": (_replace("observations/qpos", lambda a: a[:, :6]), "observations/qpos", "(T, 7)"),
}


@pytest.mark.parametrize("case", list(BAD_EDITS))
def test_bad_key_errors_leave_nothing(tmp_path: Path, case: str) -> None:
    edit, key, message = BAD_EDITS[case]
    src = tmp_path / "in"
    write_episode(src / "task" / "episode_0.hdf5")
    bad = write_episode(src / "task" / "episode_1.hdf5")
    with h5py.File(bad, "a") as f:
        edit(f)
    before = set(tmp_path.iterdir())
    with pytest.raises(FastUMIFormatError, match=message) as info:
        convert_fastumi(src, "local/bad", tmp_path / "out" / "ds", image_size=SIZE)
    assert info.value.path == bad and info.value.key == key
    assert "episode_1.hdf5" in str(info.value) and key in str(info.value)
    assert_nothing_left(tmp_path, before)


def test_bad_file_errors(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    src = tmp_path / "in"
    good = write_episode(src / "task" / "episode_0.hdf5")
    trunc = src / "task" / "episode_1.hdf5"
    trunc.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(FastUMIFormatError, match="truncated or corrupt") as info:
        inspect_dataset(src)
    assert info.value.path == trunc

    trunc.write_text("not hdf5 at all")
    with pytest.raises(FastUMIFormatError, match="not an HDF5 file"):
        inspect_dataset(src)

    write_episode(trunc, cams={"front": (BGR_A, H + 2, W)})
    with pytest.raises(FastUMIFormatError, match="mixed image sizes") as info:
        inspect_dataset(src)
    assert info.value.key == "observations/images/front"

    write_episode(trunc, cols=8)
    with pytest.raises(FastUMIFormatError, match="differs from"):
        inspect_dataset(src)

    empty = tmp_path / "empty"
    empty.mkdir()
    before = set(tmp_path.iterdir())
    out = tmp_path / "never"
    assert main(["--input", str(empty), "--repo-id", "local/e", "--root", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "no episode_<idx>.hdf5" in err and str(empty) in err
    assert len(err.splitlines()) == 1
    assert_nothing_left(tmp_path, before)


@pytest.mark.parametrize("exc", [RuntimeError("disk on fire"), KeyboardInterrupt()])
def test_failure_mid_conversion_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, exc: BaseException
) -> None:
    src = tmp_path / "in"
    for i in range(2):
        write_episode(src / "task" / f"episode_{i}.hdf5", num=4)
    real = convert_mod.iter_frames
    calls = {"n": 0}

    def flaky(spec, image_size=None):
        calls["n"] += 1
        for t, frame in enumerate(real(spec, image_size)):
            if calls["n"] == 2 and t == 2:  # second episode, after the first one was saved
                raise exc
            yield frame

    monkeypatch.setattr(convert_mod, "iter_frames", flaky)
    before = set(tmp_path.iterdir())
    with pytest.raises(type(exc)):
        convert_fastumi(src, "local/x", tmp_path / "new" / "nested" / "ds", image_size=SIZE)
    assert calls["n"] == 2
    assert_nothing_left(tmp_path, before)
