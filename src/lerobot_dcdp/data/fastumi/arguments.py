"""``dcdp-fastumi-to-lerobot``'s command line: the argument parser and its value checks (argparse names the
checks in its messages: ``invalid _positive_int value``)."""

from __future__ import annotations

import argparse

from lerobot_dcdp.data.fastumi.features import ACTION_MODES, MIN_IMAGE_SIZE
from lerobot_dcdp.data.fastumi.spec import LAYOUTS


def _positive_int(text: str) -> int:
    """``--fps``: a positive integer.

    Raises:
        argparse.ArgumentTypeError: ``text`` is not one (``ValueError`` when not an integer at all).
    """
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _image_size(text: str) -> int:
    """``--image-size``: an even integer of at least ``MIN_IMAGE_SIZE`` (video encoding).

    Raises:
        argparse.ArgumentTypeError: ``text`` is not one (``ValueError`` when not an integer at all).
    """
    value = int(text)
    if value < MIN_IMAGE_SIZE or value % 2:
        raise argparse.ArgumentTypeError(f"must be even and >= {MIN_IMAGE_SIZE} (video encoding), got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``dcdp-fastumi-to-lerobot``."""
    p = argparse.ArgumentParser(
        prog="dcdp-fastumi-to-lerobot",
        description="Convert FastUMI / FastUMI Pro HDF5 episodes into a LeRobotDataset v3.",
    )
    p.add_argument("--input", required=True, help="folder of <task>/episode_<idx>.hdf5 or episode_<idx>.hdf5")
    p.add_argument("--repo-id", required=True, help="dataset id, e.g. local/fastumi_cups (not pushed)")
    p.add_argument("--root", required=True, help="output dataset directory")
    p.add_argument(
        "--fps", type=_positive_int, default=None, help="override the frame rate (default: file, else 20)"
    )
    p.add_argument("--image-size", type=_image_size, default=224, help="side of the square RGB frames (224)")
    p.add_argument("--task", default=None, help="task string for all episodes (default: task folder name)")
    p.add_argument("--action", choices=ACTION_MODES, default="absolute", help="action representation")
    p.add_argument("--layout", choices=LAYOUTS, default="auto", help="input layout (default: detect)")
    p.add_argument("--force", action="store_true", help="replace an existing dataset at --root")
    return p
