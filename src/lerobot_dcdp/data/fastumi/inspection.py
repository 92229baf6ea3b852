"""Finding and validating FastUMI episodes before anything is converted: the episode files under a folder,
each file's layout, keys, shapes, dtypes, frame counts, finite poses, unit quaternions and readable first
and last images, that all episodes share one schema, and the dataset's frame rate."""

from __future__ import annotations

import logging
import math
import re
from pathlib import Path

try:
    import h5py
except ImportError as err:  # an optional dependency
    raise ImportError("the FastUMI tools need h5py: pip install 'lerobot_policy_dcdp[fastumi]'") from err
import numpy as np

from lerobot_dcdp.data.fastumi.hdf5 import get_dataset, open_episode, read_block, read_pose_array
from lerobot_dcdp.data.fastumi.spec import (
    ACTION_KEY,
    DEFAULT_FPS,
    FPS_ATTRS,
    IMAGES_KEY,
    LAYOUTS,
    QPOS_KEY,
    QUAT_TOLERANCE,
    CameraSpec,
    EpisodeSpec,
    FastUMIFormatError,
)

#: the logger these warnings have always gone to (they were in ``reader`` before the split)
logger = logging.getLogger("lerobot_dcdp.data.fastumi.reader")

_EPISODE_RE = re.compile(r"^episode_(\d+)\.(hdf5|h5)$")
_ARM_RE = re.compile(r"^robot_(\d+)$")


def find_episode_files(input_dir: str | Path) -> list[tuple[Path, str]]:
    """List the episode files under ``input_dir`` with their default task name.

    Accepted: ``<input_dir>/<task>/episode_<idx>.hdf5`` (task = folder name),
    ``<input_dir>/episode_<idx>.hdf5`` (task = name of ``input_dir``) and a single ``.hdf5`` file
    (task = its folder name). ``.h5`` works too.
    Episodes are ordered by task folder, then by numeric index.

    Args:
        input_dir: Root directory (or one episode file).

    Returns:
        ``(path, task)`` pairs.

    Raises:
        FastUMIFormatError: The path does not exist or holds no episode file.
    """
    root = Path(input_dir)
    if root.is_file():
        return [(root, root.resolve().parent.name)]
    if not root.is_dir():
        raise FastUMIFormatError(root, None, "input directory does not exist")
    task_name = root.resolve().name
    out = [(p, task_name) for p in _episodes_in(root)]
    for sub in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        out.extend((p, sub.name) for p in _episodes_in(sub))
    if not out:
        raise FastUMIFormatError(
            root, None, "no episode_<idx>.hdf5 files found (looked in the folder and its task sub-folders)"
        )
    return out


def _episodes_in(folder: Path) -> list[Path]:
    """The ``episode_<idx>`` files directly in ``folder`` by index (other HDF5 files: a warning each)."""
    found = []
    for p in folder.iterdir():
        if not p.is_file():
            continue
        if _EPISODE_RE.match(p.name):
            found.append(p)
        elif p.suffix in (".hdf5", ".h5"):
            logger.warning("Skipping %s: not named episode_<idx>.hdf5", p)
    return sorted(found, key=lambda p: int(_EPISODE_RE.match(p.name).group(1)))


def detect_layout(f: h5py.File, path: str | Path) -> tuple[str, tuple[str, ...]]:
    """Detect the layout of an open episode file.

    Args:
        f: Open HDF5 file.
        path: Its path (for error messages).

    Returns:
        ``(layout, arms)``: ``("fastumi_pro", ("robot_0", "robot_1", ...))`` when the root holds
        ``robot_<i>`` groups, otherwise ``("fastumi", ("",))`` for a ``(T, 7)`` qpos and
        ``("fastumi_pro", ("",))`` for ``(T, 8)``.
    """
    arms = sorted((k for k in f if _ARM_RE.match(k) and isinstance(f[k], h5py.Group)), key=_arm_index)
    if arms:
        return "fastumi_pro", tuple(arms)
    qpos = get_dataset(f, QPOS_KEY, path)
    if qpos.ndim != 2 or qpos.shape[1] not in (7, 8):
        raise FastUMIFormatError(
            path, QPOS_KEY, f"expected shape (T, 7) (FastUMI) or (T, 8) (FastUMI Pro), got {qpos.shape}"
        )
    return ("fastumi" if qpos.shape[1] == 7 else "fastumi_pro"), ("",)


