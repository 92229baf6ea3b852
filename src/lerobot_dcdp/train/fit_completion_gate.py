"""``dcdp-fit-completion-gate``: a completion gate fitted on demonstrations, as a new policy folder.

The gate (``completion_gate.py``) learns where a demonstration is nearly done -- the object's keypoints
(``anchor_feature``) within a radius of their place on the episode's last frame: ``--radius-fraction``
(default 0.15) of how far the object typically travels to its end in these demonstrations, or ``--radius`` in
the keypoints' own units -- from the state features the policy reads, normalised as the base normalises them.

- ``--policy <corrector>``: the gate of a trained corrector. Everything else of the corrector is copied
  unchanged (``config.json`` gets ``completion_gate=true``, the weights the gate's).
- ``--base <base> --anchor-feature <key>``: no corrector training. The folder wraps the bare base for the
  training-free ``object_anchored`` execution (its default there) with the gate: the plan carried along with
  the object's motion, left as planned where the task is nearly done. Its corrector is a fresh, minimal one
  (some kilobytes): exactly the base's plan (``--policy.execution=dcdp`` runs open loop, in the led scene).

Both set the scene lead (``scene_lead.py``: plan in a scene moved ``lead_steps`` steps of the object's own
motion ahead, so a drifting object is stopped upstream and carried into the goal) to the folder's
``n_action_steps``; ``--lead-steps 0`` leaves it off (a folder whose base cannot be led -- no
``anchor_feature``, the robot's xy not among the base's inputs, or images -- gets none, and the fit says why).
With a lead, ``lead_noise`` is the object tracker's per-step jitter, measured on the demonstrations' still
steps (``scene_lead.tracker_noise``; 0 in simulation).

The new folder appears only when complete and loads with ``--policy.path`` like any corrector.

    dcdp-fit-completion-gate --policy models/pusht-dcdp-state-teleop --repo-id local/pusht_expert \\
        --root data/pusht_expert --out models/pusht-dcdp-state-teleop-gated
    dcdp-fit-completion-gate --base models/pusht-act-state --anchor-feature observation.environment_state \\
        --repo-id local/pusht_expert --root data/pusht_expert --out runs/pusht-act-anchored-gated
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from lerobot_dcdp.data.atomic_dataset import staged_dir
from lerobot_dcdp.model.completion_gate import CompletionGate, completion_labels, travel_scale
from lerobot_dcdp.model.scene_lead import tracker_noise
from lerobot_dcdp.policy.base_policy import portable_base_reference


def gate_data(policy, dataset) -> tuple[Tensor, Tensor, Tensor]:
    """Inputs (T, D) of ``policy``'s gate for every frame of ``dataset``, the frames' episode indices (T,)
    and the object's raw keypoints (T, N, 2)."""
    config = policy.config
    if not config.anchor_feature:
        raise ValueError(
            "the completion gate's labels need the object's keypoints: the corrector has no anchor_feature"
        )
    keys = list(dict.fromkeys([*policy.completion_gate.keys, config.anchor_feature]))
    missing = [k for k in keys if k not in dataset.meta.features]
    if missing:
        raise ValueError(f"the dataset has no {missing} (it has {sorted(dataset.meta.features)})")
    table = dataset.hf_dataset.with_format("numpy")
    raw = {k: torch.as_tensor(np.stack(table[k]), dtype=torch.float32) for k in keys}
    episodes = torch.as_tensor(np.asarray(table["episode_index"]), dtype=torch.long)
    order = torch.as_tensor(np.asarray(table["index"]), dtype=torch.long).argsort(stable=True)
    raw = {k: v[order] for k, v in raw.items()}
    x = torch.cat([policy.normalizer(k, raw[k]) for k in policy.completion_gate.keys], dim=-1)
    anchor = raw[config.anchor_feature]
    if anchor.shape[-1] % 2:
        raise ValueError(
            f"anchor_feature {config.anchor_feature!r} has {anchor.shape[-1]} values per frame: the gate's "
            "labels read it as (x, y) keypoints, so it needs an even number"
        )
    points = anchor.reshape(len(episodes), -1, 2)
    return x, episodes[order], points


