"""``dcdp-fit-pixel-keypoints``: train the frame -> object-keypoints reader of an image corrector.

Reads every frame of a LeRobotDataset that holds a camera (``--image-key``, default ``observation.image``)
and the object's keypoints for that frame (``--target-key``, default ``observation.environment_state``: a
simulator's at recording time, e.g. ``dcdp-pusht-demos --images`` or ``dcdp-record-corrections`` with
images), and regresses the keypoints from the frame alone (:class:`~lerobot_dcdp.model.pixel_keypoints.
PixelKeypointNet`). Whole episodes are held out for validation (``--val-episodes``), and the held-out mean
keypoint error, in the keypoints' own units, is printed and saved. At run time the reader replaces the
keypoints: nothing reads the simulator's.

The folder (``--out``) appears only when complete: ``config.json`` (architecture, keys, normalisation),
``model.safetensors`` and ``fit.json`` (the held-out error, the data, the command's settings).

    dcdp-fit-pixel-keypoints --repo-id local/pusht_image_kp --root data/pusht_image_kp \\
        --out runs/pusht_pixel_keypoints --steps 4000
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch
from torch import Tensor

from lerobot_dcdp.data.atomic_dataset import staged_dir
from lerobot_dcdp.model.pixel_keypoints import (
    CONFIG_NAME,
    FIT_NAME,
    WEIGHTS_NAME,
    PixelKeypointNet,
    PixelKeypointsConfig,
    keypoint_error,
)


def load_frames(dataset, image_key: str, target_key: str) -> tuple[Tensor, Tensor, Tensor]:
    """Every frame of ``dataset`` as uint8 images (T, C, H, W), float keypoints (T, D) and episode indices.

    Raises:
        ValueError: the dataset lacks one of the keys, or ``image_key`` is no camera.
    """
    feats = dataset.meta.features
    for key in (image_key, target_key):
        if key not in feats:
            raise ValueError(f"the dataset has no {key!r} (it has {sorted(feats)})")
    if feats[image_key]["dtype"] not in ("image", "video"):
        raise ValueError(f"{image_key!r} is no camera (dtype {feats[image_key]['dtype']!r})")
    loader = torch.utils.data.DataLoader(dataset, batch_size=256, shuffle=False, num_workers=0)
    images, targets, episodes = [], [], []
    for batch in loader:
        images.append((batch[image_key] * 255).round().to(torch.uint8))
        targets.append(batch[target_key].float())
        episodes.append(batch["episode_index"])
    return torch.cat(images), torch.cat(targets), torch.cat(episodes)


def split_episodes(episodes: Tensor, n_val: int) -> tuple[Tensor, Tensor]:
    """Boolean masks (train, val) over frames: the last ``n_val`` episodes (by index) are held out (pure).

    Raises:
        ValueError: fewer than ``n_val + 1`` episodes.
    """
    ids = torch.unique(episodes)
    if n_val < 0 or len(ids) <= n_val:
        raise ValueError(f"--val-episodes={n_val} needs more episodes than that; the dataset has {len(ids)}")
    val = torch.isin(episodes, ids[len(ids) - n_val :]) if n_val else torch.zeros_like(episodes, dtype=bool)
    return ~val, val


def fit(
    images: Tensor,
    targets: Tensor,
    train: Tensor,
    val: Tensor,
    steps: int,
    batch_size: int = 64,
    lr: float = 1e-3,
    seed: int = 0,
    log_every: int = 500,
) -> tuple[PixelKeypointNet, dict]:
    """Fit a :class:`PixelKeypointNet` by MSE on standardised keypoints (Adam, cosine-decayed ``lr``).

    Returns:
        The net in eval mode and its metrics: ``val_error`` / ``train_error`` (mean keypoint distance in
        raw units; ``None`` without held-out frames), ``zero_error`` (predicting the mean keypoints).
    """
    torch.manual_seed(seed)
    mean, std = targets[train].mean(0), targets[train].std(0).clamp_min(1e-6)
    cfg = PixelKeypointsConfig(
        image_shape=tuple(images.shape[1:]),
        n_outputs=targets.shape[1],
        shift=mean.tolist(),
        scale=std.tolist(),
    )
    net = PixelKeypointNet(cfg)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(steps, 1))
    idx = torch.nonzero(train).flatten()
    gen = torch.Generator().manual_seed(seed)
    net.train()
    t0 = time.perf_counter()
    for step in range(steps):
        pick = idx[torch.randint(len(idx), (batch_size,), generator=gen)]
        x = images[pick].float() / 255
        loss = torch.nn.functional.mse_loss(net.standardised(x), (targets[pick] - mean) / std)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if log_every and (step + 1) % log_every == 0:
            print(
                f"step {step + 1}/{steps} loss {loss.item():.4f} ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    net.eval()
    metrics = {
        "train_error": evaluate(net, images[train], targets[train]),
        "val_error": evaluate(net, images[val], targets[val]) if val.any() else None,
        "zero_error": keypoint_error(
            mean.expand_as(targets[val if val.any() else train]), targets[val if val.any() else train]
        ).item(),
        "steps": steps,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    return net, metrics


@torch.no_grad()
def evaluate(net: PixelKeypointNet, images: Tensor, targets: Tensor, batch_size: int = 512) -> float:
    """Mean keypoint distance (raw units) of ``net``'s estimates over the frames."""
    preds = [net(images[i : i + batch_size].float() / 255) for i in range(0, len(images), batch_size)]
    return keypoint_error(torch.cat(preds), targets).item()


