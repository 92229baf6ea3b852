"""Throughput / memory benchmark of the FastUMI converter (not a test).

Writes one synthetic FastUMI episode (1920x1080 BGR frames, gzip level 4, one chunk per frame, like the
released data) into a temporary directory, then

1. times a read-only pass (gzip decompression + BGR->RGB + resize) with :func:`iter_frames`, and
2. times the full :func:`convert_fastumi` run (read + PNG staging + AV1 encoding + stats + metadata),

and prints frames/s and the process' peak RSS (``resource.getrusage``). The synthetic episode is written
by a separate (spawned) process so that its memory does not count in the converter's peak RSS.

Usage::

    python -m lerobot_dcdp.data.fastumi.benchmark --frames 1000 [--image-size 224] \
        [--width 1920 --height 1080]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

try:
    import h5py
except ImportError as err:  # an optional dependency
    raise ImportError("the FastUMI tools need h5py: pip install 'lerobot_policy_dcdp[fastumi]'") from err
import numpy as np


def write_synthetic_episode(path: str, frames: int, height: int, width: int, seed: int = 0) -> None:
    """Write a FastUMI-layout episode with smooth, moving, mildly noisy frames (realistic gzip ratio).

    Args:
        path: Output ``.hdf5`` file.
        frames: Number of frames ``T``.
        height: Frame height.
        width: Frame width.
        seed: Noise seed.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width]
    base = np.stack([xx * 255 // max(width - 1, 1), yy * 255 // max(height - 1, 1), (xx + yy) % 256], -1)
    base = base.astype(np.uint8)
    noise = rng.integers(0, 4, size=(4, height, width, 3), dtype=np.uint8)
    theta = np.linspace(0, 1.0, frames)
    qpos = np.zeros((frames, 7))
    qpos[:, 0] = np.linspace(0, 0.3, frames)
    qpos[:, 2] = 0.2
    qpos[:, 5] = np.sin(theta / 2)
    qpos[:, 6] = np.cos(theta / 2)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        f.attrs["sim"] = False
        f.create_dataset("observations/qpos", data=qpos)
        f.create_dataset("action", data=qpos)
        images = f.create_dataset(
            "observations/images/front",
            shape=(frames, height, width, 3),
            dtype=np.uint8,
            chunks=(1, height, width, 3),
            compression="gzip",
            compression_opts=4,
        )
        box_h, box_w = height // 4, width // 6
        for t in range(frames):
            frame = base + noise[t % 4]
            x0 = (t * 13) % max(width - box_w, 1)
            frame[height // 3 : height // 3 + box_h, x0 : x0 + box_w] = (40, 180, 220)
            images[t] = frame


def _peak_rss_mib(who: int = resource.RUSAGE_SELF) -> float:
    return resource.getrusage(who).ru_maxrss / 1024.0  # Linux reports KiB


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the results.

    Args:
        argv: Arguments (default: ``sys.argv[1:]``).

    Returns:
        Exit status.
    """
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=1000, help="frames T of the synthetic episode (1000)")
    p.add_argument("--image-size", type=int, default=224, help="side of the stored square frames (224)")
    p.add_argument("--width", type=int, default=1920, help="width of the synthetic source frames (1920)")
    p.add_argument("--height", type=int, default=1080, help="height of the synthetic source frames (1080)")
    p.add_argument("--skip-read-pass", action="store_true", help="only time the full conversion")
    p.add_argument("--tmp-dir", default=None, help="where to put the temporary files (default: system tmp)")
    args = p.parse_args(argv)
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only

    from lerobot_dcdp.data.fastumi.convert import convert_fastumi
    from lerobot_dcdp.data.fastumi.reader import inspect_episode, iter_frames

    tmp = Path(tempfile.mkdtemp(prefix="fastumi-bench-", dir=args.tmp_dir))
    try:
        episode = tmp / "in" / "bench" / "episode_0.hdf5"
        t0 = time.perf_counter()
        ctx = mp.get_context("spawn")
        writer = ctx.Process(
            target=write_synthetic_episode, args=(str(episode), args.frames, args.height, args.width)
        )
        writer.start()
        writer.join()
        if writer.exitcode != 0:
            print(f"error: writing the synthetic episode failed ({writer.exitcode})", file=sys.stderr)
            return 1
        write_s = time.perf_counter() - t0
        raw_mb = args.frames * args.height * args.width * 3 / 1e6
        file_mb = episode.stat().st_size / 1e6
        print(
            f"synthetic episode: {args.frames} frames {args.width}x{args.height}, raw {raw_mb:.0f} MB, "
            f"gzip file {file_mb:.0f} MB, written in {write_s:.1f}s"
        )
        rss_start = _peak_rss_mib()

        result: dict = {"frames": args.frames, "width": args.width, "height": args.height}
        result["image_size"] = args.image_size
        if not args.skip_read_pass:
            spec = inspect_episode(episode, "bench")
            t0 = time.perf_counter()
            n = sum(1 for _ in iter_frames(spec, args.image_size))
            read_s = time.perf_counter() - t0
            result["read_fps"] = round(n / read_s, 2)
            print(f"read pass (gunzip + resize + BGR->RGB): {n / read_s:.1f} frames/s ({read_s:.1f}s)")
        rss_read = _peak_rss_mib()

        t0 = time.perf_counter()
        summary = convert_fastumi(tmp / "in", "local/fastumi_bench", tmp / "out", image_size=args.image_size)
        conv_s = time.perf_counter() - t0
        rss_end = _peak_rss_mib()
        result.update(
            convert_fps=round(summary["frames"] / conv_s, 2),
            convert_s=round(conv_s, 2),
            peak_rss_mib_before=round(rss_start, 1),
            peak_rss_mib_after_read=round(rss_read, 1),
            peak_rss_mib=round(rss_end, 1),
            file_mb=round(file_mb, 1),
        )
        frame_mib = args.height * args.width * 3 / 2**20
        conv_fps = summary["frames"] / conv_s
        print(f"full conversion at {args.image_size}px: {conv_fps:.1f} frames/s ({conv_s:.1f}s)")
        print(
            f"peak RSS: {rss_end:.0f} MiB (after imports/setup {rss_start:.0f} MiB, "
            f"after read pass {rss_read:.0f} MiB); one raw frame is {frame_mib:.1f} MiB"
        )
        print(json.dumps(result))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