def inspect_episode(
    path: str | Path, task: str, layout: str = "auto", quat_tol: float = QUAT_TOLERANCE
) -> EpisodeSpec:
    """Validate one episode file and describe it.

    Checks every key and shape, that images, qpos and action agree on ``T``, that poses are finite, that
    quaternions are unit (within ``quat_tol``) and that the first and last frame of every camera decode.

    Args:
        path: Episode file.
        task: Task string to attach.
        layout: ``"auto"`` (detect), ``"fastumi"`` (read 7 pose columns; an 8-column file loses its
            gripper column) or ``"fastumi_pro"`` (requires 8 columns).
        quat_tol: Allowed deviation of quaternion norms from 1.

    Returns:
        The episode description.

    Raises:
        FastUMIFormatError: On any problem, naming the file and key.
        ValueError: ``layout`` is not one of ``LAYOUTS``.
    """
    path = Path(path)
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    with open_episode(path) as f:
        layout, arms = _resolve_layout(f, path, layout)
        pose_dim = 7 if layout == "fastumi" else 8
        num_frames: int | None = None
        t_key = ""
        cameras: list[CameraSpec] = []
        for arm in arms:
            num_frames, t_key = _inspect_poses(f, path, arm, pose_dim, quat_tol, num_frames, t_key)
            cameras += _inspect_cameras(f, path, arm, num_frames, t_key)
        if not num_frames:
            raise FastUMIFormatError(path, t_key, "episode has no frames")
        fps = _read_fps(f, path)
    return EpisodeSpec(
        path=path,
        task=task,
        layout=layout,
        arms=arms,
        pose_dim=pose_dim,
        num_frames=num_frames,
        cameras=tuple(cameras),
        fps=fps,
    )


def _resolve_layout(f: h5py.File, path: Path, layout: str) -> tuple[str, tuple[str, ...]]:
    """The layout to read a file with (``auto``: the detected one) and its arms.

    Raises:
        FastUMIFormatError: ``fastumi`` asked for a dual-arm (FastUMI Pro) file.
    """
    detected, arms = detect_layout(f, path)
    if layout == "auto":
        return detected, arms
    if layout == "fastumi" and arms != ("",):
        raise FastUMIFormatError(
            path,
            arms[0],
            "dual-arm (robot_<i>/) files are FastUMI Pro files; use --layout fastumi_pro/auto",
        )
    return layout, arms


def _inspect_poses(
    f: h5py.File, path: Path, arm: str, pose_dim: int, quat_tol: float, num_frames: int | None, t_key: str
) -> tuple[int, str]:
    """Check an arm's qpos and action arrays and that their frame count is the episode's.

    Args:
        f: Open episode file.
        path: Its path (for error messages).
        arm: The arm's group (``""`` for a single arm).
        pose_dim: Columns read per array.
        quat_tol: Allowed deviation of quaternion norms from 1.
        num_frames: The episode's frame count so far, or ``None`` before the first array.
        t_key: The key ``num_frames`` was read from.

    Returns:
        ``(num_frames, t_key)``: the first array's when none was known yet, else the ones given.

    Raises:
        FastUMIFormatError: A bad array, a frame count mismatch, a non-finite pose or a non-unit quaternion.
    """
    prefix = f"{arm}/" if arm else ""
    for key in (prefix + QPOS_KEY, prefix + ACTION_KEY):
        arr = read_pose_array(f, key, path, pose_dim)
        if num_frames is None:
            num_frames, t_key = arr.shape[0], key
        elif arr.shape[0] != num_frames:
            raise FastUMIFormatError(
                path, key, f"has {arr.shape[0]} frames but {t_key} has {num_frames} (T mismatch)"
            )
        _check_pose_values(arr, key, path, quat_tol)
    return num_frames, t_key


