"""``dcdp-precompute-base-features``: the base's own image-encoder features at every frame, as a new column.

A corrector with ``--policy.backbone=base_encoder`` reads its camera through the frozen base's image encoder
(LeRobot diffusion / VQ-BeT ``rgb_encoder``). Training it that way runs a ResNet18 on every frame of every
sample's window at every update (8.4 s per update of the paper recipe on PushT's 96x96 frames here). This
command runs the encoder once per frame instead, on the frame as the base's pre-processor normalises it, and
writes the features under ``<camera>.base_encoded``; the corrector takes that column in place of the frames
during training and encodes the camera itself at run time (the same values: the encoder is frozen and, in
eval mode, deterministic). With ``--drop-cameras`` the copy leaves the frames out, so training decodes none
(1.4 s of data loading per update of the paper recipe with the frames, here).

    dcdp-precompute-base-features --base models/pusht-diffusion-image --repo-id local/pusht_image \\
        --root data/pusht_image --out-repo-id local/pusht_image_enc --out-root data/pusht_image_enc
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from lerobot_dcdp.data.frame_columns import copy_parser, frame_vectors, refuse_existing, write_with_column
from lerobot_dcdp.model.dynamics import BASE_ENCODED_SUFFIX


def precompute_base_features(
    base: str | Path,
    repo_id: str,
    root: str | Path,
    out_repo_id: str,
    out_root: str | Path,
    camera: str = "observation.image",
    drop_cameras: bool = False,
    force: bool = False,
) -> tuple[Path, str]:
    """Write a copy of the dataset at ``root`` with the base encoder's features of ``camera`` per frame
    (the cameras left out with ``drop_cameras``: the corrector declares them from the base); returns the
    copy's root and the column's key."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import batch_to_transition, transition_to_batch

    from lerobot_dcdp.policy.base_policy import base_image_encoder, load_base_policy

    out_root = refuse_existing(out_root, force)
    policy = load_base_policy(str(base), "cpu").eval()
    if camera not in (policy.config.input_features or {}):
        raise ValueError(
            f"the base does not read {camera!r}; it reads {sorted(policy.config.input_features)}"
        )
    encoder, _ = base_image_encoder(policy)
    pre = PolicyProcessorPipeline.from_pretrained(
        str(base),
        "policy_preprocessor.json",
        to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )
    dataset = LeRobotDataset(repo_id, root=root)
    key = camera + BASE_ENCODED_SUFFIX
    if key in dataset.meta.features:
        raise ValueError(f"the dataset already holds {key!r}")
    values = frame_vectors(lambda batch: encoder(pre(batch)[camera]), dataset, camera)
    write_with_column(dataset, key, values, out_repo_id, out_root, drop_cameras)
    return out_root, key


def main(argv: list[str] | None = None) -> None:
    p = copy_parser("dcdp-precompute-base-features", __doc__.splitlines()[0], "the features")
    p.add_argument("--base", required=True, help="the base policy's folder (its pretrained_model)")
    p.add_argument("--camera", default="observation.image", help="the camera the base's encoder reads")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    try:
        out, key = precompute_base_features(
            a.base, a.repo_id, a.root, a.out_repo_id, a.out_root, a.camera, a.drop_cameras, a.force
        )
    except (FileExistsError, ValueError) as err:
        sys.exit(f"dcdp-precompute-base-features: error: {err}")
    print(f"wrote {out} ({key}: the base encoder's features per frame)")


if __name__ == "__main__":
    main()