def save_reader(net: PixelKeypointNet, out: Path, image_key: str, target_key: str, fit_info: dict) -> None:
    """Write the reader's folder atomically (it appears only when complete)."""
    from safetensors.torch import save_file

    with staged_dir(out) as tmp:
        tmp.mkdir(parents=True)
        config = {**net.config.to_dict(), "image_key": image_key, "target_key": target_key}
        (tmp / CONFIG_NAME).write_text(json.dumps(config, indent=2) + "\n")
        save_file({k: v.contiguous() for k, v in net.state_dict().items()}, str(tmp / WEIGHTS_NAME))
        (tmp / FIT_NAME).write_text(json.dumps(fit_info, indent=2) + "\n")


def build_parser() -> argparse.ArgumentParser:
    """The CLI's flags."""
    p = argparse.ArgumentParser(prog="dcdp-fit-pixel-keypoints", description=__doc__.splitlines()[0])
    p.add_argument("--repo-id", required=True, help="a LeRobotDataset with frames and the object's keypoints")
    p.add_argument("--root", required=True, help="the dataset's local folder")
    p.add_argument("--out", required=True, help="the reader's folder (replaced atomically when complete)")
    p.add_argument("--image-key", default="observation.image", help="the camera feature to read")
    p.add_argument(
        "--target-key", default="observation.environment_state", help="the keypoints feature to regress"
    )
    p.add_argument("--steps", type=int, default=4000, help="Adam updates (default 4000)")
    p.add_argument("--batch-size", type=int, default=64, help="frames per update (default 64)")
    p.add_argument("--lr", type=float, default=1e-3, help="peak learning rate, cosine-decayed (default 1e-3)")
    p.add_argument(
        "--val-episodes", type=int, default=10, help="episodes held out for the error (default 10)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the initialisation and the batches")
    return p


def main(argv: list[str] | None = None) -> None:
    """Fit, report the held-out error, write the folder."""
    a = build_parser().parse_args(argv)
    if a.steps < 1 or a.batch_size < 1 or a.lr <= 0:
        sys.exit("dcdp-fit-pixel-keypoints: error: --steps, --batch-size and --lr must be positive")
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        dataset = LeRobotDataset(a.repo_id, root=a.root)
        images, targets, episodes = load_frames(dataset, a.image_key, a.target_key)
        train, val = split_episodes(episodes, a.val_episodes)
    except ValueError as e:
        sys.exit(f"dcdp-fit-pixel-keypoints: error: {e}")
    net, metrics = fit(images, targets, train, val, a.steps, a.batch_size, a.lr, a.seed)
    info = {**metrics, "repo_id": a.repo_id, "frames": len(images), "val_frames": int(val.sum())}
    save_reader(net, Path(a.out), a.image_key, a.target_key, info)
    val_text = "n/a (no held-out episodes)" if metrics["val_error"] is None else f"{metrics['val_error']:.3f}"
    print(
        f"held-out keypoint error {val_text} (predicting the mean: {metrics['zero_error']:.3f}; "
        f"train {metrics['train_error']:.3f}) -> {a.out}"
    )


if __name__ == "__main__":
    main()
