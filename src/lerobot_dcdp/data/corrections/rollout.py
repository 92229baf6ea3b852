"""Roll the frozen base out as deployed and label every executed step: one batch of episodes, lock-step.

The base runs as it does at deployment -- one chunk every H steps -- and each frame records the observation,
the chunk as planned, its step s and delay d, the executed action, the reward and success, the drift offset
the env applied and, with an online teacher, its action. After the episodes end each gets its labels: the
online teacher's actions, or the hindsight labels of :mod:`.labels`, blended with the plan by the episode's
weight (:func:`label_weight`).
"""

from __future__ import annotations

import numpy as np
import torch

from lerobot_dcdp.data.corrections.drift import DriftSpec, episode_env
from lerobot_dcdp.data.corrections.labels import anchored_labels, drift_offset_labels
from lerobot_dcdp.data.corrections.settings import ONLINE_TEACHERS


def load_policy(
    policy_path: str | None,
    base_path: str | None,
    execution: str,
    anchor_feature: str,
    anchor_shape: tuple[int, ...] | None = None,
):
    """A DCDP policy in ``execution`` mode, from a trained corrector or around a bare base, and its
    processors (:func:`~lerobot_dcdp.policy.loader.load_dcdp`). Around a base that does not read
    ``anchor_feature`` (an image base), the wrapper reads it too, with ``anchor_shape`` (the env's): the
    anchoring teachers label with it."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_dcdp.policy.loader import load_dcdp

    if (policy_path is None) == (base_path is None):
        raise ValueError("give exactly one of --policy (a trained corrector) or --base (a bare base policy)")
    if policy_path is None and execution == "dcdp":
        raise ValueError("execution='dcdp' needs a trained corrector: pass --policy, not --base")
    extra = None
    if base_path is not None and anchor_feature and anchor_shape is not None:
        if anchor_feature not in (PreTrainedConfig.from_pretrained(str(base_path)).input_features or {}):
            extra = {anchor_feature: PolicyFeature(type=FeatureType.ENV, shape=tuple(anchor_shape))}
    loaded = load_dcdp(
        policy_path, base=base_path, execution=execution, anchor_feature=anchor_feature, extra_inputs=extra
    )
    return tuple(loaded)


def recorded_keys(policy) -> list[str]:
    """The observation keys a recording stores: every input the policy and its base read (vectors and
    cameras), and the anchor feature (the object's keypoints the anchoring teachers label with)."""
    return sorted(set(policy.check.expected_shapes) | ({policy.config.anchor_feature} - {None}))


def stored_frame(value: torch.Tensor) -> np.ndarray:
    """One observation as the recording stores it: a camera frame (C, H, W) in [0, 1] as uint8 (H, W, C), a
    vector as float32 (pure)."""
    if value.ndim == 3:
        return (value.permute(1, 2, 0).clamp(0, 1) * 255).round().to(torch.uint8).numpy()
    return value.numpy().astype(np.float32)


def label_weight(spec: DriftSpec, gated: bool, ramp: float) -> float:
    """Share of the anchoring correction in an episode's labels (``anchored_when_drifting``: none without
    drift; with ``ramp > 0`` it grows linearly with the drift magnitude up to full at ``ramp`` px/step)."""
    if not gated:
        return 1.0
    if spec.perturbation == "none":
        return 0.0
    return 1.0 if ramp <= 0 else min(1.0, spec.magnitude / ramp)


class _Columns:
    """Each episode's recorded columns, filled by :func:`~lerobot_dcdp.sim.lockstep.run_lockstep`'s
    callbacks (:meth:`act`, :meth:`on_step`)."""

    KEYS = ("obs", "anchor", "plan", "step", "delay", "exec", "reward", "success", "offset", "teach")

    def __init__(self, policy, pre, post, n: int, online_teacher, teacher_drives: bool) -> None:
        self.policy, self.pre, self.post = policy, pre, post
        self.online_teacher, self.teacher_drives = online_teacher, teacher_drives
        self.anchor = policy.config.anchor_feature
        self.obs_keys = recorded_keys(policy)
        self.cols = [{k: [] for k in self.KEYS} for _ in range(n)]

    def act(self, obs: list[dict], active: np.ndarray) -> np.ndarray:
        """The action sent to each env (the policy's, or the teacher's when it drives), recording the step."""
        from lerobot.envs.utils import preprocess_observation

        stacked = {k: np.stack([o[k] for o in obs]) for k in obs[0]}
        raw = preprocess_observation(stacked)
        missing = [k for k in self.obs_keys if k not in raw]
        if missing:
            raise ValueError(
                f"the env's observations give {sorted(raw)}, not {missing} that the policy reads: pick the "
                "env's observation type that holds them (e.g. --env.obs_type=environment_state_agent_pos)"
            )
        policy = self.policy
        action = self.post(policy.select_action(self.pre(dict(raw)))).cpu().numpy()
        taught = None
        if self.online_teacher is not None:
            taught = self.online_teacher(obs, raw, active, command=action, chunk_step=policy.last_step)
        if taught is not None and self.teacher_drives:
            action = taught
        self._store(raw, active, action, taught)
        return action

    def _store(self, raw: dict, active: np.ndarray, action: np.ndarray, taught: np.ndarray | None) -> None:
        policy = self.policy
        plan = self.post(policy.planned_chunk).cpu().numpy()
        for i in np.flatnonzero(active):
            c = self.cols[i]
            c["obs"].append({k: stored_frame(raw[k][i]) for k in self.obs_keys})
            if self.anchor:
                c["anchor"].append(raw[self.anchor][i].numpy().astype(np.float32))
            c["plan"].append(plan[i].astype(np.float32))
            c["step"].append(policy.last_step)
            c["delay"].append(policy.chunk_delay)
            c["exec"].append(action[i].astype(np.float32))
            if taught is not None:
                c["teach"].append(taught[i].astype(np.float32))

    def on_step(self, i: int, o: dict, reward: float, info: dict) -> None:
        c = self.cols[i]
        c["reward"].append(reward)
        c["offset"].append(np.asarray(info.get("perturbation_offset", (0.0, 0.0)), dtype=np.float64))
        c["success"].append(bool(info.get("is_success", False)))

    def add_last_anchors(self, last: list[dict]) -> None:
        """The anchor feature of the observation after each episode's last step."""
        from lerobot.envs.utils import preprocess_observation

        if not self.anchor:
            return
        for i, o in enumerate(last):
            anchor = preprocess_observation({k: v[None] for k, v in o.items()})[self.anchor][0].numpy()
            self.cols[i]["anchor"].append(anchor.astype(np.float32))


def _labels(c: dict, plans, steps, delays, w: float, teacher: str, lookahead: int) -> np.ndarray:
    """One episode's labels: the teacher's, ``w`` of its correction of the plan (the plan itself at 0)."""
    plan_s = plans[np.arange(len(steps)), steps]
    labels = plan_s.copy()
    if teacher in ONLINE_TEACHERS:
        taught_ep = np.stack(c["teach"])
        labels = taught_ep if w == 1.0 else plan_s + w * (taught_ep - plan_s)
    elif w > 0 and teacher == "drift_offset":
        labels = drift_offset_labels(plans, steps, np.stack(c["offset"]), lookahead, delays)
        labels = plan_s + w * (labels - plan_s)
    elif w > 0:
        kps = np.stack(c["anchor"])
        anchored = anchored_labels(plans, steps, kps.reshape(len(kps), -1, 2), lookahead, delays)
        labels = plan_s + w * (anchored - plan_s)
    return labels


def _episode(c: dict, obs_keys: list[str], w: float, teacher: str, lookahead: int) -> dict:
    """One episode's recorded columns as arrays, with its labels."""
    plans, steps, delays = np.stack(c["plan"]), np.asarray(c["step"]), np.asarray(c["delay"])
    return {
        "obs": {k: np.stack([f[k] for f in c["obs"]]) for k in obs_keys},
        "plan": plans,
        "step": steps,
        "delay": delays,
        "label": _labels(c, plans, steps, delays, w, teacher, lookahead),
        "exec": np.stack(c["exec"]),
        "reward": np.asarray(c["reward"], dtype=np.float32),
        "success": np.asarray(c["success"], dtype=bool),
    }


@torch.no_grad()
@torch.random.fork_rng(devices=[])  # the seeding below leaves the caller's global RNG as it was
def rollout_corrections(
    policy,
    pre,
    post,
    seeds,
    specs,
    max_steps: int,
    lookahead: int,
    weights: list[float] | None = None,
    teacher: str = "object_anchored",
    online_teacher=None,
    teacher_drives: bool = False,
    env_config=None,
) -> list[dict]:
    """Run one batch of episodes (lock-step) and return each episode's frames with teacher labels.

    Args:
        policy, pre, post: The DCDP policy (its base plans the chunks) and its processors.
        seeds, specs: Per episode, its reset seed and its drift (:class:`~.drift.DriftSpec`).
        max_steps: Step limit of an episode.
        lookahead: Hindsight teachers: steps ahead whose block pose (or drift) the label takes.
        weights: Per episode, the share of the teacher's correction in the label; default 1.
        teacher: ``drift_offset`` labels with the applied drift, ``teleop`` / ``policy`` / ``expert`` with
            ``online_teacher(obs, batch, active, command, chunk_step)``'s action for each step, any other with
            the anchoring of ``policy.config.anchor_feature``.
        online_teacher: The online teacher (:mod:`.teachers`), or ``None``.
        teacher_drives: Execute the online teacher's actions instead of the policy's.
        env_config: A LeRobot ``EnvConfig``, default ``pusht_perturbed`` with keypoint observations
            (:func:`~.drift.episode_env`).

    Returns:
        Per episode: ``obs`` (key -> (T, ...)), ``plan`` (T, H, A), ``step``, ``delay``, ``label`` (T, A),
        ``exec`` (T, A), ``reward`` and ``success`` (T,).
    """
    from lerobot_dcdp.sim.lockstep import run_lockstep

    envs = [episode_env(env_config, sp, max_steps) for sp in specs]
    n = len(seeds)
    columns = _Columns(policy, pre, post, n, online_teacher, teacher_drives)
    torch.manual_seed(seeds[0])  # the base's sampling noise: the same command records the same data
    policy.reset()
    if online_teacher is not None:
        online_teacher.reset(n)
    last = run_lockstep(envs, list(seeds), columns.act, max_steps, columns.on_step).obs
    columns.add_last_anchors(last)
    for env in envs:
        env.close()
    return [
        _episode(c, columns.obs_keys, 1.0 if weights is None else float(weights[i]), teacher, lookahead)
        for i, c in enumerate(columns.cols)
    ]
