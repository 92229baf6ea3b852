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

A robot whose state ``lerobot-rollout`` flattened into one ``observation.state`` (``pusht_sim``: agent and
block keypoints, 18 values) is cut back into the base's vector inputs (``dcdp_split_state``'s rule). The
recorded action is kept as ``executed_action``. Vector observations only (no camera features yet).

    dcdp-dagger-to-corrections --base models/pusht-diffusion-state --repo-id user/rollout_dagger \\
        --root data/rollout_dagger --out-repo-id local/dagger_corrections --out-root data/dagger_corrections
"""

from __future__ import annotations

import argparse
import sys
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


def _vector_splits(base_config, features: dict) -> list[tuple[str, int]] | None:
    """The base's vector inputs as ``dcdp_split_state`` splits when the dataset flattened them into
    ``observation.state``; ``None`` when the dataset already holds every one."""
    from lerobot_dcdp.policy.processor_split_state import VECTOR_FEATURE_TYPES

    vectors = [
        (k, int(f.shape[0])) for k, f in base_config.input_features.items() if f.type in VECTOR_FEATURE_TYPES
    ]
    others = [k for k, f in base_config.input_features.items() if f.type not in VECTOR_FEATURE_TYPES]
    if others:
        raise ValueError(f"the base reads {others}; dcdp-dagger-to-corrections handles vector inputs only")
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
    features: dict, first: dict, keys: list[str], as_recorded: bool, plan_width: int
) -> dict[str, dict]:
    """The corrections dataset's features: the base's inputs ``keys`` (as recorded, names kept, when
    ``as_recorded``; else float32 of ``first``'s shapes), the plan and its step, the label ``action``,
    ``executed_action`` and ``intervention``."""
    action_dim = int(features["action"]["shape"][0])
    spec = {k: {"dtype": "float32", "shape": tuple(first[k].shape), "names": None} for k in keys}
    if as_recorded:
        spec = {k: {**features[k], "shape": tuple(features[k]["shape"])} for k in keys}
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


def _write_episode(
    out, frames: list[dict], rows: np.ndarray, plans: np.ndarray, keys: list[str], horizon: int, label: str
) -> tuple[int, int]:
    """Add one episode's frames (indices ``rows`` of ``frames``) to ``out`` with their chunk's plan, step and
    label (:func:`chunk_starts`; ``label`` is ``--autonomous-label``) and save it; returns its intervention
    frames and chunks."""
    action_dim = int(frames[rows[0]]["action"].shape[-1])
    chunk_length = plans.shape[1] // action_dim
    taken = np.array([bool(frames[i][INTERVENTION].reshape(-1)[0]) for i in rows])
    starts = rows[chunk_starts(taken, horizon)]
    for i, start, person in zip(rows, starts, taken, strict=True):
        step = int(i - start)
        plan = plans[start]
        executed = frames[i]["action"].numpy().astype(np.float32)
        target = executed if person or label == "executed" else plan.reshape(chunk_length, action_dim)[step]
        out.add_frame(
            {
                **{k: frames[i][k].numpy().astype(np.float32) for k in keys},
                "observation.dcdp_plan": plan,
                "observation.dcdp_plan_step": np.array([step], dtype=np.float32),
                "action": np.asarray(target, dtype=np.float32),
                "executed_action": executed,
                INTERVENTION: np.array([person]),
                "task": frames[i]["task"],
            }
        )
    out.save_episode()
    return int(taken.sum()), len(np.unique(starts))


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
    split = None if splits is None else SplitStateProcessorStep(splits=splits)
    keys = [k for k, _ in splits] if splits else list(base_cfg.input_features)

    def transform(frame: dict) -> dict:
        if split is None:
            return frame
        return {**frame, **split.observation({"observation.state": frame["observation.state"]})}

    plans = base_plans(str(base_path), dataset, seed=seed, transform=transform)  # (N, L * A) at every frame
    chunk_length = plans.shape[1] // int(features["action"]["shape"][0])
    if horizon > chunk_length:
        raise ValueError(f"n_action_steps={horizon} exceeds the base's chunk of {chunk_length} actions")
    frames = [transform(dataset[i]) for i in range(len(dataset))]
    episode_of = np.array([int(f["episode_index"]) for f in frames])
    spec = _corrections_features(features, frames[0], keys, split is None, plans.shape[1])
    counts = {"episodes": 0, "frames": 0, "intervention_frames": 0, "chunks": 0}
    with staged_dir(Path(out_root)) as built:
        out = LeRobotDataset.create(
            repo_id=out_repo_id,
            fps=dataset.fps,
            features=spec,
            root=built,
            robot_type=dataset.meta.robot_type,
            use_videos=False,
        )
        for e in np.unique(episode_of):
            rows = np.flatnonzero(episode_of == e)
            by_person, chunks = _write_episode(out, frames, rows, plans, keys, horizon, autonomous_label)
            counts["episodes"] += 1
            counts["frames"] += len(rows)
            counts["intervention_frames"] += by_person
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
