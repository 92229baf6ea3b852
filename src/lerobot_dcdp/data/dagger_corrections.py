"""``dcdp-dagger-to-corrections``: a ``lerobot-rollout --strategy.type=dagger`` recording as corrections.

LeRobot's DAgger strategy records the robot's observation, the action sent and ``intervention`` (``True``
while the person drives through the teleoperator). The ``residual`` corrector trains on frames that also say
which chunk was being executed and at which step (docs/METHOD.md); the recording does not hold them, so this
command rebuilds them with the frozen base:

- **chunk boundaries**: the policy plans at an episode's first frame, every ``n_action_steps`` frames after,
  and again at the first autonomous frame after an intervention (LeRobot's engine replans when it takes
  over again); frames of an intervention belong to the chunk that was running when it began, counted on;
- **plans**: the base's chunk from the observation at each chunk start, with its own observation history
  (:func:`~lerobot_dcdp.data.precompute_plans.base_plans`; a diffusion base draws a fresh sample of the chunk
  it executed, ACT recomputes it exactly), stored flat as ``observation.dcdp_plan`` with
  ``observation.dcdp_plan_step``;
- **labels** (``action``): the person's action on intervention frames; on autonomous frames the planned
  action itself (``--autonomous-label=plan``: the person let the robot go on, so the chunk needed no
  correction) or the action the robot sent (``executed``: when a trained corrector drove, its own output).

The base's inputs are copied: vectors, and cameras (RGB ``image`` or ``video`` features, kept as recorded:
dtype, shape, names; a video camera is re-encoded, so a person's DAgger session on a camera robot trains an
image corrector too). A robot whose state ``lerobot-rollout`` flattened into one ``observation.state``
(``pusht_sim``: agent and block keypoints, 18 values) is cut back into the base's vector inputs
(``dcdp_split_state``'s rule). The recorded action is kept as ``executed_action``. A base input of any other
kind (language, depth maps, ...) is refused by name.

    dcdp-dagger-to-corrections --base models/pusht-diffusion-state --repo-id user/rollout_dagger \\
        --root data/rollout_dagger --out-repo-id local/dagger_corrections --out-root data/dagger_corrections
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from lerobot_dcdp.data.atomic_dataset import staged_dir

INTERVENTION = "intervention"
AUTONOMOUS_LABELS = ("plan", "executed")


def chunk_starts(intervention: np.ndarray, horizon: int) -> np.ndarray:
    """For every frame of one episode, the index of the frame whose observation planned its chunk.

    Args:
        intervention: (T,) bool, ``True`` where the person drove.
        horizon: Actions executed per chunk (``n_action_steps``).
    """
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1, got {horizon}")
    starts = np.zeros(len(intervention), dtype=np.int64)
    start = 0
    for t in range(len(intervention)):
        resumed = t > 0 and intervention[t - 1] and not intervention[t]
        if t == 0 or resumed or t - start >= horizon:
            start = t
        starts[t] = start
    return starts


def _cameras(base_config, features: dict) -> list[str]:
    """The base's camera inputs, each an RGB ``image`` or ``video`` feature of the recording.

    Raises:
        ValueError: a camera the recording lacks, stores as something else, or that is not RGB (a depth map).
    """
    from lerobot.configs.types import FeatureType

    cameras = [k for k, f in base_config.input_features.items() if f.type is FeatureType.VISUAL]
    recorded = sorted(k for k, f in features.items() if f["dtype"] in ("image", "video"))
    for key in cameras:
        if key not in features:
            raise ValueError(
                f"the base reads the camera {key!r}, which the recording lacks (its cameras: {recorded})"
            )
        ft = features[key]
        shape = tuple(ft["shape"])
        if ft["dtype"] not in ("image", "video"):
            raise ValueError(f"the base reads {key!r} as a camera; the recording stores it as {ft['dtype']}")
        if (ft.get("info") or {}).get("is_depth_map") or len(shape) != 3 or 3 not in (shape[0], shape[2]):
            raise ValueError(
                f"the recording's camera {key!r} ({ft['dtype']} of shape {shape}) is not an RGB image: "
                "dcdp-dagger-to-corrections copies RGB cameras only (no depth maps)"
            )
    return cameras


def _vector_splits(base_config, features: dict) -> list[tuple[str, int]] | None:
    """The base's vector inputs as ``dcdp_split_state`` splits when the dataset flattened them into
    ``observation.state``; ``None`` when the dataset already holds every one.

    Raises:
        ValueError: a base input that is neither a vector nor a camera (named), or a recording whose
            ``observation.state`` cannot be cut into the base's vectors.
    """
    from lerobot.configs.types import FeatureType

    from lerobot_dcdp.policy.processor_split_state import VECTOR_FEATURE_TYPES

    vectors = [
        (k, int(f.shape[0])) for k, f in base_config.input_features.items() if f.type in VECTOR_FEATURE_TYPES
    ]
    copied = (*VECTOR_FEATURE_TYPES, FeatureType.VISUAL)
    others = {k: f.type.value for k, f in base_config.input_features.items() if f.type not in copied}
    if others:
        raise ValueError(
            f"the base reads {others}; dcdp-dagger-to-corrections copies vector (STATE, ENV) and camera "
            "(VISUAL) inputs only"
        )
    if all(k in features for k, _ in vectors):
        return None
    vectors.sort(key=lambda kv: kv[0] != "observation.state")
    total = sum(d for _, d in vectors)
    width = int(features.get("observation.state", {}).get("shape", (0,))[0])
    if vectors[0][0] != "observation.state" or width != total:
        raise ValueError(
            f"the recording lacks {[k for k, _ in vectors if k not in features]} and its observation.state "
            f"is {width} wide, not the {total} of the base's inputs {vectors} concatenated"
        )
    return vectors


def _open_recording(
    base_path: str | Path,
    repo_id: str,
    root: str | Path,
    out_root: str | Path,
    n_action_steps: int | None,
    autonomous_label: str,
    force: bool,
):
    """Check :func:`dagger_to_corrections`' arguments; returns the recording (a ``LeRobotDataset``), the
    base's config and the chunk horizon (``n_action_steps``, default the base's)."""
    import lerobot.policies  # noqa: F401  (registers every LeRobot policy config type)
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if autonomous_label not in AUTONOMOUS_LABELS:
        raise ValueError(f"autonomous_label must be one of {AUTONOMOUS_LABELS}, got {autonomous_label!r}")
    base_path, out_root = Path(base_path), Path(out_root)
    if not (base_path / "config.json").is_file():
        raise ValueError(f"--base {base_path} (resolved {base_path.resolve()}) holds no config.json")
    if out_root.exists() and not force:
        raise FileExistsError(f"{out_root} exists; pass --force to replace it")
    dataset = LeRobotDataset(repo_id, root=root)
    if INTERVENTION not in dataset.meta.features:
        raise ValueError(
            f"{repo_id} has no {INTERVENTION!r} column: record it with lerobot-rollout --strategy.type=dagger"
        )
    base_cfg = PreTrainedConfig.from_pretrained(base_path)
    horizon = int(n_action_steps or base_cfg.n_action_steps)
    if horizon < 1:
        raise ValueError(f"n_action_steps must be >= 1, got {horizon}")
    return dataset, base_cfg, horizon


def _corrections_features(
    features: dict, first: dict, keys: list[str], cameras: list[str], as_recorded: bool, plan_width: int
) -> dict[str, dict]:
    """The corrections dataset's features: the base's vector inputs ``keys`` (as recorded, names kept, when
    ``as_recorded``; else float32 of ``first``'s shapes), its ``cameras`` (as recorded: dtype, shape, names;
    the video ``info`` is rewritten by the encoder), the plan and its step, the label ``action``,
    ``executed_action`` and ``intervention``."""
    action_dim = int(features["action"]["shape"][0])
    spec = {k: {"dtype": "float32", "shape": tuple(first[k].shape), "names": None} for k in keys}
    if as_recorded:
        spec = {k: {**features[k], "shape": tuple(features[k]["shape"])} for k in keys}
    for k in cameras:
        spec[k] = {
            "dtype": features[k]["dtype"],
            "shape": tuple(features[k]["shape"]),
            "names": features[k]["names"],
        }
    spec.update(
        {
            "observation.dcdp_plan": {"dtype": "float32", "shape": (plan_width,), "names": None},
            "observation.dcdp_plan_step": {"dtype": "float32", "shape": (1,), "names": None},
            "action": {**features["action"], "shape": (action_dim,)},
            "executed_action": {**features["action"], "shape": (action_dim,)},
            INTERVENTION: {"dtype": "bool", "shape": (1,), "names": None},
        }
    )
    return spec


def _camera_frame(image: torch.Tensor) -> np.ndarray:
    """A camera frame as ``LeRobotDataset`` returns it, (C, H, W) float in [0, 1], as (H, W, C) uint8.

    Rounded here: ``add_frame`` would truncate ``x * 255`` and darken a shade on the way (an ``image`` camera
    is copied exactly this way).
    """
    return (image.clamp(0, 1) * 255).round().to(torch.uint8).permute(1, 2, 0).numpy()


def _write_episode(
    out,
    read: Callable[[int], dict],
    rows: np.ndarray,
    taken: np.ndarray,
    plans: np.ndarray,
    keys: list[str],
    cameras: list[str],
    horizon: int,
    label: str,
) -> int:
    """Add one episode's frames (``read(i)`` for ``i`` in ``rows``, ``taken``: the person drove) to ``out``
    with their chunk's plan, step and label (:func:`chunk_starts`; ``label`` is ``--autonomous-label``) and
    save it; returns its chunks."""
    starts = rows[chunk_starts(taken, horizon)]
    for i, start, person in zip(rows, starts, taken, strict=True):
        frame = read(int(i))
        step = int(i - start)
        plan = plans[start]
        executed = frame["action"].numpy().astype(np.float32)
        target = executed if person or label == "executed" else plan.reshape(-1, executed.shape[-1])[step]
        out.add_frame(
            {
                **{k: frame[k].numpy().astype(np.float32) for k in keys},
                **{k: _camera_frame(frame[k]) for k in cameras},
                "observation.dcdp_plan": plan,
                "observation.dcdp_plan_step": np.array([step], dtype=np.float32),
                "action": np.asarray(target, dtype=np.float32),
                "executed_action": executed,
                INTERVENTION: np.array([person]),
                "task": frame["task"],
            }
        )
    out.save_episode()
    return len(np.unique(starts))


def dagger_to_corrections(
    base_path: str | Path,
    repo_id: str,
    root: str | Path,
    out_repo_id: str,
    out_root: str | Path,
    n_action_steps: int | None = None,
    autonomous_label: str = "plan",
    seed: int = 0,
    force: bool = False,
) -> dict:
    """Write the corrections dataset of a DAgger recording; see the module docstring.

    Args:
        base_path: The frozen base's ``pretrained_model`` folder.
        repo_id: The DAgger recording's repo id.
        root: The DAgger recording's folder.
        out_repo_id: The corrections dataset's repo id.
        out_root: Where the corrections dataset goes (written whole, then moved into place).
        n_action_steps: Actions executed per chunk (default: the base's ``n_action_steps``).
        autonomous_label: The label of autonomous frames: ``plan`` or ``executed``.
        seed: Seeds the base's sampling noise.
        force: Replace an existing ``out_root``.

    Returns:
        Counts: ``episodes``, ``frames``, ``intervention_frames``, ``chunks``.

    Raises:
        ValueError: a recording without ``intervention``, inputs the base cannot read, bad arguments.
        FileExistsError: ``out_root`` exists and ``force`` is not set.
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.precompute_plans import base_plans
    from lerobot_dcdp.policy.processor_split_state import SplitStateProcessorStep

    dataset, base_cfg, horizon = _open_recording(
        base_path, repo_id, root, out_root, n_action_steps, autonomous_label, force
    )
    features = dataset.meta.features
    splits = _vector_splits(base_cfg, features)
    cameras = _cameras(base_cfg, features)
    split = None if splits is None else SplitStateProcessorStep(splits=splits)
    keys = [k for k, _ in splits] if splits else [k for k in base_cfg.input_features if k not in cameras]

    def transform(frame: dict) -> dict:
        if split is None:
            return frame
        return {**frame, **split.observation({"observation.state": frame["observation.state"]})}

    plans = base_plans(str(base_path), dataset, seed=seed, transform=transform)  # (N, L * A) at every frame
    chunk_length = plans.shape[1] // int(features["action"]["shape"][0])
    if horizon > chunk_length:
        raise ValueError(f"n_action_steps={horizon} exceeds the base's chunk of {chunk_length} actions")

    def read(i: int) -> dict:
        return transform(dataset[i])

    # frames are read one at a time while written (a camera recording does not fit in memory)
    episode_of = np.asarray(dataset.hf_dataset["episode_index"]).reshape(-1)
    person = np.asarray(dataset.hf_dataset[INTERVENTION]).reshape(-1).astype(bool)
    spec = _corrections_features(features, read(0), keys, cameras, split is None, plans.shape[1])
    counts = {"episodes": 0, "frames": 0, "intervention_frames": 0, "chunks": 0}
    with staged_dir(Path(out_root)) as built:
        out = LeRobotDataset.create(
            repo_id=out_repo_id,
            fps=dataset.fps,
            features=spec,
            root=built,
            robot_type=dataset.meta.robot_type,
            use_videos=any(features[k]["dtype"] == "video" for k in cameras),
        )
        for e in np.unique(episode_of):
            rows = np.flatnonzero(episode_of == e)
            taken = person[rows]
            chunks = _write_episode(out, read, rows, taken, plans, keys, cameras, horizon, autonomous_label)
            counts["episodes"] += 1
            counts["frames"] += len(rows)
            counts["intervention_frames"] += int(taken.sum())
            counts["chunks"] += chunks
        out.finalize()
    return counts


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-dagger-to-corrections", description=__doc__.splitlines()[0])
    p.add_argument("--base", required=True, help="the frozen base's pretrained_model directory")
    p.add_argument("--repo-id", required=True, help="the DAgger recording's repo id")
    p.add_argument("--root", required=True, help="the DAgger recording's directory")
    p.add_argument("--out-repo-id", required=True, help="the corrections dataset's repo id")
    p.add_argument("--out-root", required=True, help="where the corrections dataset goes")
    p.add_argument("--n-action-steps", type=int, default=None, help="actions per chunk (default: the base's)")
    p.add_argument(
        "--autonomous-label",
        default="plan",
        choices=AUTONOMOUS_LABELS,
        help="label of the frames the robot drove: the planned action (plan, default) or the action it sent "
        "(executed: a trained corrector drove)",
    )
    p.add_argument("--seed", type=int, default=0, help="seeds the base's sampling noise")
    p.add_argument("--force", action="store_true", help="replace --out-root if it exists")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    try:
        counts = dagger_to_corrections(
            a.base,
            a.repo_id,
            a.root,
            a.out_repo_id,
            a.out_root,
            a.n_action_steps,
            a.autonomous_label,
            a.seed,
            a.force,
        )
    except (FileExistsError, ValueError) as err:
        sys.exit(f"dcdp-dagger-to-corrections: error: {err}")
    out = Path(a.out_root).resolve()
    print(
        f"wrote {counts['episodes']} episodes ({counts['frames']} frames, {counts['intervention_frames']} by "
        f"the person, {counts['chunks']} chunks) to {out} as repo id {a.out_repo_id}\n"
        f"train a corrector on it:\n  lerobot-train --policy.type=dcdp --policy.base_policy_path={a.base} "
        f"--dataset.repo_id={a.out_repo_id} --dataset.root={out} --batch_size=128 --steps=1000 "
        "--policy.push_to_hub=false --output_dir=runs/dcdp"
    )


if __name__ == "__main__":
    main()
