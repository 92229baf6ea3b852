"""Seconds per training update of LeRobot's image diffusion policy for some encoder / U-Net / history choices.

One update = forward + backward + Adam step on a synthetic batch (96x96 frames, PushT's 2-D state and action),
as lerobot-train runs it minus data loading: what picks a CPU-affordable image base recipe.

    OMP_NUM_THREADS=2 .venv/bin/python scripts/image_base_update_cost.py --threads 2
"""

import argparse
import time

import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

# (U-Net down_dims, resize before the crop, crop, observation steps)
VARIANTS = [
    ((128, 256, 512), None, (84, 84), 2),
    ((64, 128, 256), None, (84, 84), 2),
    ((64, 128, 256), (80, 80), (72, 72), 2),
    ((64, 128, 256), None, (84, 84), 1),
    ((64, 128, 256), (80, 80), (72, 72), 1),
]


def update_seconds(dims, resize, crop, n_obs: int, batch: int, repeats: int) -> tuple[float, float]:
    """Best-of-``repeats`` seconds per update (after one warm-up) and the parameter count in millions."""
    cfg = DiffusionConfig(
        horizon=16,
        n_obs_steps=n_obs,
        n_action_steps=8,
        down_dims=dims,
        resize_shape=resize,
        crop_shape=crop,
        diffusion_step_embed_dim=64 if dims[0] == 64 else 128,
        pretrained_backbone_weights=None,
        use_group_norm=True,
        device="cpu",
        input_features={
            "observation.image": PolicyFeature(FeatureType.VISUAL, (3, 96, 96)),
            "observation.state": PolicyFeature(FeatureType.STATE, (2,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
    )
    policy = DiffusionPolicy(cfg)
    opt = torch.optim.Adam(policy.parameters(), 1e-4)
    data = {
        "observation.image": torch.rand(batch, n_obs, 3, 96, 96),
        "observation.state": torch.rand(batch, n_obs, 2),
        "action": torch.rand(batch, 16, 2),
        "action_is_pad": torch.zeros(batch, 16, dtype=torch.bool),
    }
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        loss, _ = policy.forward(data)
        loss.backward()
        opt.step()
        opt.zero_grad()
        times.append(time.perf_counter() - t0)
    return min(times[1:]), sum(p.numel() for p in policy.parameters()) / 1e6


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    p.add_argument("--batch", type=int, default=32, help="samples per update")
    p.add_argument("--repeats", type=int, default=3, help="timed updates per variant (best kept)")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    print("| U-Net | resize | crop | obs steps | params (M) | s / update |\n|---|---|---|---|---|---|")
    for dims, resize, crop, n_obs in VARIANTS:
        s, params = update_seconds(dims, resize, crop, n_obs, a.batch, a.repeats)
        print(f"| {'-'.join(map(str, dims))} | {resize} | {crop} | {n_obs} | {params:.1f} | {s:.2f} |")


if __name__ == "__main__":
    main()