def fit_gate(
    gate: CompletionGate,
    x: Tensor,
    near: Tensor,
    episodes: Tensor,
    steps: int = 3000,
    lr: float = 1e-3,
    val_fraction: float = 0.1,
    seed: int = 0,
) -> dict[str, float]:
    """Train ``gate`` on inputs ``x`` (T, D) and labels ``near`` (T,) with full-batch Adam on the binary
    cross-entropy, a ``val_fraction`` of the episodes held out (rounded down, so a small dataset may hold
    none out).

    Returns:
        ``loss``, ``train_accuracy``, ``near_rate`` (over all frames), ``val_episodes`` (how many were held
        out) and on the held-out frames ``val_accuracy``, ``val_near_recall`` and ``val_far_accuracy``: NaN
        where there is no such frame (no episode held out, or none of its frames near / far).

    Raises:
        ValueError: ``val_fraction`` holds out every episode.
    """
    generator = torch.Generator().manual_seed(seed)
    ids = episodes.unique()
    held = ids[torch.randperm(len(ids), generator=generator)[: int(val_fraction * len(ids))]]
    val = torch.isin(episodes, held)
    if val.all():
        raise ValueError(f"val_fraction {val_fraction} leaves no episode of {len(ids)} to train on")
    train = ~val
    target = near.float()
    torch.manual_seed(seed)
    for p in gate.parameters():  # a fresh start, reproducible from ``seed``
        if p.ndim > 1:
            torch.nn.init.kaiming_uniform_(p, a=5**0.5)
        else:
            torch.nn.init.zeros_(p)
    optimizer = torch.optim.Adam(gate.parameters(), lr=lr)
    for _ in range(steps):
        loss = torch.nn.functional.binary_cross_entropy_with_logits(gate.logit(x[train]), target[train])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        guess = gate.logit(x) > 0

    def accuracy(mask: Tensor) -> float:
        return float((guess[mask] == near[mask]).float().mean()) if mask.any() else float("nan")

    return {
        "loss": float(loss.detach()),
        "train_accuracy": accuracy(train),
        "val_accuracy": accuracy(val),
        "near_rate": float(target.mean()),
        "val_near_recall": accuracy(val & near),
        "val_far_accuracy": accuracy(val & ~near),
        "val_episodes": len(held),
    }


#: the corrector a ``--base`` folder carries only to load as a DCDP policy: the smallest the config allows
UNUSED_CORRECTOR = dict(
    feature_dim=8,
    n_heads=1,
    state_hidden_dim=8,
    latent_dim=2,
    encoder_hidden_dim=8,
    decoder_hidden_dim=8,
    step_embed_dim=4,
)


def gated_anchoring_policy(base: str, anchor_feature: str, dataset_meta, n_action_steps: int | None = None):
    """A DCDP policy around the bare ``base`` that runs ``object_anchored`` on ``anchor_feature`` with a
    (not yet fitted) completion gate, executing ``n_action_steps`` per chunk (default: the base's own, else
    DCDP's default). Its fresh corrector
    (``UNUSED_CORRECTOR``'s sizes) and the gate read the state features the base reads, plus the anchor
    feature; the corrector is exactly the base's plan (the residual head starts at zero).

    Raises:
        ValueError: the anchor feature is not in the dataset, or the base and the dataset do not fit together.
    """
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.configs.types import FeatureType
    from lerobot.policies.factory import make_policy
    from lerobot.utils.feature_utils import dataset_to_policy_features

    from lerobot_dcdp.policy.base_policy import resolve_base_reference
    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig

    features = dataset_to_policy_features(dataset_meta.features)
    if anchor_feature not in features:
        raise ValueError(
            f"--anchor-feature {anchor_feature!r} is not a feature of the dataset ({sorted(features)})"
        )
    base_config = PreTrainedConfig.from_pretrained(resolve_base_reference(base))
    reads = set(base_config.input_features or {}) | {anchor_feature}
    state = [k for k, f in features.items() if f.type in (FeatureType.STATE, FeatureType.ENV) and k in reads]
    config = DCDPConfig(
        base_policy_path=str(Path(base).resolve()) if Path(base).is_dir() else base,
        anchor_feature=anchor_feature,
        execution="object_anchored",
        n_action_steps=n_action_steps or getattr(base_config, "n_action_steps", None) or 8,
        completion_gate=True,
        observation_features=state,
        **UNUSED_CORRECTOR,
        device="cpu",
        push_to_hub=False,
    )
    return make_policy(config, ds_meta=dataset_meta)


