"""What an image corrector's per-frame encoder carries of the block's motion: a linear probe.

Episodes of ``pusht_perturbed`` under block drift, driven by the scripted expert (as ``reader_error.py``);
each frame goes through each encoder, and a ridge regression (held-out episodes, its weight picked on a split
of the training ones) reads from the encoder's output (a) the block's keypoints and (b) their change over
``--lag`` steps (from the outputs at t and t-lag), what a corrector must read to follow a moving block.
Errors are mean point distances (px), as ``reader_error.py`` reports; "zero" predicts no change / the mean
pose.

Encoders: ``resnet18`` (the corrector's default image backbone: a frozen, random torchvision ResNet18 trunk,
average-pooled), ``resnet18_map`` (the same trunk's 3x3 map, flattened), ``base`` (the frozen base's own
trained encoder, ``--policy.backbone=base_encoder``, after the base's image normalisation), ``reader`` (a
frame -> keypoints reader's estimate), ``pixels`` (the frame average-pooled to 24x24).

    .venv/bin/python scripts/encoder_probe.py --base <image base pretrained_model> --reader <reader folder>
"""

import argparse

import numpy as np
import torch


def collect(episodes: int, seed: int, steps: int, magnitude: float, perturbation: str):
    """Frames (N, 3, 96, 96) in [0, 1], true keypoints (N, K) and episode ids (N,)."""
    from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env
    from lerobot_dcdp.sim.pusht_expert import ExpertConfig, ScriptedExpert

    frames, kps, ids = [], [], []
    for e in range(episodes):
        env = make_perturbed_env(
            obs_type="pixels_environment_state_agent_pos", perturbation=perturbation, magnitude=magnitude
        )
        obs, _ = env.reset(seed=seed + e)
        expert = ScriptedExpert(ExpertConfig(max_exec=8), seed=seed + e)
        prev, queue = np.array(env.unwrapped.agent.position, dtype=float), []
        for _ in range(steps):
            frames.append(torch.from_numpy(obs["pixels"].copy()).permute(2, 0, 1))
            kps.append(np.asarray(obs["environment_state"], np.float32))
            ids.append(e)
            queue = queue or list(expert.next_actions(env, prev))
            prev = np.asarray(queue.pop(0), dtype=float)
            obs, _, done, trunc, _ = env.step(prev)
            if done or trunc:
                break
        env.close()
    return torch.stack(frames).float() / 255, np.stack(kps), np.asarray(ids)


def add_drift_args(p: argparse.ArgumentParser, episodes: int) -> None:
    """The flags of :func:`collect` and the lag over which the block's change is read."""
    p.add_argument("--episodes", type=int, default=episodes, help="episodes (seeds from --seed)")
    p.add_argument("--seed", type=int, default=100_000, help="first episode seed")
    p.add_argument("--steps", type=int, default=120, help="steps per episode")
    p.add_argument("--magnitude", type=float, default=2.0, help="block drift, px per step")
    p.add_argument("--perturbation", default="random", help="constant or random drift")
    p.add_argument("--lag", type=int, default=8, help="steps over which the change is read")


def encoders(base_path: str | None, reader_path: str | None) -> dict:
    """``{name: frames (B, 3, 96, 96) in [0, 1] -> features (B, F)}``."""
    import torchvision

    torch.manual_seed(0)
    trunk = torch.nn.Sequential(*list(torchvision.models.resnet18(weights=None).children())[:-2]).eval()
    out = {
        "resnet18": lambda x: trunk(x).mean(dim=(-2, -1)),
        "resnet18_map": lambda x: trunk(x).flatten(1),
        "pixels": lambda x: torch.nn.functional.adaptive_avg_pool2d(x, 24).flatten(1),
    }
    if base_path:
        from lerobot_dcdp.policy.base_policy import base_image_encoder, load_base_policy, load_base_stats

        base = load_base_policy(base_path, "cpu")
        enc, _ = base_image_encoder(base)
        enc.eval()
        mode, stats = load_base_stats(base_path).get("observation.image", ("IDENTITY", {}))
        if mode == "MEAN_STD":
            mean, std = stats["mean"].view(1, -1, 1, 1), stats["std"].view(1, -1, 1, 1)
            out["base"] = lambda x: enc((x - mean) / std)
        elif mode == "MIN_MAX":
            lo, hi = stats["min"].view(1, -1, 1, 1), stats["max"].view(1, -1, 1, 1)
            out["base"] = lambda x: enc((x - lo) / (hi - lo).clamp_min(1e-8) * 2 - 1)
        else:
            out["base"] = enc
    if reader_path:
        from lerobot_dcdp.model.pixel_keypoints import load_reader

        net, _, _ = load_reader(reader_path)
        out["reader"] = net
    return out


def ridge_error(x: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray, val: np.ndarray) -> float:
    """Held-out mean point distance of a ridge readout x -> y (its weight picked on ``val``, within
    ``train``)."""
    mu, sd = x[train].mean(0), x[train].std(0) + 1e-6
    x = np.concatenate([(x - mu) / sd, np.ones((len(x), 1))], axis=1)
    point = lambda d: np.linalg.norm(d.reshape(len(d), -1, 2), axis=-1).mean()  # noqa: E731
    fit = train & ~val

    def solve(rows: np.ndarray, alpha: float) -> np.ndarray:
        a = x[rows]
        return np.linalg.solve(a.T @ a + alpha * len(a) * np.eye(a.shape[1]), a.T @ y[rows])

    best = min((10.0**k for k in range(-4, 6)), key=lambda al: point(x[val] @ solve(fit, al) - y[val]))
    return point(x[test] @ solve(train, best) - y[test])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--base", help="an image base's pretrained_model folder (its encoder is probed)")
    p.add_argument("--reader", help="a keypoint reader's folder (dcdp-fit-pixel-keypoints --out)")
    # a quarter of the episodes is held out
    add_drift_args(p, episodes=24)
    a = p.parse_args()
    frames, kps, ids = collect(a.episodes, a.seed, a.steps, a.magnitude, a.perturbation)
    n_test = max(1, a.episodes // 4)
    test_all = ids >= a.episodes - n_test
    val_all = (ids % 4 == 0) & ~test_all
    # the frames t whose t-lag is in the same episode
    now = np.flatnonzero(np.r_[np.zeros(a.lag, bool), ids[a.lag :] == ids[: -a.lag]])
    change = kps[now] - kps[now - a.lag]
    point = lambda d: np.linalg.norm(d.reshape(len(d), -1, 2), axis=-1).mean()  # noqa: E731
    tr, te = ~test_all, test_all
    print(
        f"frames {len(kps)} ({n_test} of {a.episodes} episodes held out), "
        f"{a.perturbation} {a.magnitude} px/step; "
        f"zero readout: keypoints {point(kps[te] - kps[tr].mean(0)):.2f} px, "
        f"change over {a.lag} steps {point(change[te[now]]):.2f} px"
    )
    for name, enc in encoders(a.base, a.reader).items():
        with torch.no_grad():
            feats = torch.cat([enc(frames[i : i + 64]) for i in range(0, len(frames), 64)]).numpy()
        pose = ridge_error(feats, kps, tr, te, val_all & tr)
        pair = np.concatenate([feats[now], feats[now] - feats[now - a.lag]], axis=1)
        move = ridge_error(pair, change, tr[now], te[now], (val_all & tr)[now])
        print(f"{name:13s} width {feats.shape[1]:5d}: keypoints {pose:6.2f} px, change {move:6.2f} px")


if __name__ == "__main__":
    main()
