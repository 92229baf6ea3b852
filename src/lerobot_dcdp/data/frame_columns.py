"""A vector computed from a dataset's camera at every frame, written as a new column of a copy of the dataset.

The training-time caches of the image path use it: a keypoint reader's estimate
(``dcdp-precompute-keypoints``) and the base's own image-encoder features (``dcdp-precompute-base-features``).
The rest of the dataset is copied by LeRobot's ``modify_features``; the new dataset appears only when
complete.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from lerobot_dcdp.data.atomic_dataset import staged_dir


def copy_parser(prog: str, description: str, what: str) -> argparse.ArgumentParser:
    """The arguments every column-writing command shares: the dataset, its copy and ``--force``.

    Args:
        prog: The command's name.
        description: Its one-line description.
        what: What the new column holds, for the ``--out-root`` help.
    """
    p = argparse.ArgumentParser(prog=prog, description=description)
    p.add_argument("--repo-id", required=True, help="the dataset's repo id")
    p.add_argument("--root", required=True, help="the dataset's directory")
    p.add_argument("--out-repo-id", required=True, help="the copy's repo id")
    p.add_argument("--out-root", required=True, help=f"where the copy with {what} goes")
    p.add_argument(
        "--drop-cameras",
        action="store_true",
        help="leave the cameras out of the copy (training decodes no frame)",
    )
    p.add_argument("--force", action="store_true", help="replace --out-root if it exists")
    return p


def refuse_existing(out_root: str | Path, force: bool) -> Path:
    """``out_root`` as a path, refused if it exists and ``force`` is not set.

    Raises:
        FileExistsError: ``out_root`` exists and ``force`` is false.
    """
    out_root = Path(out_root)
    if out_root.exists() and not force:
        raise FileExistsError(f"{out_root} exists; pass --force to replace it")
    return out_root


def camera_keys(dataset) -> list[str]:
    """The dataset's cameras (image or video features)."""
    return [k for k, f in dataset.meta.features.items() if f["dtype"] in ("image", "video")]


@torch.no_grad()
def frame_vectors(
    fn: Callable[[dict[str, torch.Tensor]], torch.Tensor], dataset, image_key: str, batch_size: int = 256
) -> np.ndarray:
    """``fn`` of each of the dataset's N frames, (N, F) float32 in global index order.

    Args:
        fn: Maps a batch of frames (the dataset's own entries, ``image_key`` among them) to (B, F).
        dataset: The ``LeRobotDataset``.
        image_key: The camera ``fn`` reads (checked to exist).
        batch_size: Frames per call.

    Raises:
        ValueError: the dataset has no camera ``image_key``.
    """
    if image_key not in camera_keys(dataset):
        cameras = camera_keys(dataset)
        raise ValueError(f"{image_key!r} is not a camera of the dataset: its cameras are {cameras}")
    from tqdm import tqdm

    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=False, num_workers=0)
    out = [fn(batch).float().numpy() for batch in tqdm(loader, desc=f"frames of {image_key}", unit="batch")]
    return np.concatenate(out).astype(np.float32)


def write_with_column(
    dataset, key: str, values: np.ndarray, out_repo_id: str, out_root: Path, drop_cameras: bool = False
) -> None:
    """Write a copy of ``dataset`` with ``values`` (N, F) as the column ``key`` (cameras left out on request).

    Raises:
        ValueError: the dataset already holds ``key``.
    """
    from lerobot.datasets.dataset_tools import modify_features

    if key in dataset.meta.features:
        raise ValueError(f"the dataset already holds {key!r}: name another column for it")
    info = {"dtype": "float32", "shape": [values.shape[1]], "names": None}
    with staged_dir(Path(out_root)) as built:
        modify_features(
            dataset,
            add_features={key: (values, info)},
            remove_features=camera_keys(dataset) if drop_cameras else None,
            output_dir=built,
            repo_id=out_repo_id,
        )