def set_lead(policy, lead_steps: int | None) -> str:
    """Set ``policy``'s scene lead: ``lead_steps``, or by default its ``n_action_steps`` where the base can be
    led (an anchor feature, the robot's xy among the base's inputs, no image; else 0). Returns what was set.

    Raises:
        ValueError: an explicit lead > 0 the policy cannot run.
    """
    from lerobot_dcdp.model.scene_lead import check_lead_features

    config = policy.config
    explicit = lead_steps is not None
    steps = lead_steps if explicit else config.n_action_steps
    try:
        if steps and not config.anchor_feature:
            raise ValueError("a scene lead needs a folder with an anchor_feature (the object's keypoints)")
        if steps:
            check_lead_features(config, dict(policy.base.config.input_features or {}), policy.normalizer)
    except ValueError as e:
        if explicit:
            raise
        config.lead_steps = 0
        return f"no scene lead ({e})"
    config.lead_steps = steps
    return f"scene lead {steps} steps" if steps else "no scene lead"


def build_parser() -> argparse.ArgumentParser:
    """``dcdp-fit-completion-gate``'s flags."""
    p = argparse.ArgumentParser(prog="dcdp-fit-completion-gate", description=__doc__.splitlines()[0])
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--policy", help="a trained corrector's pretrained_model folder: gate its corrections")
    what.add_argument(
        "--base", help="a bare base (pretrained_model folder or Hub id): gate the training-free anchoring"
    )
    p.add_argument(
        "--anchor-feature", help="with --base: the observation key of the object's xy keypoints (needed)"
    )
    p.add_argument(
        "--n-action-steps",
        type=int,
        help="with --base: actions executed per chunk (default: the base's own n_action_steps, else 8)",
    )
    p.add_argument(
        "--lead-steps",
        type=int,
        help="the scene lead in planned steps (default: the folder's n_action_steps where it has an "
        "anchor_feature; 0: off)",
    )
    p.add_argument("--repo-id", required=True, help="demonstrations (LeRobotDataset repo id)")
    p.add_argument("--root", required=True, help="the demonstrations' local folder")
    p.add_argument("--out", required=True, help="the new policy folder (must not exist)")
    near = p.add_mutually_exclusive_group()
    near.add_argument(
        "--radius-fraction",
        type=float,
        default=0.15,
        help="'nearly done': within this fraction of the object's typical travel to its end (default 0.15)",
    )
    near.add_argument("--radius", type=float, help="'nearly done' in the keypoints' own units instead")
    p.add_argument("--steps", type=int, default=3000, help="full-batch Adam steps of the fit (default 3000)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam's learning rate (default 1e-3)")
    p.add_argument(
        "--val-fraction",
        type=float,
        default=0.1,
        help="share of the episodes held out for the accuracy, rounded down (default 0.1; 0: fit on all)",
    )
    p.add_argument(
        "--seed", type=int, default=0, help="seeds the held-out split, the gate's start and a --base folder"
    )
    return p


def _check_flags(a: argparse.Namespace) -> None:
    """Exit with one message for flags that do not go together or are out of range."""
    if a.radius is None and not 0 < a.radius_fraction < 1:
        sys.exit(f"--radius-fraction must be in (0, 1), got {a.radius_fraction}")
    if a.radius is not None and not a.radius > 0:
        sys.exit(f"--radius must be > 0, got {a.radius}")
    if a.base is not None and not a.anchor_feature:
        sys.exit("--base needs --anchor-feature: the observation key of the object's xy keypoints")
    if a.policy is not None and (a.anchor_feature or a.n_action_steps):
        sys.exit("--anchor-feature and --n-action-steps go with --base; a corrector (--policy) keeps its own")
    if a.n_action_steps is not None and a.n_action_steps < 1:
        sys.exit(f"--n-action-steps must be >= 1, got {a.n_action_steps}")
    if a.lead_steps is not None and a.lead_steps < 0:
        sys.exit(f"--lead-steps must be >= 0 (0: no scene lead), got {a.lead_steps}")


def _gated_policy(a: argparse.Namespace, dataset):
    """The policy whose gate is fitted, with a fresh gate: the ``--policy`` corrector, or a
    :func:`gated_anchoring_policy` around ``--base``."""
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    if a.policy is not None:
        policy = DCDPPolicy.from_pretrained(str(a.policy))
        policy.config.completion_gate = True
        policy.completion_gate = CompletionGate(policy.state_dims)
        return policy
    torch.manual_seed(a.seed)  # the unused corrector too: the same command writes the same folder
    try:
        return gated_anchoring_policy(a.base, a.anchor_feature, dataset.meta, a.n_action_steps)
    except ValueError as e:
        sys.exit(f"--base {a.base} with the demonstrations {a.root}: {e}")


