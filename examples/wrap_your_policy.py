"""Wrap any pretrained chunking policy (Diffusion Policy, ACT, ...) in a DCDP corrector, all from Python.

1. ``make_policy`` builds a ``dcdp`` policy around the frozen base (features from the dataset);
2. its corrector trains for a few steps on a LeRobotDataset: the policy's ``forward`` + its optimizer preset.
   With the default ``--correction residual`` on plain demonstrations, stage 1 synthesises the object's
   motion after plan time and learns to carry the plan along with it: name the object's xy keypoints with
   ``--anchor-feature`` (a dataset recorded by ``dcdp-record-corrections`` needs no anchor). ``reconstruct``
   is the paper's recipe, measured to make the base worse (docs/FINDINGS.md);
3. the corrector is saved (``lerobot-eval --policy.path=OUT`` loads it) and run in every execution mode
   on one recorded episode: the actions it takes from the recorded observations, their distance to the
   recorded actions, and the time per step.

This is the Python view of what ``lerobot-train --policy.type=dcdp`` does (README: "Wrap your own policy");
use that command for real runs: it checkpoints and resumes (``--resume=true``).

Example (the shipped PushT base on the expert demonstrations)::

    python examples/wrap_your_policy.py models/pusht-diffusion-state \\
        --repo-id local/pusht_expert --root data/pusht_expert --steps 200 --out runs/my_corrector \\
        --anchor-feature observation.environment_state
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import torch
from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.policies.factory import make_policy, make_pre_post_processors

import lerobot_policy_dcdp  # noqa: F401  (registers the `dcdp` policy type with LeRobot)
from lerobot_dcdp.policy.configuration_dcdp import CORRECTIONS, EXECUTION_MODES, DCDPConfig


def train_corrector(
    base: Path, repo_id: str, root: Path | None, steps: int, batch_size: int, out: Path, **overrides
) -> Path:
    """Train a DCDP corrector for ``base`` on a dataset and save it.

    Args:
        base: The pretrained chunking policy (a ``pretrained_model`` directory); it stays frozen.
        repo_id: Dataset repo id (read from ``root``, or from the local Hugging Face cache when ``root``
            is ``None``).
        root: Dataset directory.
        steps: Optimiser steps.
        batch_size: Samples per step.
        out: Where the corrector is saved (weights, config, processors).
        **overrides: Any ``DCDPConfig`` field, e.g. ``feature_dim=32`` or
            ``anchor_feature="observation.environment_state"``.

    Returns:
        ``out``.
    """
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    cfg = DCDPConfig(base_policy_path=str(base), device="cpu", push_to_hub=False, **overrides)
    policy = make_policy(cfg, ds_meta=meta)  # loads and freezes the base, checks it against the features
    preprocessor, postprocessor = make_pre_post_processors(cfg, dataset_stats=meta.stats)  # the base's

    # every sample carries the observation window and action chunk the corrector learns from
    dataset = LeRobotDataset(repo_id, root=root, delta_timestamps=resolve_delta_timestamps(cfg, meta))
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=True, drop_last=True)
    optimizer = cfg.get_optimizer_preset().build(policy.get_optim_params())

    policy.train()
    for step, batch in zip(range(1, steps + 1), itertools.cycle(loader), strict=False):
        loss, info = policy.forward(preprocessor(batch))
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.get_optim_params(), cfg.optimizer_grad_clip_norm)
        optimizer.step()
        optimizer.zero_grad()
        if step == 1 or step == steps or step % 50 == 0:
            print(f"step {step}/{steps}  loss {loss.item():.4f}")

    policy.save_pretrained(out)
    preprocessor.save_pretrained(out)
    postprocessor.save_pretrained(out)
    return out


@torch.no_grad()
def run_every_mode(corrector: Path, repo_id: str, root: Path | None, episode: int = 0) -> dict[str, dict]:
    """Run the saved corrector in every execution mode on the recorded observations of one episode.

    Returns:
        ``{mode: {"mae": mean |action - recorded action|, "ms": mean ms per step}}``; ``object_anchored``
        only when the corrector names an ``anchor_feature``.
    """
    from lerobot.configs import PreTrainedConfig

    cfg = PreTrainedConfig.from_pretrained(corrector)
    cfg.pretrained_path = corrector
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    policy = make_policy(cfg, ds_meta=meta)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(cfg, pretrained_path=str(corrector))
    dataset = LeRobotDataset(repo_id, root=root, episodes=[episode])
    inputs = [k for k in cfg.input_features if k in meta.features]

    results = {}
    for mode in EXECUTION_MODES:
        if mode == "object_anchored" and not cfg.anchor_feature:
            continue
        policy.config.execution = mode
        policy.reset()
        errors, times = [], []
        for frame in dataset:
            observation = {k: frame[k] for k in inputs}  # what a robot or env would report
            t0 = time.perf_counter()
            action = postprocessor(policy.select_action(preprocessor(observation)))
            times.append(time.perf_counter() - t0)
            errors.append((action.squeeze(0) - frame["action"]).abs().mean().item())
        results[mode] = {"mae": sum(errors) / len(errors), "ms": 1e3 * sum(times) / len(times)}
        print(
            f"{mode:18s} |action - recorded| {results[mode]['mae']:8.3f}  {results[mode]['ms']:6.1f} ms/step"
        )
    return results


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("base", type=Path, help="pretrained chunking policy directory (stays frozen)")
    p.add_argument("--repo-id", required=True, help="LeRobotDataset repo id, e.g. local/pusht_expert")
    p.add_argument("--root", type=Path, default=None, help="dataset directory (default: HF cache)")
    p.add_argument("--out", type=Path, required=True, help="where to save the corrector")
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--feature-dim", type=int, default=128, help="corrector width (32 for a quick try)")
    p.add_argument(
        "--anchor-feature",
        default=None,
        help="object xy keypoints key: synthesised motion for `residual` on demonstrations, object_anchored",
    )
    p.add_argument(
        "--correction",
        choices=CORRECTIONS,
        default="residual",
        help="residual (default: plan + learned correction) or reconstruct (paper; measured to hurt)",
    )
    args = p.parse_args(argv)
    if not (args.base / "config.json").is_file():
        p.error(f"{args.base} is not a pretrained policy directory (no config.json)")
    if args.steps < 1 or args.batch_size < 1:
        p.error("--steps and --batch-size must be >= 1")
    if args.correction == "residual" and not args.anchor_feature:
        meta = LeRobotDatasetMetadata(args.repo_id, root=args.root)
        if "observation.dcdp_plan" not in meta.features:
            p.error(
                "--correction residual on plain demonstrations needs --anchor-feature (the observation key "
                "holding the object's xy keypoints), or a dataset recorded by dcdp-record-corrections"
            )
    heads = 8 if args.feature_dim % 8 == 0 else 1
    corrector = train_corrector(
        args.base,
        args.repo_id,
        args.root,
        args.steps,
        args.batch_size,
        args.out,
        feature_dim=args.feature_dim,
        n_heads=heads,
        anchor_feature=args.anchor_feature,
        correction=args.correction,
        # synthesised motion moves the anchor keypoints only: the corrector reads those
        observation_features=[args.anchor_feature] if args.anchor_feature else [],
    )
    print(f"corrector saved to {corrector}")
    run_every_mode(corrector, args.repo_id, args.root)


if __name__ == "__main__":
    main()
