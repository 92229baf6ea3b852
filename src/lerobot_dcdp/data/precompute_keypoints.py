"""``dcdp-precompute-keypoints``: a keypoint reader's estimate at every frame of a dataset, as a new column.

An image corrector reads the object's keypoints that its pre-processor's reader (``dcdp_pixel_keypoints``,
``--policy.keypoint_reader_path``) estimates from the camera. Training it that way decodes and reads every
frame of every sample's history at every update. This command runs the reader once per frame instead and
writes its estimate under ``--output-key`` (the corrector's ``anchor_feature``), the same values the
pre-processor step computes from the same frames (the reader is deterministic); with ``--drop-cameras`` the
copy leaves the cameras out, so training loads vectors only (the reader step passes a frame-less batch
unchanged) while the trained folder still reads the camera at run time. The rest of the dataset is copied by
LeRobot's ``modify_features``; the new dataset appears only when complete.

    dcdp-precompute-keypoints --reader runs/pusht_pixel_keypoints --repo-id local/pusht_image_kp \\
        --root data/pusht_image_kp --out-repo-id local/pusht_image_kpest --out-root data/pusht_image_kpest \\
        --output-key observation.kp_estimate --drop-cameras
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from lerobot_dcdp.data.frame_columns import copy_parser, frame_vectors, refuse_existing, write_with_column
from lerobot_dcdp.model.pixel_keypoints import load_reader


def precompute_keypoints(
    reader: str | Path,
    repo_id: str,
    root: str | Path,
    out_repo_id: str,
    out_root: str | Path,
    output_key: str | None = None,
    drop_cameras: bool = False,
    force: bool = False,
) -> tuple[Path, str]:
    """Write a copy of the dataset at ``root`` with the reader's estimate per frame; returns the copy's root
    and the key the estimate went under (default: the key the reader was fitted to, which must not be in the
    dataset already)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    out_root = refuse_existing(out_root, force)
    net, image_key, target_key = load_reader(reader)
    key = output_key or target_key
    dataset = LeRobotDataset(repo_id, root=root)
    if key in dataset.meta.features:
        raise ValueError(
            f"the dataset already holds {key!r}: name another column for the estimate (--output-key)"
        )
    estimates = frame_vectors(lambda batch: net(batch[image_key].float()), dataset, image_key)
    write_with_column(dataset, key, estimates, out_repo_id, out_root, drop_cameras)
    return out_root, key


def main(argv: list[str] | None = None) -> None:
    p = copy_parser("dcdp-precompute-keypoints", __doc__.splitlines()[0], "the estimate")
    p.add_argument("--reader", required=True, help="the reader's folder (dcdp-fit-pixel-keypoints --out)")
    p.add_argument(
        "--output-key", default=None, help="the estimate's column (default: the key the reader was fitted to)"
    )
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    try:
        out, key = precompute_keypoints(
            a.reader, a.repo_id, a.root, a.out_repo_id, a.out_root, a.output_key, a.drop_cameras, a.force
        )
    except (FileExistsError, ValueError) as err:
        sys.exit(f"dcdp-precompute-keypoints: error: {err}")
    print(f"wrote {out} ({key}: the reader's estimate per frame)")


if __name__ == "__main__":
    main()
