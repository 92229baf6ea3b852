"""FastUMI / FastUMI Pro HDF5 episodes -> LeRobotDataset v3 (``dcdp-fastumi-to-lerobot``).

The reader is importable without LeRobot; :func:`convert_fastumi` imports LeRobot lazily.
"""

from lerobot_dcdp.data.fastumi.convert import (
    compose_pose,
    convert_fastumi,
    relative_pose,
    to_relative_actions,
)
from lerobot_dcdp.data.fastumi.reader import (
    EpisodeSpec,
    FastUMIFormatError,
    inspect_dataset,
    inspect_episode,
    iter_frames,
    read_vectors,
)

__all__ = [
    "EpisodeSpec",
    "FastUMIFormatError",
    "compose_pose",
    "convert_fastumi",
    "inspect_dataset",
    "inspect_episode",
    "iter_frames",
    "read_vectors",
    "relative_pose",
    "to_relative_actions",
]
