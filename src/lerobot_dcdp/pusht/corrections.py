"""``dcdp-record-corrections``: stale chunks and a teacher's corrections of them, as a LeRobotDataset v3.

The training signal of the ``residual`` corrector (docs/METHOD.md): the frozen base runs as it does at
deployment -- one chunk every H steps -- on PushT with the T block drifting (``pusht_perturbed``, the default;
``--env.type=<any registered LeRobot env>`` with its ``--env.*`` flags runs that env as configured), and every
executed step is labelled with what a teacher would do with the stale chunk. Per frame the dataset holds

- every vector observation the policy and its base read (raw; PushT: ``observation.state``,
  ``observation.environment_state``);
- ``observation.dcdp_plan`` (L * A,) and ``observation.dcdp_plan_step`` (1,): the chunk as the base planned
  it at the chunk start (flattened, so LeRobot's ``merge_datasets`` can aggregate DAgger rounds), and the
  step s of this frame in it;
- ``observation.dcdp_plan_delay`` (1,): the chunk's delay d, steps from the observation it was planned from
  to its first action (``--max-delay D``: episode k's base answers d = k mod (D + 1) steps late, as
  ``--policy.inference_delay`` runs it; train with ``--policy.train_max_delay >= D``);
- ``action``: the teacher's action for step s; ``executed_action``: what was actually sent to the env;
- ``next.reward``, ``next.success``, ``next.done``.

Teachers:

- ``object_anchored``: the planned action carried along with the least-squares rigid motion of the block
  keypoints since plan time (the policy's training-free ``object_anchored`` mode), measured ``lookahead``
  steps later (hindsight: the recorded future is known, so ``lookahead > 0`` labels the action that
  anticipates where the block will be; a learned corrector must predict that from its history).
- ``anchored_when_drifting`` (privileged: it knows the episode's drift): the same, but in episodes without
  drift the label is the plan itself -- where only the pusher moves the block, the chunk needs no correction
  (anchoring would add the block's push-induced motion to a plan that already expects it) -- and those
  episodes are driven open loop (unless ``execution`` is ``dcdp``). The student has to tell drift from
  pushing from its observations. ``--ramp r``: the share of the correction grows linearly with the
  episode's drift magnitude, full from r px/step on (small drifts barely cost the base: docs/ANALYSIS.md).
- ``drift_offset`` (privileged: it reads the offsets the env applied): ``plan_s`` translated by the drift
  alone, summed from plan time to the observation ``lookahead`` steps after this one. The drift is a pure
  translation of the block (``pusht_perturbed``), so this is the exact exogenous part of the block's motion:
  the push-induced motion the plan already expects is left alone, in every episode, static or not. The
  student has to tell drift from pushing from its observations.
- ``expert`` (privileged, PushT): the scripted expert re-planning every 8 steps from the block's exact pose
  (read from its keypoints): the registered ``pusht_expert`` teleoperator with its defaults, as a labeller.
  With ``--execution dcdp`` the learner drives and the expert labels the states it visits (DAgger); record
  each round to its own dataset and aggregate them with LeRobot's ``merge_datasets`` (the plan column is flat
  so the stock merge copies it).
- ``teleop``: a LeRobot teleoperator's action for the current observation (``--teleop.type=...`` and its
  ``--teleop.*`` flags): a person's corrections, HG-DAgger style. Two scripted stand-ins for the person are
  registered (:mod:`lerobot_dcdp.teleoperators`): ``pusht_nudge`` corrects the robot's own command (shown to
  it with its chunk step) by carrying it with the block once the world moves the block; ``pusht_expert``
  drives with pushes of its own. They see the scene through ``send_feedback`` (the ``pusht_sim`` observation
  names). One teleoperator per parallel env.
- ``policy``: a teacher policy's action for the current observation (``--teacher-policy=<pretrained_model
  dir>``, any LeRobot policy type, with its own processors): a privileged or bigger policy.

``execution`` picks who drives the env: ``object_anchored`` (the anchoring), ``open_loop`` (the base),
``dcdp`` (a trained corrector: a DAgger round, visiting the states the learner visits) or ``teacher`` (the
``teleop`` / ``policy`` teacher's own actions: the person drives).

Drift per episode is drawn from the episode's seed: none with probability ``static_fraction``, else constant
(direction uniform on the circle) or random (5 directions drawn uniformly, redrawn every 25/50/100 steps),
with a magnitude uniform in ``[0, max_magnitude]`` px/step. Seeds must stay below the evaluation seeds
(100000..).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lerobot_dcdp.atomic_dataset import staged_dir
from lerobot_dcdp.pusht.demos import EVAL_SEED_START, FPS, TASK

EXECUTIONS = ("object_anchored", "open_loop", "dcdp", "teacher")
TEACHERS = ("object_anchored", "anchored_when_drifting", "drift_offset", "expert", "teleop", "policy")
#: Teachers that label each step online from the current observation (the others label in hindsight).
ONLINE_TEACHERS = ("expert", "teleop", "policy")
MARKER = ".dcdp_corrections"


@dataclass
class DriftSpec:
    """The perturbation of one recorded episode."""

    perturbation: str
    magnitude: float
    direction_deg: float
    directions_deg: tuple[float, ...]
    resample_every: int

    def env_kwargs(self) -> dict:
        return {
            "perturbation": self.perturbation,
            "magnitude": self.magnitude,
            "direction_deg": self.direction_deg,
            "directions_deg": self.directions_deg,
            "resample_every": self.resample_every,
        }


def drift_for_seed(seed: int, max_magnitude: float, static_fraction: float) -> DriftSpec:
    """The drift of episode ``seed`` (a pure function of its arguments)."""
    rng = np.random.default_rng([seed, 7_919])
    static = rng.random() < static_fraction
    kind = "constant" if rng.random() < 0.5 else "random"
    mag = float(rng.uniform(0.0, max_magnitude))
    direction = float(rng.uniform(0.0, 360.0))
    dirs = tuple(float(d) for d in rng.uniform(0.0, 360.0, 5))
    every = int(rng.choice([25, 50, 100]))
    if static or mag == 0.0:
        return DriftSpec("none", 0.0, direction, dirs, every)
    return DriftSpec(kind, mag, direction, dirs, every)


#: Names of PushT's vector observations (the ``pusht`` datasets'), kept when a recording holds them.
PUSHT_NAMES = {
    "observation.state": ["x", "y"],
    "observation.environment_state": [f"kp{i // 2}_{'xy'[i % 2]}" for i in range(16)],
}


def features(plan_length: int, action_dim: int = 2, observations: dict | None = None) -> dict:
    """LeRobotDataset feature spec of recorded corrections (``observations``: key -> shape of the stored
    observations; default PushT's agent position and block keypoints)."""
    observations = observations or {"observation.state": (2,), "observation.environment_state": (16,)}
    spec = {}
    for key, shape in observations.items():
        names = PUSHT_NAMES.get(key)
        spec[key] = {
            "dtype": "float32",
            "shape": tuple(shape),
            "names": names if names is not None and (len(names),) == tuple(shape) else None,
        }
    xy = ["x", "y"] if action_dim == 2 else None
    return {
        **spec,
        # flat (L * A,): LeRobot's merge_datasets cannot copy a 2-D column (the policy reshapes it)
        "observation.dcdp_plan": {"dtype": "float32", "shape": (plan_length * action_dim,), "names": None},
        "observation.dcdp_plan_step": {"dtype": "float32", "shape": (1,), "names": None},
        "observation.dcdp_plan_delay": {"dtype": "float32", "shape": (1,), "names": None},
        "action": {"dtype": "float32", "shape": (action_dim,), "names": xy},
        "executed_action": {"dtype": "float32", "shape": (action_dim,), "names": xy},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
        "next.success": {"dtype": "bool", "shape": (1,), "names": None},
        "next.done": {"dtype": "bool", "shape": (1,), "names": None},
    }


def plan_time(steps: np.ndarray, delays: np.ndarray | None) -> np.ndarray:
    """Index of the observation each frame's chunk was planned from: t - s - d."""
    t = np.arange(len(steps))
    plan_idx = t - steps - (0 if delays is None else np.asarray(delays))
    if (plan_idx < 0).any():
        raise ValueError(
            "a frame's chunk starts before the episode (plan_step + delay larger than its index)"
        )
    return plan_idx


def anchored_labels(
    plans: np.ndarray,
    steps: np.ndarray,
    keypoints: np.ndarray,
    lookahead: int,
    delays: np.ndarray | None = None,
) -> np.ndarray:
    """Teacher actions of one episode: ``plan_s`` moved with the block's rigid motion from plan time to
    ``t + lookahead`` (clamped to the episode's last observation).

    Args:
        plans: (T, H, A) raw chunk as planned, per frame; steps: (T,) s of each frame.
        keypoints: (T + 1, N, 2) raw keypoints of every observation, the one after the last step included.
        lookahead: steps ahead of t at which the block pose is taken (0: the current observation).
        delays: (T,) each frame's chunk delay d (plan time t-s-d); None: 0.
    """
    from lerobot_dcdp.correction import anchor_actions, rigid_fit_2d

    t_len = len(steps)
    t = np.arange(t_len)
    plan_idx = plan_time(steps, delays)
    target = np.minimum(t + lookahead, len(keypoints) - 1)
    kp = torch.as_tensor(keypoints, dtype=torch.float64)
    rot, tr = rigid_fit_2d(kp[plan_idx], kp[target])
    plan_s = torch.as_tensor(plans[t, steps], dtype=torch.float64)
    return anchor_actions(plan_s, rot, tr).numpy().astype(np.float32)


def drift_offset_labels(
    plans: np.ndarray,
    steps: np.ndarray,
    offsets: np.ndarray,
    lookahead: int,
    delays: np.ndarray | None = None,
) -> np.ndarray:
    """Teacher actions of one episode: ``plan_s`` translated by the drift the env applied between the plan's
    observation and observation ``t + lookahead`` (clamped to the episode's last observation).

    Args:
        plans: (T, H, A) raw chunk as planned, per frame; steps: (T,) s of each frame.
        offsets: (T, 2) block translation the env applied in each step (``info["perturbation_offset"]``);
            observation t has seen the offsets of steps 0..t-1.
        lookahead: observations ahead of t whose drift is included (0: what observation t has seen).
        delays: (T,) each frame's chunk delay d (plan time t-s-d); None: 0.
    """
    t_len = len(steps)
    t = np.arange(t_len)
    plan_idx = plan_time(steps, delays)
    if offsets.shape != (t_len, 2):
        raise ValueError(f"offsets must be ({t_len}, 2), one per step, got {offsets.shape}")
    seen = np.concatenate([np.zeros((1, 2)), np.cumsum(offsets, axis=0)])  # drift seen by obs 0..T
    target = np.minimum(t + lookahead, t_len)
    return (plans[t, steps] + seen[target] - seen[plan_idx]).astype(np.float32)


class TeleopTeacher:
    """Labels from LeRobot teleoperators, one per parallel env (each keeps its own state).

    Every step each teleoperator is shown, through ``send_feedback``, those of its declared feedback features
    the recorder has: the env's observation (as the ``pusht_sim`` robot names it), the robot's command this
    step (``command.x.pos`` / ``command.y.pos``, what a leader arm that follows the robot reports) and its
    index in the running chunk (``chunk_step``). Its ``get_action()`` (named like the robot's action,
    ``x.pos`` / ``y.pos``) is the label.
    """

    #: the env's raw observation keys whose values are shown to a teleoperator that takes feedback
    FEEDBACK_KEYS = ("agent_pos", "environment_state")

    def __init__(self, config, n: int) -> None:
        from lerobot.teleoperators.utils import make_teleoperator_from_config

        from lerobot_dcdp.robots.pusht_sim import AGENT_NAMES

        self.teleops = [make_teleoperator_from_config(config) for _ in range(n)]
        names = tuple(self.teleops[0].action_features)
        if names != AGENT_NAMES:
            raise ValueError(
                f"teleoperator {config.type!r} sends actions {names}; the PushT recorder needs {AGENT_NAMES} "
                "(the agent's target, px)"
            )
        for t in self.teleops:
            t.connect()

    def check_observation(self, keys: Collection[str]) -> None:
        """Refuse, before any episode runs, an env whose raw observations lack what a teleoperator that takes
        feedback is shown (the agent position and the object keypoints).

        Args:
            keys: The keys of the env's raw observation (``env.reset()[0]``).

        Raises:
            ValueError: naming the missing keys and the observation type that holds them.
        """
        from lerobot_dcdp.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
        from lerobot_dcdp.teleoperators.pusht_nudge import CHUNK_STEP, COMMAND_NAMES

        wanted = set(self.teleops[0].feedback_features)
        if not wanted:
            return
        unknown = sorted(wanted - set(AGENT_NAMES + KEYPOINT_NAMES + COMMAND_NAMES + (CHUNK_STEP,)))
        if unknown:
            raise ValueError(
                f"teleoperator {self.teleops[0].name!r} asks for feedback {unknown}, which the PushT "
                f"recorder does not have (it shows {list(AGENT_NAMES + KEYPOINT_NAMES)}, "
                f"{list(COMMAND_NAMES)} and {CHUNK_STEP!r})"
            )
        missing = [k for k in self.FEEDBACK_KEYS if k not in keys]
        if missing:
            raise ValueError(
                f"teleoperator {self.teleops[0].name!r} is shown the agent position and the block keypoints, "
                f"but the env's observations hold {sorted(keys)}, not {missing}: pick the env's observation "
                "type that holds them (pusht: --env.obs_type=environment_state_agent_pos)"
            )

    def reset(self, n: int) -> None:
        for t in self.teleops[:n]:
            if hasattr(t, "reset"):
                t.reset()

    def __call__(
        self, obs: list[dict], batch: dict, active: np.ndarray, command: np.ndarray, chunk_step: int
    ) -> np.ndarray:
        """Each active env's teleoperator action (N, 2) after showing it the scene and the robot's
        ``command`` (N, 2) at ``chunk_step`` of the running chunk."""
        from lerobot_dcdp.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
        from lerobot_dcdp.teleoperators.pusht_nudge import CHUNK_STEP, COMMAND_NAMES

        out = np.zeros((len(obs), len(AGENT_NAMES)), dtype=np.float32)
        for i in np.flatnonzero(active):
            t = self.teleops[i]
            wanted = t.feedback_features
            if wanted:
                feedback = dict(zip(AGENT_NAMES, obs[i]["agent_pos"].tolist(), strict=True))
                feedback.update(zip(KEYPOINT_NAMES, obs[i]["environment_state"].tolist(), strict=True))
                feedback.update(zip(COMMAND_NAMES, np.asarray(command[i], dtype=float).tolist(), strict=True))
                feedback[CHUNK_STEP] = int(chunk_step)
                t.send_feedback({k: v for k, v in feedback.items() if k in wanted})
            action = t.get_action()
            out[i] = [action[k] for k in AGENT_NAMES]
        return out

    def close(self) -> None:
        for t in self.teleops:
            if t.is_connected:
                t.disconnect()


class PolicyTeacher:
    """Labels from a pretrained LeRobot policy (any type), run batched on the env's observations with its
    own processors."""

    def __init__(self, path: str | Path) -> None:
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        path = Path(path)
        if not (path / "config.json").is_file():
            raise ValueError(
                f"--teacher-policy={path} (resolved {path.resolve()}) holds no config.json: give a "
                "pretrained_model folder (e.g. <output_dir>/checkpoints/last/pretrained_model)"
            )
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = "cpu"
        self.policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg).eval()
        self.pre, self.post = make_pre_post_processors(cfg, pretrained_path=str(path))

    def reset(self, n: int) -> None:
        self.policy.reset()

    @torch.no_grad()
    def __call__(
        self, obs: list[dict], batch: dict, active: np.ndarray, command: np.ndarray, chunk_step: int
    ) -> np.ndarray:
        """The teacher policy's action (N, A) for the batched observation (``command``, ``chunk_step``:
        unused, the policy sees only the observation)."""
        return self.post(self.policy.select_action(self.pre(dict(batch)))).cpu().numpy().astype(np.float32)

    def close(self) -> None:
        pass


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
    """Run one batch of episodes (lock-step) and return each episode's frames with teacher labels
    (``weights``: per episode, the share of the teacher's correction in the label; default 1;
    ``teacher``: ``drift_offset`` labels with the applied drift, ``teleop`` / ``policy`` with
    ``online_teacher(obs, batch, active, command, chunk_step)``'s action for each step (executed instead
    of the policy's when ``teacher_drives``), any other with the anchoring of
    ``policy.config.anchor_feature``; ``env_config``: a LeRobot ``EnvConfig``, default ``pusht_perturbed``
    with keypoint observations: :func:`episode_env`)."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.lockstep import run_lockstep

    envs = [episode_env(env_config, sp, max_steps) for sp in specs]
    n = len(seeds)
    anchor = policy.config.anchor_feature
    obs_keys = recorded_keys(policy)
    keys = ("obs", "anchor", "plan", "step", "delay", "exec", "reward", "success", "offset", "teach")
    cols = [{k: [] for k in keys} for _ in seeds]
    torch.manual_seed(seeds[0])  # the base's sampling noise: the same command records the same data
    policy.reset()
    if online_teacher is not None:
        online_teacher.reset(n)

    def anchor_of(o: dict) -> np.ndarray:
        return preprocess_observation({k: v[None] for k, v in o.items()})[anchor][0].numpy()

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        stacked = {k: np.stack([o[k] for o in obs]) for k in obs[0]}
        raw = preprocess_observation(stacked)
        missing = [k for k in obs_keys if k not in raw]
        if missing:
            raise ValueError(
                f"the env's observations give {sorted(raw)}, not {missing} that the policy reads: pick the "
                "env's observation type that holds them (e.g. --env.obs_type=environment_state_agent_pos)"
            )
        action = post(policy.select_action(pre(dict(raw)))).cpu().numpy()
        taught = None
        if online_teacher is not None:
            taught = online_teacher(obs, raw, active, command=action, chunk_step=policy.last_step)
        if taught is not None and teacher_drives:
            action = taught
        plan = post(policy.planned_chunk).cpu().numpy()
        for i in np.flatnonzero(active):
            c = cols[i]
            c["obs"].append({k: raw[k][i].numpy().astype(np.float32) for k in obs_keys})
            if anchor:
                c["anchor"].append(raw[anchor][i].numpy().astype(np.float32))
            c["plan"].append(plan[i].astype(np.float32))
            c["step"].append(policy.last_step)
            c["delay"].append(policy.chunk_delay)
            c["exec"].append(action[i].astype(np.float32))
            if taught is not None:
                c["teach"].append(taught[i].astype(np.float32))
        return action

    def on_step(i: int, o: dict, reward: float, info: dict) -> None:
        c = cols[i]
        c["reward"].append(reward)
        c["offset"].append(np.asarray(info.get("perturbation_offset", (0.0, 0.0)), dtype=np.float64))
        c["success"].append(bool(info.get("is_success", False)))

    last = run_lockstep(envs, list(seeds), act, max_steps, on_step).obs
    if anchor:  # the observation after each episode's last step
        for i in range(n):
            cols[i]["anchor"].append(anchor_of(last[i]).astype(np.float32))
    for env in envs:
        env.close()
    episodes = []
    for i, c in enumerate(cols):
        plans, steps, delays = np.stack(c["plan"]), np.asarray(c["step"]), np.asarray(c["delay"])
        plan_s = plans[np.arange(len(steps)), steps]
        w = 1.0 if weights is None else float(weights[i])
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
        episodes.append(
            {
                "obs": {k: np.stack([f[k] for f in c["obs"]]) for k in obs_keys},
                "plan": plans,
                "step": steps,
                "delay": delays,
                "label": labels,
                "exec": np.stack(c["exec"]),
                "reward": np.asarray(c["reward"], dtype=np.float32),
                "success": np.asarray(c["success"], dtype=bool),
            }
        )
    return episodes


def recorded_keys(policy) -> list[str]:
    """The observation keys a recording stores: every vector input the policy and its base read."""
    from lerobot.configs.types import FeatureType

    features = {**(policy.base.config.input_features or {}), **(policy.config.input_features or {})}
    keys = sorted(set(policy.check.expected_shapes) | ({policy.config.anchor_feature} - {None}))
    images = [k for k in keys if k in features and features[k].type is FeatureType.VISUAL]
    if images:
        raise ValueError(
            f"dcdp-record-corrections stores vector observations only; the policy reads the images {images}"
        )
    return keys


def episode_env(env_config, spec: DriftSpec, max_steps: int):
    """One episode's gym env: ``pusht_perturbed`` (the default) with the episode's drawn drift, or any other
    registered LeRobot env type as its ``--env.*`` flags configure it (its own dynamics; no drift drawn)."""
    import gymnasium as gym

    from lerobot_dcdp.envs.pusht_perturbed import PushTPerturbedEnvConfig, make_perturbed_env

    if env_config is None:
        return make_perturbed_env(
            obs_type="environment_state_agent_pos", max_episode_steps=max_steps, **spec.env_kwargs()
        )
    if isinstance(env_config, PushTPerturbedEnvConfig):
        own = {k: v for k, v in env_config.gym_kwargs.items() if k not in spec.env_kwargs()}
        return make_perturbed_env(max_episode_steps=max_steps, **own, **spec.env_kwargs())
    import importlib

    importlib.import_module(env_config.package_name)
    kwargs = {**env_config.gym_kwargs, "max_episode_steps": max_steps}
    return gym.make(f"{env_config.package_name}/{env_config.task}", disable_env_checker=True, **kwargs)


def _weight(spec: DriftSpec, gated: bool, ramp: float) -> float:
    """Share of the anchoring correction in an episode's labels (``anchored_when_drifting``: none without
    drift; with ``ramp > 0`` it grows linearly with the drift magnitude up to full at ``ramp`` px/step)."""
    if not gated:
        return 1.0
    if spec.perturbation == "none":
        return 0.0
    return 1.0 if ramp <= 0 else min(1.0, spec.magnitude / ramp)


def _write_episode(ds, ep: dict, task: str) -> None:
    n = len(ep["step"])
    for t in range(n):
        ds.add_frame(
            {
                **{k: v[t] for k, v in ep["obs"].items()},
                "observation.dcdp_plan": ep["plan"][t].reshape(-1),
                "observation.dcdp_plan_step": np.array([ep["step"][t]], dtype=np.float32),
                "observation.dcdp_plan_delay": np.array([ep["delay"][t]], dtype=np.float32),
                "action": ep["label"][t],
                "executed_action": ep["exec"][t],
                "next.reward": ep["reward"][t : t + 1],
                "next.success": ep["success"][t : t + 1],
                "next.done": np.array([t == n - 1]),
                "task": task,
            }
        )
    ds.save_episode()


def load_policy(policy_path: str | None, base_path: str | None, execution: str, anchor_feature: str):
    """A DCDP policy in ``execution`` mode, from a trained corrector or around a bare base, and its
    processors."""
    from lerobot_dcdp.configuration_dcdp import DCDPConfig
    from lerobot_dcdp.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.processor_dcdp import make_dcdp_pre_post_processors

    if (policy_path is None) == (base_path is None):
        raise ValueError("give exactly one of --policy (a trained corrector) or --base (a bare base policy)")
    if policy_path is not None:
        policy = DCDPPolicy.from_pretrained(policy_path)
        policy.config.anchor_feature = policy.config.anchor_feature or anchor_feature
    else:
        if execution == "dcdp":
            raise ValueError("execution='dcdp' needs a trained corrector: pass --policy, not --base")
        cfg = DCDPConfig(base_policy_path=base_path, anchor_feature=anchor_feature, device="cpu")
        policy = DCDPPolicy(cfg)
    policy.config.execution = execution
    policy.eval()
    pre, post = make_dcdp_pre_post_processors(policy.config)
    return policy, pre, post


def record_corrections(
    root: str | Path,
    repo_id: str = "local/pusht_corrections",
    policy_path: str | None = None,
    base_path: str | None = None,
    episodes: int = 200,
    seed: int = 0,
    execution: str = "object_anchored",
    teacher: str = "object_anchored",
    lookahead: int = 0,
    max_magnitude: float = 2.5,
    static_fraction: float = 0.1,
    batch_size: int = 50,
    max_steps: int = 300,
    force: bool = False,
    progress: bool = True,
    ramp: float = 0.0,
    teleop_config=None,
    teacher_policy: str | Path | None = None,
    env_config=None,
    anchor_feature: str = "observation.environment_state",
    max_delay: int = 0,
) -> dict:
    """Record ``episodes`` episodes of stale chunks and teacher corrections to a LeRobotDataset at ``root``.

    ``teleop_config`` (a LeRobot ``TeleoperatorConfig``) is the ``teleop`` teacher, ``teacher_policy`` (a
    ``pretrained_model`` folder) the ``policy`` teacher. ``env_config`` (a LeRobot ``EnvConfig``; default
    ``pusht_perturbed`` with keypoint observations) is the env: ``pusht_perturbed`` episodes get the drift
    drawn per episode, any other env type runs as configured. ``anchor_feature`` names the object's xy
    keypoints for the anchoring teachers. ``max_delay`` D: late chunks, the base of episode ``seed + k``
    answering d = k mod (D + 1) steps late (``inference_delay``; the first chunk of an episode is on time).

    Raises:
        ValueError: bad arguments, seeds reaching the evaluation seeds, or an existing ``root`` that is not an
            earlier output of this command (or is one, without ``force``).
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from tqdm import tqdm

    root = Path(root)
    if execution not in EXECUTIONS:
        raise ValueError(f"execution must be one of {EXECUTIONS}, got {execution!r}")
    if teacher not in TEACHERS:
        raise ValueError(f"teacher must be one of {TEACHERS}, got {teacher!r}")
    if episodes < 1 or batch_size < 1 or max_steps < 1:
        raise ValueError(
            f"episodes, batch_size, max_steps must be >= 1, got {episodes}, {batch_size}, {max_steps}"
        )
    if ramp < 0:
        raise ValueError(f"ramp must be >= 0, got {ramp}")
    if teacher == "teleop" and teleop_config is None:
        raise ValueError("teacher='teleop' needs a teleoperator: --teleop.type=<type> (e.g. pusht_expert)")
    if teacher == "policy" and teacher_policy is None:
        raise ValueError("teacher='policy' needs --teacher-policy=<pretrained_model folder>")
    if teacher != "teleop" and teleop_config is not None:
        raise ValueError(f"--teleop.* is given but teacher={teacher!r}: pass --teacher=teleop")
    if teacher != "policy" and teacher_policy is not None:
        raise ValueError(f"--teacher-policy is given but teacher={teacher!r}: pass --teacher=policy")
    from lerobot_dcdp.envs.pusht_perturbed import PushTPerturbedEnvConfig

    drifting = env_config is None or isinstance(env_config, PushTPerturbedEnvConfig)
    if teacher == "drift_offset" and not drifting:
        raise ValueError(
            f"teacher='drift_offset' reads the drift pusht_perturbed applies; env type {env_config.type!r} "
            "has none (use object_anchored, policy or teleop)"
        )
    if execution == "teacher" and teacher not in ONLINE_TEACHERS:
        raise ValueError(
            f"execution='teacher' lets the teacher drive, which needs teacher in {ONLINE_TEACHERS}; "
            f"teacher={teacher!r} drives with execution='object_anchored'"
        )
    if lookahead < 0:
        raise ValueError(f"lookahead must be >= 0, got {lookahead}")
    if max_delay < 0:
        raise ValueError(f"max_delay must be >= 0 control steps, got {max_delay}")
    if not max_magnitude >= 0 or not 0.0 <= static_fraction <= 1.0:
        raise ValueError(
            "max_magnitude must be >= 0 and static_fraction in [0, 1], "
            f"got {max_magnitude}, {static_fraction}"
        )
    if seed < 0 or seed + episodes > EVAL_SEED_START:
        raise ValueError(
            f"seeds {seed}..{seed + episodes - 1} must stay in [0, {EVAL_SEED_START}): the evaluation seeds "
            "are never trained on"
        )
    if root.exists() and any(root.iterdir()):
        if not (root / MARKER).is_file():
            raise ValueError(
                f"root={root} exists and is not an output of dcdp-record-corrections; refusing it"
            )
        if not force:
            raise ValueError(f"root={root} already exists; pass --force to overwrite it")
    drive = "open_loop" if execution == "teacher" else execution
    policy, pre, post = load_policy(policy_path, base_path, drive, anchor_feature)
    policy.config.lead_steps = 0  # the plan column is the base's chunk for the scene as observed
    horizon = policy.config.n_action_steps
    if horizon + max_delay > policy.source.max_length:
        raise ValueError(
            f"max_delay={max_delay} needs n_action_steps + max_delay = {horizon + max_delay} actions per "
            f"chunk, but the base plans at most {policy.source.max_length}"
        )
    seeds = list(range(seed, seed + episodes))
    if drifting:
        specs = [drift_for_seed(s, max_magnitude, static_fraction) for s in seeds]
    else:
        specs = [DriftSpec("none", 0.0, 0.0, (0.0,), 50) for _ in seeds]
    keys = recorded_keys(policy)
    probe = episode_env(env_config, specs[0], max_steps)
    try:
        from lerobot.envs.utils import preprocess_observation

        raw_first = probe.reset(seed=seeds[0])[0]
        first = preprocess_observation({k: v[None] for k, v in raw_first.items()})
    finally:
        probe.close()
    missing = [k for k in keys if k not in first]
    if missing:
        raise ValueError(
            f"the env's observations give {sorted(first)}, not {missing} that the policy reads: pick the "
            "env's observation type that holds them (pusht: --env.obs_type=environment_state_agent_pos)"
        )
    shapes = {k: tuple(first[k].shape[1:]) for k in keys}
    action_dim = int(policy.config.action_feature.shape[0])
    fps = FPS if env_config is None else env_config.fps
    task = TASK if drifting or env_config.type == "pusht" else env_config.task
    frames = 0
    gap = []
    online = None
    if teacher in ("teleop", "expert"):
        if teacher == "expert":
            from lerobot_dcdp.teleoperators import PushTExpertConfig

            teleop_config = PushTExpertConfig()
        online = TeleopTeacher(teleop_config, min(batch_size, episodes))
        try:
            online.check_observation(set(raw_first))
        except ValueError:
            online.close()
            raise
    elif teacher == "policy":
        online = PolicyTeacher(teacher_policy)
    try:
        with staged_dir(root) as tmp_root:
            ds = LeRobotDataset.create(
                repo_id=repo_id,
                fps=fps,
                features=features(horizon, action_dim, shapes),
                root=tmp_root,
                robot_type="pusht",
                use_videos=False,
            )
            bar = tqdm(total=episodes, desc=f"episodes ({execution})", disable=not progress)
            gated = teacher == "anchored_when_drifting"
            kept = [gated and sp.perturbation == "none" for sp in specs]  # labelled with the plan itself
            groups = [
                (plan_labels, delay, idx)
                for plan_labels in (False, True)
                for delay in range(max_delay + 1)
                if (
                    idx := [
                        i for i in range(episodes) if kept[i] == plan_labels and i % (max_delay + 1) == delay
                    ]
                )
            ]
            for plan_labels, delay, idx in groups:
                policy.config.execution = "open_loop" if plan_labels and execution != "dcdp" else drive
                policy.config.inference_delay = delay
                weight = [0.0 if plan_labels else _weight(specs[i], gated, ramp) for i in idx]
                for j in range(0, len(idx), batch_size):
                    part = idx[j : j + batch_size]
                    for ep in rollout_corrections(
                        policy,
                        pre,
                        post,
                        [seeds[i] for i in part],
                        [specs[i] for i in part],
                        max_steps,
                        lookahead,
                        weight[j : j + batch_size],
                        teacher,
                        online,
                        teacher_drives=execution == "teacher",
                        env_config=env_config,
                    ):
                        _write_episode(ds, ep, task)
                        frames += len(ep["step"])
                        gap.append(
                            np.linalg.norm(
                                ep["label"] - ep["plan"][np.arange(len(ep["step"])), ep["step"]], axis=-1
                            )
                        )
                        bar.update(1)
            bar.close()
            ds.finalize()
            (tmp_root / MARKER).write_text(
                f"execution={execution} teacher={teacher} lookahead={lookahead} max_delay={max_delay} "
                f"seeds={seed}..{seed + episodes - 1}\n"
            )
    finally:
        if online is not None:
            online.close()
    gap_all = np.concatenate(gap)
    return {
        "episodes": episodes,
        "frames": frames,
        "root": str(root),
        "mean_correction_px": float(gap_all.mean()),
        "p90_correction_px": float(np.percentile(gap_all, 90)),
    }