def _fit(policy, dataset, a: argparse.Namespace, lead: str) -> tuple[dict[str, float], str]:
    """Set the folder's completion radius (and the lead's tracker noise) and fit the gate; returns
    :func:`fit_gate`'s statistics, with ``radius``, ``frames`` and ``episodes`` added, and the lead's
    description."""
    x, episodes, points = gate_data(policy, dataset)
    radius = a.radius if a.radius is not None else a.radius_fraction * travel_scale(points, episodes)
    policy.config.completion_radius = radius
    if policy.config.lead_steps:  # the lead's tolerance for the tracker's jitter, from the same frames
        policy.config.lead_noise = tracker_noise(points, episodes)
        lead += f" (tracker noise {policy.config.lead_noise:.3g})"
    near = completion_labels(points, episodes, radius)
    stats = fit_gate(policy.completion_gate, x, near, episodes, a.steps, a.lr, a.val_fraction, a.seed)
    stats.update(radius=radius, frames=len(episodes), episodes=len(episodes.unique()))
    return stats, lead


def _write_folder(policy, source: Path | None, out: Path) -> None:
    """Write the gated policy folder to ``out`` (staged, moved into place when complete): a ``--policy``
    corrector's other files copied, a ``--base`` folder's processors made; the base recorded relative to
    ``out``."""
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    with staged_dir(out) as tmp:
        tmp.mkdir()
        if source is not None:  # the corrector's processors and the rest of its folder
            for f in source.iterdir():
                if f.is_file() and f.name not in ("config.json", "model.safetensors"):
                    shutil.copy2(f, tmp / f.name)
        else:  # the base's processors, as lerobot-train saves them beside a corrector
            for processor in make_dcdp_pre_post_processors(policy.config):
                processor.save_pretrained(tmp)
        policy.save_pretrained(tmp)
        # the base is recorded relative to the folder saved into; the folder's final place is ``out``
        saved = json.loads((tmp / "config.json").read_text())
        cfg = policy.config
        saved["base_policy_path"] = portable_base_reference(cfg.base_policy_path, cfg.pretrained_path, out)
        saved["pretrained_path"] = None  # the folder it is loaded from says where it is
        (tmp / "config.json").write_text(json.dumps(saved, indent=4))


def held_out_report(stats: dict[str, float], val_fraction: float) -> str:
    """The fit's accuracy in words: on the held-out episodes, or, where none was held out (``val_fraction``
    0 or too small for the number of episodes), on the training frames, saying so."""
    if not stats["val_episodes"]:
        why = (
            "--val-fraction 0"
            if val_fraction <= 0
            else f"--val-fraction {val_fraction:g} of {stats['episodes']} episodes rounds down to none"
        )
        return f"no held-out episode ({why}): training accuracy {stats['train_accuracy']:.3f}"

    def rate(name: str, none: str) -> str:
        return none if math.isnan(stats[name]) else f"{stats[name]:.3f}"

    return (
        f"{stats['val_episodes']} held-out episodes: accuracy {stats['val_accuracy']:.3f}, "
        f"near recalled {rate('val_near_recall', 'n/a (no near frame)')}, "
        f"far kept {rate('val_far_accuracy', 'n/a (no far frame)')}"
    )


def main(argv: list[str] | None = None) -> None:
    """``dcdp-fit-completion-gate``: fit the gate and write the new folder; a bad flag, input or dataset
    exits with one message and writes nothing."""
    a = build_parser().parse_args(argv)
    _check_flags(a)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    out = Path(a.out)
    if out.exists():
        sys.exit(f"--out {out} exists: give a new folder")
    if not (Path(a.root) / "meta" / "info.json").is_file():  # LeRobotDataset would create it and go online
        sys.exit(f"--root {a.root} holds no LeRobotDataset (no meta/info.json)")
    torch.set_num_threads(1)
    dataset = LeRobotDataset(a.repo_id, root=a.root)
    policy = _gated_policy(a, dataset)
    try:
        lead = set_lead(policy, a.lead_steps)
    except ValueError as e:
        sys.exit(f"--lead-steps {a.lead_steps}: {e}")
    try:
        stats, lead = _fit(policy, dataset, a, lead)
    except ValueError as e:
        sys.exit(f"cannot fit the completion gate on {a.root}: {e}")
    source = None if a.policy is None else Path(a.policy)
    _write_folder(policy, source, out)
    print(
        f"completion gate fitted on {stats['frames']} frames of {stats['episodes']} episodes "
        f"(radius {stats['radius']:.4g}, near: {100 * stats['near_rate']:.1f} %); "
        f"{held_out_report(stats, a.val_fraction)}; {lead}; "
        f"wrote {out}" + (" (object_anchored with the gate; no corrector)" if source is None else "")
    )


if __name__ == "__main__":
    main()