def _inspect_cameras(f: h5py.File, path: Path, arm: str, num_frames: int, t_key: str) -> list[CameraSpec]:
    """Check an arm's camera datasets (in name order) and describe them.

    Args:
        f: Open episode file.
        path: Its path (for error messages).
        arm: The arm's group (``""`` for a single arm); a dual-arm camera is named ``<arm>_<cam>``.
        num_frames: The episode's frame count.
        t_key: The key ``num_frames`` was read from (for error messages).

    Returns:
        One spec per camera.

    Raises:
        FastUMIFormatError: No image group or camera, a bad image dataset, or an unreadable first/last frame.
    """
    img_key = (f"{arm}/" if arm else "") + IMAGES_KEY
    group = f.get(img_key)
    if not isinstance(group, h5py.Group):
        raise FastUMIFormatError(path, img_key, "missing image group")
    if len(group) == 0:
        raise FastUMIFormatError(path, img_key, "image group holds no camera")
    cameras = []
    for cam in sorted(group):
        key = f"{img_key}/{cam}"
        ds = group[cam]
        _check_camera(ds, path, key, num_frames, t_key)
        name = f"{arm}_{cam}" if arm else cam
        cameras.append(CameraSpec(name=name, key=key, height=int(ds.shape[1]), width=int(ds.shape[2])))
    return cameras


def _check_camera(ds: h5py.Dataset | h5py.Group, path: Path, key: str, num_frames: int, t_key: str) -> None:
    """Check one camera: a ``(T, H, W, 3)`` uint8 dataset of the episode's ``T`` whose first and last frame
    can be read."""
    if not isinstance(ds, h5py.Dataset) or ds.ndim != 4 or ds.shape[-1] != 3:
        shape = ds.shape if isinstance(ds, h5py.Dataset) else "a group"
        raise FastUMIFormatError(path, key, f"expected a (T, H, W, 3) image dataset, got {shape}")
    if ds.dtype != np.uint8:
        raise FastUMIFormatError(path, key, f"expected uint8 images, got {ds.dtype}")
    if ds.shape[0] != num_frames:
        raise FastUMIFormatError(
            path, key, f"has {ds.shape[0]} frames but {t_key} has {num_frames} (T mismatch)"
        )
    if num_frames > 0:
        for idx in {0, num_frames - 1}:
            read_block(ds, idx, idx + 1, path, key)


def inspect_dataset(
    input_dir: str | Path, layout: str = "auto", task: str | None = None, quat_tol: float = QUAT_TOLERANCE
) -> list[EpisodeSpec]:
    """Validate every episode under ``input_dir`` and check they can share one dataset.

    Episodes must agree on layout, arms, pose columns, camera names and per-camera image size.

    Args:
        input_dir: Root directory (see :func:`find_episode_files`).
        layout: ``"auto"``, ``"fastumi"`` or ``"fastumi_pro"``.
        task: Task string for all episodes; ``None`` uses each episode's task folder name.
        quat_tol: Allowed deviation of quaternion norms from 1.

    Returns:
        One spec per episode, in conversion order.

    Raises:
        FastUMIFormatError: On the first problem found.
    """
    specs: list[EpisodeSpec] = []
    for path, folder_task in find_episode_files(input_dir):
        spec = inspect_episode(path, task if task is not None else folder_task, layout, quat_tol)
        if specs:
            _check_same_schema(specs[0], spec)
        specs.append(spec)
    return specs


