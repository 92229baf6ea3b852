"""How well a keypoint reader reads the PushT block from rendered frames, where an image corrector uses it.

Episodes of ``pusht_perturbed`` (camera + simulator keypoints of the same step) under block drift, driven by
the scripted expert; per frame, the reader's keypoints against the simulator's (mean point distance, px), and
what the corrector reads: the block's change over a chunk, estimated keypoints at t minus at t-8, against the
true change. Frames are the env's own renders (not decoded video, which the reader was fitted on).

    .venv/bin/python scripts/reader_error.py --reader runs/reader --episodes 10
"""

import argparse

import numpy as np
import torch
from encoder_probe import add_drift_args, collect

from lerobot_dcdp.model.pixel_keypoints import load_reader


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--reader", required=True, help="the reader's folder (dcdp-fit-pixel-keypoints --out)")
    add_drift_args(p, episodes=10)
    a = p.parse_args()
    net, _, _ = load_reader(a.reader)
    frames, true, ids = collect(a.episodes, a.seed, a.steps, a.magnitude, a.perturbation)
    with torch.no_grad():
        est = torch.cat([net(frames[i : i + 1]) for i in range(len(frames))]).numpy()
    point = lambda d: np.linalg.norm(d.reshape(len(d), -1, 2), axis=-1).mean(-1)  # noqa: E731
    errors = point(est - true)
    now = np.flatnonzero(np.r_[np.zeros(a.lag, bool), ids[a.lag :] == ids[: -a.lag]])  # t-lag in the episode
    change_errors = point((est[now] - est[now - a.lag]) - (true[now] - true[now - a.lag]))
    changes = point(true[now] - true[now - a.lag])
    print(
        f"frames {len(errors)}: keypoint error mean {np.mean(errors):.2f} px, "
        f"p90 {np.percentile(errors, 90):.2f}"
    )
    print(
        f"change over {a.lag} steps: true mean {np.mean(changes):.2f} px, error of the estimated change mean "
        f"{np.mean(change_errors):.2f} px, p90 {np.percentile(change_errors, 90):.2f}"
    )


if __name__ == "__main__":
    main()