def _parse_choice(args: list[str], name: str, base):
    """``--<name>.type=<type> --<name>.<field>=<value>`` flags as a ``base`` (a draccus ChoiceRegistry)
    config; ``None`` without flags."""
    from dataclasses import make_dataclass

    import draccus

    if not args:
        return None
    if not any(x.startswith(f"--{name}.type=") for x in args):
        known = ", ".join(sorted(base.get_known_choices()))
        raise ValueError(f"--{name}.* flags need --{name}.type=<one of: {known}>")
    args_class = make_dataclass(f"{name.title()}Args", [(name, base)])
    try:
        return getattr(draccus.parse(config_class=args_class, args=args), name)
    except (draccus.utils.ParsingError, SystemExit, ValueError) as err:
        cause = err.__cause__ or err
        raise ValueError(f"bad --{name}.* flags ({' '.join(args)}): {cause}") from err


def parse_teleop_args(args: list[str]):
    """LeRobot's ``--teleop.type=<type> --teleop.<field>=<value>`` flags as a ``TeleoperatorConfig`` (``None``
    when there are none); any other leftover flag is an error naming it."""
    from lerobot.teleoperators.config import TeleoperatorConfig

    unknown = [x for x in args if not x.startswith("--teleop.")]
    if unknown:
        raise ValueError(f"unrecognized arguments: {' '.join(unknown)}")
    return _parse_choice(args, "teleop", TeleoperatorConfig)


