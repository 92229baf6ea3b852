"""``dcdp-precompute-plans``: the frozen base's chunk planned at every frame of a dataset, as a new column.

Stage 1 on plain demonstrations (``correction=residual`` with ``anchor_feature``) takes the demonstration's
own chunk as "the plan" by default. With this column it takes the chunk the *base* planned from that frame
instead, which is what the corrector corrects at deployment. The base runs once per frame, in episode order
with its own observation history (every episode of a batch advances one frame per call), and its chunk is
stored raw (un-normalised), flattened to ``chunk_length * action_dim`` values per frame under
``--plan-key`` (the corrector config's ``plan_feature``, default ``observation.dcdp_plan``). The rest of the
dataset is copied unchanged by LeRobot's ``add_features``; the new dataset appears only when complete.

    dcdp-precompute-plans --base models/pusht-diffusion-state --repo-id local/pusht_expert \\
        --root data/pusht_expert --out-repo-id local/pusht_expert_plans --out-root data/pusht_expert_plans
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from lerobot_dcdp.data.atomic_dataset import staged_dir
from lerobot_dcdp.model.correction import unnormalize


@torch.no_grad()
def base_plans(
    base_path: str, dataset, episodes_per_batch: int = 64, seed: int = 0, transform=None
) -> np.ndarray:
    """The base's raw chunk (N, L * A) planned at each of the dataset's N frames (global index order).

    Args:
        base_path: The base's ``pretrained_model`` directory.
        dataset: A ``LeRobotDataset`` holding every input the base reads.
        episodes_per_batch: Episodes run side by side (one frame of each per base call).
        seed: Seeds the base's sampling noise (diffusion), so the column is reproducible.
        transform: Applied to every frame before the base reads it (e.g. a split of a robot's flattened
            state); ``None``: the frames as stored.
    """
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.utils.constants import ACTION

    from lerobot_dcdp.policy.base_policy import load_base_policy, load_base_stats
    from lerobot_dcdp.runtime.chunk_sources import make_chunk_source

    base = load_base_policy(base_path, "cpu")
    pre, _ = make_pre_post_processors(base.config, pretrained_path=base_path)
    mode, stats = load_base_stats(base_path).get(ACTION, ("IDENTITY", {}))
    source = make_chunk_source(base)
    keys = list(base.config.input_features)
    read = dataset.__getitem__ if transform is None else (lambda i: transform(dataset[i]))
    available = dataset.meta.features if transform is None else read(0)
    missing = [k for k in keys if k not in available]
    if missing:
        raise ValueError(f"the dataset has no {missing}, which the base reads (it has {sorted(available)})")
    episode_of = np.asarray(dataset.hf_dataset["episode_index"])
    episodes = [np.flatnonzero(episode_of == e) for e in np.unique(episode_of)]  # global indices per episode
    out = np.zeros((len(episode_of), source.chunk_length * base.config.action_feature.shape[0]), np.float32)
    generator_state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    try:
        for start in range(0, len(episodes), episodes_per_batch):
            group = episodes[start : start + episodes_per_batch]
            source.reset()
            for k in range(max(len(g) for g in group)):
                rows = [g[min(k, len(g) - 1)] for g in group]  # an ended episode repeats its last frame
                frames = [read(int(i)) for i in rows]
                batch = {key: torch.stack([f[key] for f in frames]) for key in keys}
                chunk = source.chunk(source.observe(pre(batch)))  # (B, L, A) base-normalised
                raw = unnormalize(chunk, stats, mode) if stats else chunk
                for g, plan in zip(group, raw, strict=True):
                    if k < len(g):
                        out[g[k]] = plan.reshape(-1).numpy()
    finally:
        torch.random.set_rng_state(generator_state)
    return out


def precompute_plans(
    base_path: str,
    repo_id: str,
    root: str | Path,
    out_repo_id: str,
    out_root: str | Path,
    plan_key: str = "observation.dcdp_plan",
    episodes_per_batch: int = 64,
    seed: int = 0,
    force: bool = False,
) -> Path:
    """Write a copy of the dataset at ``root`` with the base's per-frame chunk under ``plan_key``."""
    from lerobot.datasets.dataset_tools import add_features
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    out_root = Path(out_root)
    if out_root.exists() and not force:
        raise FileExistsError(f"{out_root} exists; pass --force to replace it")
    dataset = LeRobotDataset(repo_id, root=root)
    if plan_key in dataset.meta.features:
        raise ValueError(f"the dataset already holds {plan_key!r}")
    plans = base_plans(base_path, dataset, episodes_per_batch, seed)
    info = {"dtype": "float32", "shape": [plans.shape[1]], "names": None}
    with staged_dir(out_root) as built:
        add_features(dataset, {plan_key: (plans, info)}, output_dir=built, repo_id=out_repo_id)
    return out_root


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-precompute-plans", description=__doc__.splitlines()[0])
    p.add_argument("--base", required=True, help="the frozen base's pretrained_model directory")
    p.add_argument("--repo-id", required=True, help="the dataset's repo id")
    p.add_argument("--root", required=True, help="the dataset's directory")
    p.add_argument("--out-repo-id", required=True, help="the copy's repo id")
    p.add_argument("--out-root", required=True, help="where the copy with the plan column goes")
    p.add_argument("--plan-key", default="observation.dcdp_plan", help="the corrector's plan_feature")
    p.add_argument(
        "--episodes-per-batch",
        type=int,
        default=64,
        help="episodes run side by side, one frame of each per base call (default: %(default)s)",
    )
    p.add_argument("--seed", type=int, default=0, help="seeds the base's sampling noise")
    p.add_argument("--force", action="store_true", help="replace --out-root if it exists")
    args = p.parse_args(argv)
    if args.episodes_per_batch < 1:
        p.error("--episodes-per-batch must be >= 1")
    if not (Path(args.base) / "config.json").is_file():
        p.error(f"--base {args.base} is not a pretrained_model directory (no config.json)")
    try:
        out = precompute_plans(
            args.base,
            args.repo_id,
            args.root,
            args.out_repo_id,
            args.out_root,
            args.plan_key,
            args.episodes_per_batch,
            args.seed,
            args.force,
        )
    except (FileExistsError, ValueError) as err:
        sys.exit(f"dcdp-precompute-plans: {err}")
    print(f"wrote {out} ({args.plan_key}: the base's chunk per frame)")


if __name__ == "__main__":
    main()
