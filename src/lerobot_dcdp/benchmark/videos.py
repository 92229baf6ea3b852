"""The benchmark's side-by-side videos: rendered frames are stashed per cell, then open loop (left) and
DCDP (right) of the same seed and perturbation are joined into one MP4."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def stash_frames(video_dir: Path, label: str, method: str, cname: str, frames: dict) -> None:
    """Save each seed's frames (downscaled to 256 x 256) as a hidden ``.npy`` for :func:`write_videos`.

    Args:
        video_dir: The videos folder (created).
        label: The model.
        method: The row that rendered them.
        cname: The condition.
        frames: ``{seed: frames}``, each ``(T, H, W, 3)`` uint8.
    """
    import cv2

    video_dir.mkdir(parents=True, exist_ok=True)
    for seed, fr in frames.items():
        small = np.stack([cv2.resize(f, (256, 256), interpolation=cv2.INTER_AREA) for f in fr])
        np.save(video_dir / f".{label}_{method}_{cname}_{seed}.npy", small)


def write_videos(video_dir: Path, label: str) -> None:
    """Side by side: open loop (left) | DCDP (right), same seed and perturbation; the stashed frames of each
    pair written are removed (an open-loop stash without its DCDP one is left)."""
    from lerobot.utils.io_utils import write_video

    for left in sorted(video_dir.glob(f".{label}_open_loop_*.npy")):
        right = left.with_name(left.name.replace("_open_loop_", "_dcdp_"))
        if not right.exists():
            continue
        a, b = np.load(left), np.load(right)
        n = max(len(a), len(b))
        a = np.concatenate([a, np.repeat(a[-1:], n - len(a), 0)])
        b = np.concatenate([b, np.repeat(b[-1:], n - len(b), 0)])
        name = left.name[1:].replace("_open_loop_", "_openloop_vs_dcdp_").replace(".npy", ".mp4")
        write_video(str(video_dir / name), list(np.concatenate([a, b], axis=2)), fps=10)
        left.unlink()
        right.unlink()
