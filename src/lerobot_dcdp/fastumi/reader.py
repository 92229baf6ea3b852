"""Layout detection, validation and streaming readers for FastUMI / FastUMI Pro HDF5 episodes.

Two on-disk layouts are understood (one ``episode_<idx>.hdf5`` file per episode):

``fastumi`` (original FastUMI release)::

    observations/images/<cam>   (T, H, W, 3) uint8, OpenCV (BGR) frames, usually gzip-compressed
    observations/qpos           (T, 7)  TCP pose [x, y, z, qx, qy, qz, qw]
    action                      (T, 7)  same layout (identical to qpos in the released data)

``fastumi_pro`` (FastUMI Pro processed episodes)::

    observations/images/<cam>   (T, H, W, 3) uint8 BGR
    observations/qpos           (T, 8)  [x, y, z, qx, qy, qz, qw, gripper]
    action                      (T, 8)

    or, for dual-arm recordings, the same tree once per arm:
    robot_0/observations/{qpos, images/<cam>}, robot_0/action      (robot_0 = left arm)
    robot_1/observations/{qpos, images/<cam>}, robot_1/action      (robot_1 = right arm)

Dual-arm episodes are read as one robot: state/action are the arms' vectors concatenated in arm order
(``robot_0`` first) and every camera is exposed as ``<arm>_<cam>`` (e.g. ``robot_0_front``).

Everything cheap is validated up front by :func:`inspect_episode` (keys, shapes, dtypes, frame counts,
finite poses, unit quaternions, readable first/last image). Images are only ever read in blocks of one
HDF5 chunk by :func:`iter_frames`, so memory stays bounded by one chunk per camera however long the
episode is. Every problem is reported as a :class:`FastUMIFormatError` naming the file and the key.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2

try:
    import h5py
except ImportError as err:  # an optional dependency
    raise ImportError("the FastUMI tools need h5py: pip install 'lerobot_policy_dcdp[fastumi]'") from err
import numpy as np

logger = logging.getLogger(__name__)

Layout = Literal["fastumi", "fastumi_pro"]
LAYOUTS: tuple[str, ...] = ("auto", "fastumi", "fastumi_pro")

DEFAULT_FPS = 20
QUAT_TOLERANCE = 1e-3
POSE_NAMES: tuple[str, ...] = ("x", "y", "z", "qx", "qy", "qz", "qw")
GRIPPER_NAME = "gripper"
# Root attributes that may carry the recording rate (first one found wins).
FPS_ATTRS: tuple[str, ...] = ("fps", "frequency", "freq", "frame_rate", "control_freq")

_EPISODE_RE = re.compile(r"^episode_(\d+)\.(hdf5|h5)$")
_ARM_RE = re.compile(r"^robot_(\d+)$")
_QPOS = "observations/qpos"
_ACTION = "action"
_IMAGES = "observations/images"


class FastUMIFormatError(ValueError):
    """A FastUMI input file or directory does not have the expected format.

    Attributes:
        path: The offending file (or directory).
        key: The HDF5 key involved, or ``None`` for file-level problems.
        problem: Human readable description.
    """

    def __init__(self, path: str | Path, key: str | None, problem: str):
        self.path = Path(path)
        self.key = key
        self.problem = problem
        where = f"{self.path}" if key is None else f"{self.path} [{key}]"
        super().__init__(f"{where}: {problem}")


@dataclass(frozen=True)
class CameraSpec:
    """One camera stream of an episode.

    Attributes:
        name: Camera name used in the dataset (``observation.images.<name>``).
        key: Full HDF5 path of the ``(T, H, W, 3)`` dataset.
        height: Source frame height in pixels.
        width: Source frame width in pixels.
    """

    name: str
    key: str
    height: int
    width: int


@dataclass(frozen=True)
class EpisodeSpec:
    """Validated description of one episode file (no bulk data is held).

    Attributes:
        path: The HDF5 file.
        task: Task string for every frame of the episode.
        layout: ``"fastumi"`` or ``"fastumi_pro"``.
        arms: HDF5 group prefix of each arm: ``("",)`` for single-arm, ``("robot_0", "robot_1")`` for dual.
        pose_dim: Columns read per arm: 7 (pose) or 8 (pose + gripper).
        num_frames: Number of frames ``T``.
        cameras: Camera streams, in a stable order.
        fps: Rate stored in the file's root attributes, or ``None`` when the file does not say.
    """

    path: Path
    task: str
    layout: str
    arms: tuple[str, ...]
    pose_dim: int
    num_frames: int
    cameras: tuple[CameraSpec, ...]
    fps: float | None

    @property
    def dual_arm(self) -> bool:
        """Whether the episode has one sub-tree per arm."""
        return self.arms != ("",)

    @property
    def vector_names(self) -> list[str]:
        """Per-dimension names of the absolute state/action vector (arm-prefixed for dual-arm)."""
        base = list(POSE_NAMES) + ([GRIPPER_NAME] if self.pose_dim == 8 else [])
        if not self.dual_arm:
            return base
        return [f"{arm}_{n}" for arm in self.arms for n in base]


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

    def episodes_in(folder: Path) -> list[Path]:
        found = []
        for p in folder.iterdir():
            if not p.is_file():
                continue
            if _EPISODE_RE.match(p.name):
                found.append(p)
            elif p.suffix in (".hdf5", ".h5"):
                logger.warning("Skipping %s: not named episode_<idx>.hdf5", p)
        return sorted(found, key=lambda p: int(_EPISODE_RE.match(p.name).group(1)))

    task_name = root.resolve().name
    out = [(p, task_name) for p in episodes_in(root)]
    for sub in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        out.extend((p, sub.name) for p in episodes_in(sub))
    if not out:
        raise FastUMIFormatError(
            root, None, "no episode_<idx>.hdf5 files found (looked in the folder and its task sub-folders)"
        )
    return out


def open_episode(path: str | Path) -> h5py.File:
    """Open an episode file read-only, turning every failure into a :class:`FastUMIFormatError`.

    Args:
        path: HDF5 file.

    Returns:
        The open file (caller closes it).
    """
    path = Path(path)
    try:
        if not h5py.is_hdf5(path):
            raise FastUMIFormatError(path, None, "not an HDF5 file")
        return h5py.File(path, "r")
    except FastUMIFormatError:
        raise
    except (OSError, ValueError) as exc:
        raise FastUMIFormatError(path, None, f"cannot open HDF5 file (truncated or corrupt?): {exc}") from exc


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
    qpos = _get_dataset(f, _QPOS, path)
    if qpos.ndim != 2 or qpos.shape[1] not in (7, 8):
        raise FastUMIFormatError(
            path, _QPOS, f"expected shape (T, 7) (FastUMI) or (T, 8) (FastUMI Pro), got {qpos.shape}"
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
    """
    path = Path(path)
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    with open_episode(path) as f:
        detected, arms = detect_layout(f, path)
        if layout == "auto":
            layout = detected
        elif layout == "fastumi" and arms != ("",):
            raise FastUMIFormatError(
                path,
                arms[0],
                "dual-arm (robot_<i>/) files are FastUMI Pro files; use --layout fastumi_pro/auto",
            )
        pose_dim = 7 if layout == "fastumi" else 8

        num_frames: int | None = None
        t_key = ""
        cameras: list[CameraSpec] = []
        for arm in arms:
            prefix = f"{arm}/" if arm else ""
            for key in (prefix + _QPOS, prefix + _ACTION):
                arr = _read_pose_array(f, key, path, pose_dim)
                if num_frames is None:
                    num_frames, t_key = arr.shape[0], key
                elif arr.shape[0] != num_frames:
                    raise FastUMIFormatError(
                        path, key, f"has {arr.shape[0]} frames but {t_key} has {num_frames} (T mismatch)"
                    )
                _check_pose_values(arr, key, path, quat_tol)
            img_key = prefix + _IMAGES
            group = f.get(img_key)
            if not isinstance(group, h5py.Group):
                raise FastUMIFormatError(path, img_key, "missing image group")
            if len(group) == 0:
                raise FastUMIFormatError(path, img_key, "image group holds no camera")
            for cam in sorted(group):
                key = f"{img_key}/{cam}"
                ds = group[cam]
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
                        _read_block(ds, idx, idx + 1, path, key)
                name = f"{arm}_{cam}" if arm else cam
                cameras.append(
                    CameraSpec(name=name, key=key, height=int(ds.shape[1]), width=int(ds.shape[2]))
                )
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