def resolve_fps(specs: list[EpisodeSpec], fps: float | None = None) -> int:
    """Pick the dataset rate: ``fps`` if given, else the files' rate (all must agree), else 20 Hz.

    Args:
        specs: Validated episodes.
        fps: Explicit override.

    Returns:
        Integer frames per second.

    Raises:
        FastUMIFormatError: The files disagree or store a non-integer rate.
    """
    if fps is not None:
        value, source, key = float(fps), None, None
    else:
        value, source, key = float(DEFAULT_FPS), None, None
        for spec in specs:
            if spec.fps is None:
                continue
            if source is None:
                value, source = spec.fps, spec
                key = "attrs"
            elif not math.isclose(spec.fps, value):
                raise FastUMIFormatError(
                    spec.path,
                    "attrs",
                    f"fps {spec.fps:g} differs from {value:g} in {source.path}; pass --fps",
                )
    rounded = round(value)
    if rounded <= 0 or not math.isclose(value, rounded, abs_tol=1e-6):
        where = source.path if source is not None else "--fps"
        raise FastUMIFormatError(where, key, f"fps must be a positive integer, got {value:g}; pass --fps")
    return int(rounded)


def _arm_index(name: str) -> int:
    """``i`` of a ``robot_<i>`` group name."""
    return int(_ARM_RE.match(name).group(1))


def _check_pose_values(arr: np.ndarray, key: str, path: Path, quat_tol: float) -> None:
    """Check that every pose is finite and every quaternion (columns 3:7) has norm 1 within ``quat_tol``."""
    bad = ~np.isfinite(arr)
    if bad.any():
        t, c = np.argwhere(bad)[0]
        raise FastUMIFormatError(path, key, f"non-finite value {arr[t, c]} at frame {t}, column {c}")
    norms = np.linalg.norm(arr[:, 3:7].astype(np.float64), axis=1)
    off = np.abs(norms - 1.0) > quat_tol
    if off.any():
        t = int(np.argmax(off))
        raise FastUMIFormatError(
            path,
            key,
            f"quaternion (columns 3:7) at frame {t} has norm {norms[t]:.6f}, not 1 (tol {quat_tol:g})",
        )


def _read_fps(f: h5py.File, path: Path) -> float | None:
    """The rate in the first of ``FPS_ATTRS`` the file's root has, or ``None`` when it has none.

    Raises:
        FastUMIFormatError: The attribute is not a positive finite number.
    """
    for name in FPS_ATTRS:
        if name in f.attrs:
            raw = f.attrs[name]
            try:
                value = float(np.asarray(raw).reshape(-1)[0])
            except (TypeError, ValueError, IndexError) as exc:
                raise FastUMIFormatError(path, f"attrs/{name}", f"not a number: {raw!r}") from exc
            if not math.isfinite(value) or value <= 0:
                raise FastUMIFormatError(path, f"attrs/{name}", f"invalid frame rate {value}")
            return value
    return None


def _check_same_schema(ref: EpisodeSpec, spec: EpisodeSpec) -> None:
    """Check that ``spec`` has ``ref``'s layout, arms, pose columns, camera names and image sizes."""
    if (spec.layout, spec.arms, spec.pose_dim) != (ref.layout, ref.arms, ref.pose_dim):
        raise FastUMIFormatError(
            spec.path,
            None,
            f"layout {spec.layout} arms={list(spec.arms)} with {spec.pose_dim} columns differs from "
            f"{ref.path} ({ref.layout} arms={list(ref.arms)} with {ref.pose_dim} columns)",
        )
    ref_cams = {c.name: c for c in ref.cameras}
    names = [c.name for c in spec.cameras]
    if names != list(ref_cams):
        raise FastUMIFormatError(
            spec.path, IMAGES_KEY, f"cameras {names} differ from {list(ref_cams)} in {ref.path}"
        )
    for cam in spec.cameras:
        other = ref_cams[cam.name]
        if (cam.height, cam.width) != (other.height, other.width):
            raise FastUMIFormatError(
                spec.path,
                cam.key,
                f"image size {cam.width}x{cam.height} differs from {other.width}x{other.height} in "
                f"{ref.path} (mixed image sizes)",
            )
