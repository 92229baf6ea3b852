"""The FastUMI formats' names and the validated description of an episode: the layouts, the HDF5 keys,
the state/action column names, the error every problem is reported as, and :class:`EpisodeSpec`.

Imports neither h5py nor LeRobot.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

Layout = Literal["fastumi", "fastumi_pro"]
LAYOUTS: tuple[str, ...] = ("auto", "fastumi", "fastumi_pro")

DEFAULT_FPS = 20
QUAT_TOLERANCE = 1e-3
POSE_NAMES: tuple[str, ...] = ("x", "y", "z", "qx", "qy", "qz", "qw")
GRIPPER_NAME = "gripper"
# Root attributes that may carry the recording rate (first one found wins).
FPS_ATTRS: tuple[str, ...] = ("fps", "frequency", "freq", "frame_rate", "control_freq")

#: HDF5 keys of an arm's observed poses, action poses and camera group (under ``robot_<i>/`` for dual-arm)
QPOS_KEY = "observations/qpos"
ACTION_KEY = "action"
IMAGES_KEY = "observations/images"


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
