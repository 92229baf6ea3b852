"""Record a corrections dataset: check the settings and the env, roll the base out in batches, write it.

Episodes are rolled out in groups that share the policy's execution mode and chunk delay: with ``max_delay``
D the base of episode ``seed + k`` answers d = k mod (D + 1) steps late; with ``anchored_when_drifting``
the episodes without drift are labelled with the plan itself and driven open loop (unless ``execution`` is
``dcdp``), and the others get the share of the correction :func:`~.rollout.label_weight` gives them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_dcdp.data.corrections.drift import DriftSpec, drift_specs, episode_env
from lerobot_dcdp.data.corrections.rollout import (
    label_weight,
    load_policy,
    recorded_keys,
    rollout_corrections,
)
from lerobot_dcdp.data.corrections.settings import RecordingSettings
from lerobot_dcdp.data.corrections.teachers import make_online_teacher
from lerobot_dcdp.data.corrections.writer import check_root, corrections_dataset, features, write_episode
from lerobot_dcdp.data.pusht_demos import FPS, TASK


def record_corrections(root: str | Path, repo_id: str = RecordingSettings.repo_id, **fields) -> dict:
    """Record stale chunks and teacher corrections to a LeRobotDataset at ``root``: :func:`record` with the
    :class:`~.settings.RecordingSettings` these arguments make (its fields, by keyword).

    Raises:
        ValueError: bad settings, seeds reaching the evaluation seeds, or an existing ``root`` that is not an
            earlier output of this command (or is one, without ``force``).
    """
    return record(RecordingSettings(root, repo_id, **fields))


def record(settings: RecordingSettings) -> dict:
    """Record ``settings.episodes`` episodes of stale chunks and teacher corrections to a LeRobotDataset at
    ``settings.root``.

    Returns:
        ``episodes``, ``frames``, ``root`` and the mean and 90th percentile of the teacher's correction of the
        plan (``mean_correction_px``, ``p90_correction_px``).

    Raises:
        ValueError: an existing ``root`` that is not an earlier output of this command (or is one, without
            ``force``), a policy or env that cannot be recorded (``max_delay`` beyond what the base plans, an
            env without the observations the policy or the teacher reads).
    """
    s = settings
    root = Path(s.root)
    check_root(root, s.force)
    drive = "open_loop" if s.execution == "teacher" else s.execution
    seeds = s.seeds
    specs = drift_specs(seeds, s.drifting, s.max_magnitude, s.static_fraction)
    raw_keys, observed = _probe_env(s.env_config, specs[0], s.max_steps, seeds[0])
    anchor_shape = observed.get(s.anchor_feature) if s.anchor_feature else None
    policy, pre, post = load_policy(s.policy_path, s.base_path, drive, s.anchor_feature, anchor_shape)
    horizon = _chunk_horizon(policy, s.max_delay)
    shapes = _stored_shapes(policy, observed)
    action_dim = int(policy.config.action_feature.shape[0])
    fps = FPS if s.env_config is None else s.env_config.fps
    task = TASK if s.drifting or s.env_config.type == "pusht" else s.env_config.task
    n_envs = min(s.batch_size, s.episodes)
    online = make_online_teacher(s.teacher, s.teleop_config, s.teacher_policy, n_envs, raw_keys)
    run = _Run(s, policy, pre, post, drive, seeds, specs, online, task)
    try:
        spec = features(horizon, action_dim, shapes)
        with corrections_dataset(root, s.repo_id, fps, spec, _marker(s)) as ds:
            frames, gap = _record_episodes(ds, run)
    finally:
        if online is not None:
            online.close()
    gap_all = np.concatenate(gap)
    return {
        "episodes": s.episodes,
        "frames": frames,
        "root": str(root),
        "mean_correction_px": float(gap_all.mean()),
        "p90_correction_px": float(np.percentile(gap_all, 90)),
    }


@dataclass
class _Run:
    """What the rollouts of one recording share."""

    settings: RecordingSettings
    policy: object
    pre: object
    post: object
    drive: str
    seeds: list[int]
    specs: list[DriftSpec]
    online: object
    task: str


def _chunk_horizon(policy, max_delay: int) -> int:
    """The actions executed per chunk, H, after checking that the base plans the H + ``max_delay`` actions a
    late chunk needs (the plan column is the base's chunk for the scene as observed: no lead)."""
    policy.config.lead_steps = 0  # the plan column is the base's chunk for the scene as observed
    horizon = policy.config.n_action_steps
    if horizon + max_delay > policy.source.max_length:
        raise ValueError(
            f"max_delay={max_delay} needs n_action_steps + max_delay = {horizon + max_delay} actions per "
            f"chunk, but the base plans at most {policy.source.max_length}"
        )
    return horizon


def _probe_env(
    env_config, spec: DriftSpec, max_steps: int, seed: int
) -> tuple[set[str], dict[str, tuple[int, ...]]]:
    """The keys of the env's raw observation and the shape of each of its observations as a policy reads
    them (LeRobot's keys, no batch dimension), from one reset of a probe env."""
    from lerobot.envs.utils import preprocess_observation

    probe = episode_env(env_config, spec, max_steps)
    try:
        raw_first = probe.reset(seed=seed)[0]
        first = preprocess_observation({k: v[None] for k, v in raw_first.items()})
    finally:
        probe.close()
    return set(raw_first), {k: tuple(v.shape[1:]) for k, v in first.items()}


def _stored_shapes(policy, observed: dict[str, tuple[int, ...]]) -> dict[str, tuple[int, ...]]:
    """The shape of each observation the recording stores (:func:`~.rollout.recorded_keys`).

    Raises:
        ValueError: the policy reads observations the env does not give.
    """
    keys = recorded_keys(policy)
    missing = [k for k in keys if k not in observed]
    if missing:
        raise ValueError(
            f"the env's observations give {sorted(observed)}, not {missing} that the policy reads: pick the "
            "env's observation type that holds them (pusht: --env.obs_type=environment_state_agent_pos; "
            "with a camera policy pixels_environment_state_agent_pos)"
        )
    return {k: observed[k] for k in keys}


def _marker(s: RecordingSettings) -> str:
    """The text of the output folder's marker file: how it was recorded."""
    return (
        f"execution={s.execution} teacher={s.teacher} lookahead={s.lookahead} max_delay={s.max_delay} "
        f"seeds={s.seed}..{s.seed + s.episodes - 1}\n"
    )


def _episode_groups(plan_labelled: list[bool], max_delay: int) -> list[tuple[bool, int, list[int]]]:
    """The episodes (indices) rolled out together: those labelled with the plan itself or not, per chunk
    delay (episode k's is k mod (max_delay + 1)); empty groups left out."""
    groups = []
    for plan_labels in (False, True):
        for delay in range(max_delay + 1):
            idx = [
                i
                for i, kept in enumerate(plan_labelled)
                if kept == plan_labels and i % (max_delay + 1) == delay
            ]
            if idx:
                groups.append((plan_labels, delay, idx))
    return groups


def _record_episodes(ds, run: _Run) -> tuple[int, list[np.ndarray]]:
    """Roll out and write every episode; returns the frames written and, per episode, the size of the
    teacher's correction of the plan at each frame."""
    from tqdm import tqdm

    s = run.settings
    bar = tqdm(total=s.episodes, desc=f"episodes ({s.execution})", disable=not s.progress)
    gated = s.teacher == "anchored_when_drifting"
    kept = [gated and sp.perturbation == "none" for sp in run.specs]  # labelled with the plan itself
    frames, gap = 0, []
    for plan_labels, delay, idx in _episode_groups(kept, s.max_delay):
        run.policy.config.execution = "open_loop" if plan_labels and s.execution != "dcdp" else run.drive
        run.policy.config.inference_delay = delay
        weight = [0.0 if plan_labels else label_weight(run.specs[i], gated, s.ramp) for i in idx]
        for j in range(0, len(idx), s.batch_size):
            for ep in _rollout(run, idx[j : j + s.batch_size], weight[j : j + s.batch_size]):
                write_episode(ds, ep, run.task)
                frames += len(ep["step"])
                gap.append(
                    np.linalg.norm(ep["label"] - ep["plan"][np.arange(len(ep["step"])), ep["step"]], axis=-1)
                )
                bar.update(1)
    bar.close()
    return frames, gap


def _rollout(run: _Run, part: list[int], weights: list[float]) -> list[dict]:
    """One batch of episodes (indices ``part``), labelled."""
    s = run.settings
    return rollout_corrections(
        run.policy,
        run.pre,
        run.post,
        [run.seeds[i] for i in part],
        [run.specs[i] for i in part],
        s.max_steps,
        s.lookahead,
        weights,
        s.teacher,
        run.online,
        teacher_drives=s.execution == "teacher",
        env_config=s.env_config,
    )
