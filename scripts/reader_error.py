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

from lerobot_dcdp.model.pixel_keypoints import load_reader
from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env
from lerobot_dcdp.sim.pusht_expert import ExpertConfig, ScriptedExpert


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--reader", required=True, help="the reader's folder (dcdp-fit-pixel-keypoints --out)")
    p.add_argument("--episodes", type=int, default=10, help="episodes (seeds from --seed)")
    p.add_argument("--seed", type=int, default=100_000, help="first episode seed")
    p.add_argument("--steps", type=int, default=120, help="steps per episode")
    p.add_argument("--magnitude", type=float, default=2.0, help="block drift, px per step")
    p.add_argument("--perturbation", default="random", help="constant or random drift")
    p.add_argument("--lag", type=int, default=8, help="steps over which the change is read")
    a = p.parse_args()
    net, _, _ = load_reader(a.reader)
    errors, change_errors, changes = [], [], []
    for e in range(a.episodes):
        env = make_perturbed_env(
            obs_type="pixels_environment_state_agent_pos", perturbation=a.perturbation, magnitude=a.magnitude
        )
        obs, _ = env.reset(seed=a.seed + e)
        expert = ScriptedExpert(ExpertConfig(max_exec=8), seed=a.seed + e)
        prev, queue = np.array(env.unwrapped.agent.position, dtype=float), []
        est, true = [], []
        for _ in range(a.steps):
            frame = torch.from_numpy(obs["pixels"]).permute(2, 0, 1).float().unsqueeze(0) / 255
            with torch.no_grad():
                est.append(net(frame)[0].numpy())
            true.append(np.asarray(obs["environment_state"], np.float32))
            queue = queue or list(expert.next_actions(env, prev))
            prev = np.asarray(queue.pop(0), dtype=float)
            obs, _, done, trunc, _ = env.step(prev)
            if done or trunc:
                break
        est, true = np.stack(est), np.stack(true)
        point = lambda d: np.linalg.norm(d.reshape(len(d), -1, 2), axis=-1).mean(-1)  # noqa: E731
        errors += list(point(est - true))
        if len(est) > a.lag:
            d_est, d_true = est[a.lag :] - est[: -a.lag], true[a.lag :] - true[: -a.lag]
            change_errors += list(point(d_est - d_true))
            changes += list(point(d_true))
        env.close()
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
