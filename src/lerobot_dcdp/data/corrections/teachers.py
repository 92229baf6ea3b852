"""The online teachers: they label each step from the current observation while the episode runs.

- ``teleop`` (:class:`TeleopTeacher`): a LeRobot teleoperator's action for the current observation
  (``--teleop.type=...`` and its ``--teleop.*`` flags): a person's corrections, HG-DAgger style. Two scripted
  stand-ins for the person are registered (:mod:`lerobot_dcdp.sim.teleoperators`): ``pusht_nudge`` corrects
  the robot's own command (shown to it with its chunk step) by carrying it with the block once the world moves
  the block; ``pusht_expert`` drives with pushes of its own. They see the scene through ``send_feedback`` (the
  ``pusht_sim`` observation names). One teleoperator per parallel env.
- ``expert`` (privileged, PushT): the registered ``pusht_expert`` teleoperator with its defaults, re-planning
  every 8 steps from the block's exact pose (read from its keypoints), as a :class:`TeleopTeacher`.
- ``policy`` (:class:`PolicyTeacher`): a teacher policy's action for the current observation
  (``--teacher-policy=<pretrained_model dir>``, any LeRobot policy type, with its own processors): a
  privileged or bigger policy.

Each is called as ``teacher(obs, batch, active, command, chunk_step)`` -> (N, A) labels, ``reset(n)`` at the
start of a batch of episodes and ``close()`` at the end of the recording.
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import numpy as np
import torch


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

        from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES

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
        from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
        from lerobot_dcdp.sim.teleoperators.pusht_nudge import CHUNK_STEP, COMMAND_NAMES

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
        from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
        from lerobot_dcdp.sim.teleoperators.pusht_nudge import CHUNK_STEP, COMMAND_NAMES

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


def make_online_teacher(
    teacher: str, teleop_config, teacher_policy: str | Path | None, n: int, observation_keys: Collection[str]
) -> TeleopTeacher | PolicyTeacher | None:
    """The online teacher ``teacher`` names (``None`` for the hindsight teachers).

    Args:
        teacher: The recorder's teacher name.
        teleop_config: ``teleop``: the LeRobot ``TeleoperatorConfig`` of its teleoperators.
        teacher_policy: ``policy``: the teacher's ``pretrained_model`` folder.
        n: Parallel envs (one teleoperator each).
        observation_keys: The keys of the env's raw observation, checked against what a teleoperator is shown.

    Raises:
        ValueError: an env whose observations lack what the teleoperator is shown, or a ``teacher_policy``
            folder without a ``config.json``.
    """
    if teacher in ("teleop", "expert"):
        if teacher == "expert":
            from lerobot_dcdp.sim.teleoperators import PushTExpertConfig

            teleop_config = PushTExpertConfig()
        online = TeleopTeacher(teleop_config, n)
        try:
            online.check_observation(observation_keys)
        except ValueError:
            online.close()
            raise
        return online
    if teacher == "policy":
        return PolicyTeacher(teacher_policy)
    return None