def read_vectors(spec: EpisodeSpec) -> tuple[np.ndarray, np.ndarray]:
    """Read the (small) pose arrays of an episode.

    Args:
        spec: Validated episode.

    Returns:
        ``(state, action)``, each ``(T, pose_dim * n_arms)`` float32 with arms concatenated in order.
    """
    with open_episode(spec.path) as f:
        states, actions = [], []
        for arm in spec.arms:
            prefix = f"{arm}/" if arm else ""
            states.append(_read_pose_array(f, prefix + _QPOS, spec.path, spec.pose_dim))
            actions.append(_read_pose_array(f, prefix + _ACTION, spec.path, spec.pose_dim))
    return np.concatenate(states, axis=1), np.concatenate(actions, axis=1)


def iter_frames(spec: EpisodeSpec, image_size: int | None = None) -> Iterator[dict[str, np.ndarray]]:
    """Stream the camera frames of an episode, converted to RGB (and resized).

    Each camera is read in blocks of one HDF5 chunk along ``T`` (one frame for contiguous datasets)
    into a reused buffer, so every chunk is decompressed exactly once and memory stays bounded.

    Args:
        spec: Validated episode.
        image_size: Output side length (square, aspect ratio not kept, ``cv2.INTER_AREA``); ``None``
            keeps the source size.

    Yields:
        ``{camera name: (S, S, 3) uint8 RGB}`` for every frame, in order. The arrays are fresh copies.

    Raises:
        FastUMIFormatError: A block cannot be read (e.g. corrupt chunk).
    """
    with open_episode(spec.path) as f:
        streams = [_iter_camera(f[cam.key], spec.path, cam.key) for cam in spec.cameras]
        for _ in range(spec.num_frames):
            yield {
                cam.name: bgr_to_rgb_resized(next(stream), image_size)
                for cam, stream in zip(spec.cameras, streams, strict=True)
            }


