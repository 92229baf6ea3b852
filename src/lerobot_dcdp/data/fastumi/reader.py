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

This module reads validated episodes (:func:`read_vectors`, :func:`iter_frames`) and re-exports the rest
of the reader: the format's names and :class:`EpisodeSpec` (``spec``), the HDF5 access (``hdf5``) and
finding and validating episodes (``inspection``).
"""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np

from lerobot_dcdp.data.fastumi.hdf5 import iter_camera, open_episode, read_pose_array
from lerobot_dcdp.data.fastumi.inspection import (
    detect_layout,
    find_episode_files,
    inspect_dataset,
    inspect_episode,
    resolve_fps,
)
from lerobot_dcdp.data.fastumi.spec import (
    ACTION_KEY,
    DEFAULT_FPS,
    FPS_ATTRS,
    GRIPPER_NAME,
    LAYOUTS,
    POSE_NAMES,
    QPOS_KEY,
    QUAT_TOLERANCE,
    CameraSpec,
    EpisodeSpec,
    FastUMIFormatError,
    Layout,
)

__all__ = [
    "DEFAULT_FPS",
    "FPS_ATTRS",
    "GRIPPER_NAME",
    "LAYOUTS",
    "POSE_NAMES",
    "QUAT_TOLERANCE",
    "CameraSpec",
    "EpisodeSpec",
    "FastUMIFormatError",
    "Layout",
    "bgr_to_rgb_resized",
    "detect_layout",
    "find_episode_files",
    "inspect_dataset",
    "inspect_episode",
    "iter_frames",
    "open_episode",
    "read_vectors",
    "resolve_fps",
]


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
            states.append(read_pose_array(f, prefix + QPOS_KEY, spec.path, spec.pose_dim))
            actions.append(read_pose_array(f, prefix + ACTION_KEY, spec.path, spec.pose_dim))
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
        streams = [iter_camera(f[cam.key], spec.path, cam.key) for cam in spec.cameras]
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