def parse_env_args(args: list[str]):
    """LeRobot's ``--env.type=<type> --env.<field>=<value>`` flags as an ``EnvConfig`` (``None``: none)."""
    from lerobot.envs.configs import EnvConfig

    return _parse_choice([x for x in args if x.startswith("--env.")], "env", EnvConfig)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-record-corrections", description=__doc__.splitlines()[0])
    p.add_argument("--root", required=True, help="output directory of the dataset")
    p.add_argument("--repo-id", default="local/pusht_corrections")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--policy", help="a trained DCDP corrector (its base plans the chunks)")
    src.add_argument("--base", help="a bare chunking base policy (pretrained_model dir)")
    p.add_argument("--execution", default="object_anchored", choices=EXECUTIONS, help="who drives the env")
    p.add_argument("--teacher", default="object_anchored", choices=TEACHERS)
    p.add_argument(
        "--ramp",
        type=float,
        default=0.0,
        help="anchored_when_drifting: full correction from this drift magnitude on, linear below (0: any)",
    )
    p.add_argument(
        "--lookahead", type=int, default=0, help="hindsight: block pose taken this many steps later"
    )
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--seed", type=int, default=0, help="first episode seed (episodes must stay below 100000)")
    p.add_argument("--max-magnitude", type=float, default=2.5, help="drift magnitude ~ U[0, this] px/step")
    p.add_argument("--static-fraction", type=float, default=0.1, help="share of episodes without drift")
    p.add_argument("--batch-size", type=int, default=50, help="envs rolled out together")
    p.add_argument("--max-steps", type=int, default=300)
    p.add_argument(
        "--max-delay",
        type=int,
        default=0,
        help="late chunks: episode k's base answers k mod (D + 1) steps late (train with "
        "--policy.train_max_delay >= D; record with --execution open_loop, docs/METHOD.md)",
    )
    p.add_argument("--force", action="store_true", help="overwrite an earlier output at --root")
    p.add_argument(
        "--teacher-policy",
        default=None,
        help="teacher=policy: a pretrained_model folder of any LeRobot policy",
    )
    p.add_argument(
        "--anchor-feature",
        default="observation.environment_state",
        help="observation key of the object's xy keypoints (the anchoring teachers)",
    )
    p.epilog = (
        "LeRobot's env flags pick the env: --env.type=<type> --env.<field>=<value> (default pusht_perturbed "
        "with keypoint observations and a drift drawn per episode). teacher=teleop takes LeRobot's "
        "teleoperator flags: --teleop.type=<type> (e.g. pusht_expert) and --teleop.<field>=<value>"
    )
    a, rest = p.parse_known_args(argv)
    torch.set_num_threads(1)
    try:
        env_config = parse_env_args(rest)
        teleop = parse_teleop_args([x for x in rest if not x.startswith("--env.")])
    except ValueError as e:
        p.error(str(e))
    try:
        info = record_corrections(
            a.root,
            a.repo_id,
            a.policy,
            a.base,
            a.episodes,
            a.seed,
            a.execution,
            a.teacher,
            a.lookahead,
            a.max_magnitude,
            a.static_fraction,
            a.batch_size,
            a.max_steps,
            a.force,
            ramp=a.ramp,
            teleop_config=teleop,
            teacher_policy=a.teacher_policy,
            env_config=env_config,
            anchor_feature=a.anchor_feature,
            max_delay=a.max_delay,
        )
    except ValueError as e:
        sys.exit(f"dcdp-record-corrections: error: {e}")
    root = Path(info["root"]).resolve()
    base = a.base or f"<the base of {a.policy}>"
    print(
        f"wrote {info['episodes']} episodes ({info['frames']} frames) to {root} as repo id {a.repo_id}; "
        f"teacher correction mean {info['mean_correction_px']:.2f} px, "
        f"p90 {info['p90_correction_px']:.2f} px\n"
        f"train a corrector on it:\n  lerobot-train --policy.type=dcdp --policy.base_policy_path={base} "
        f"--policy.anchor_feature=observation.environment_state --dataset.repo_id={a.repo_id} "
        f"--dataset.root={root} --batch_size=128 --steps=1000 --policy.push_to_hub=false "
        + (f"--policy.train_max_delay={a.max_delay} " if a.max_delay else "")
        + "--output_dir=runs/dcdp"
    )


if __name__ == "__main__":
    main()
