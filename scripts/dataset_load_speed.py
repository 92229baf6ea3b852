"""Seconds per training sample of a LeRobotDataset as lerobot-train reads it (2 frames, 16 actions).

Usage: .venv/bin/python scripts/dataset_load_speed.py ROOT [ROOT ...] (e.g. a video and a PNG copy of the
same demonstrations: dcdp-pusht-demos --images [--image-storage image]). Prints one line per dataset.
"""

import sys
import time

from lerobot.datasets.lerobot_dataset import LeRobotDataset


def per_sample(root: str, n: int = 100) -> float:
    """Mean seconds of ``n`` spread-out ``dataset[i]`` reads after 10 warm-up reads."""
    deltas = {"observation.image": [-0.1, 0.0], "observation.state": [-0.1, 0.0]}
    deltas["action"] = [i / 10 for i in range(-1, 15)]
    ds = LeRobotDataset("local/speed", root=root, delta_timestamps=deltas)
    for i in range(10):
        ds[i]
    t = time.perf_counter()
    for i in range(n):
        ds[(i * 37) % len(ds)]
    return (time.perf_counter() - t) / n


if __name__ == "__main__":
    for root in sys.argv[1:]:
        print(f"{root}: {1000 * per_sample(root):.1f} ms per sample")