def bgr_to_rgb_resized(frame: np.ndarray, image_size: int | None) -> np.ndarray:
    """Resize an OpenCV BGR frame to ``image_size`` x ``image_size`` and flip it to RGB.

    Args:
        frame: ``(H, W, 3)`` uint8 BGR.
        image_size: Target side, or ``None`` to keep the size.

    Returns:
        A new contiguous ``(S, S, 3)`` uint8 RGB array.
    """
    if image_size is not None and frame.shape[:2] != (image_size, image_size):
        frame = cv2.resize(frame, (image_size, image_size), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(frame[..., ::-1])


# ---------------------------------------------------------------------------------------------------------


def _arm_index(name: str) -> int:
    return int(_ARM_RE.match(name).group(1))


def _get_dataset(f: h5py.File, key: str, path: Path) -> h5py.Dataset:
    obj = f.get(key)
    if obj is None:
        raise FastUMIFormatError(path, key, "missing key")
    if not isinstance(obj, h5py.Dataset):
        raise FastUMIFormatError(path, key, "expected a dataset, found a group")
    return obj


def _read_pose_array(f: h5py.File, key: str, path: Path, pose_dim: int) -> np.ndarray:
    ds = _get_dataset(f, key, path)
    if ds.ndim != 2 or ds.shape[1] not in (7, 8):
        raise FastUMIFormatError(path, key, f"expected shape (T, 7) or (T, 8), got {ds.shape}")
    if ds.shape[1] < pose_dim:
        raise FastUMIFormatError(
            path, key, f"layout fastumi_pro needs (T, 8) pose + gripper, got {ds.shape}; use --layout fastumi"
        )
    if not np.issubdtype(ds.dtype, np.number):
        raise FastUMIFormatError(path, key, f"expected numbers, got dtype {ds.dtype}")
    try:
        arr = ds[:, :pose_dim]
    except (OSError, RuntimeError, ValueError) as exc:
        raise FastUMIFormatError(path, key, f"cannot read data (truncated or corrupt?): {exc}") from exc
    return arr.astype(np.float32, copy=False)


def _check_pose_values(arr: np.ndarray, key: str, path: Path, quat_tol: float) -> None:
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


def _read_block(ds: h5py.Dataset, start: int, stop: int, path: Path, key: str, out: np.ndarray | None = None):
    try:
        if out is None:
            return ds[start:stop]
        ds.read_direct(out, np.s_[start:stop], np.s_[0 : stop - start])
        return out
    except (OSError, RuntimeError, ValueError) as exc:
        raise FastUMIFormatError(
            path, key, f"cannot read frames {start}..{stop - 1} (truncated or corrupt?): {exc}"
        ) from exc


def _iter_camera(ds: h5py.Dataset, path: Path, key: str) -> Iterator[np.ndarray]:
    num = ds.shape[0]
    step = int(ds.chunks[0]) if ds.chunks else 1
    buf = np.empty((min(step, num), *ds.shape[1:]), dtype=ds.dtype)
    for start in range(0, num, step):
        stop = min(start + step, num)
        _read_block(ds, start, stop, path, key, out=buf)
        yield from buf[: stop - start]


def _read_fps(f: h5py.File, path: Path) -> float | None:
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
            spec.path, _IMAGES, f"cameras {names} differ from {list(ref_cams)} in {ref.path}"
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
