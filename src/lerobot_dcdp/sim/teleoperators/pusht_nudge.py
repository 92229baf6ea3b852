"""A scripted person who corrects the robot's own command instead of driving: ``pusht_nudge``.

A person correcting a chunking policy with a leader arm holds an arm that follows the robot (LeRobot's DAgger
strategy drives an actuated leader to the follower's command before a takeover). This stand-in person does
not plan pushes of their own: every step they take the robot's command and, once they have seen the world
moving the block, carry it with the block's rigid motion since the robot planned the running chunk (the
anchoring rule, :func:`~lerobot_dcdp.model.correction.anchor_actions`); on a still scene they let it pass. The
person judges "the world moves it" from what they see: the block's speed on steps where the agent is not
touching it (:meth:`PushTNudge.block_speed`), against ``notice_speed``.

Feedback (:meth:`PushTNudge.send_feedback`), named floats: ``x.pos`` / ``y.pos`` (the agent's observed
position, px, as ``pusht_sim`` names it), ``kp{i}_{x,y}.pos`` (the 8 block keypoints), ``command.x.pos`` /
``command.y.pos`` (the robot's command this step: the leader arm's position) and ``chunk_step`` (the index of
that command in the running chunk, 0 on the step the chunk was planned: a plan display).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from lerobot.teleoperators import Teleoperator
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
from lerobot_dcdp.sim.teleoperators.config_pusht_nudge import PushTNudgeConfig
from lerobot_dcdp.sim.teleoperators.pusht_expert import block_pose_from_keypoints

#: The robot's command this step, as the leader arm that follows it reports it.
COMMAND_NAMES = ("command.x.pos", "command.y.pos")
#: Index of the command in the running chunk (0: planned from this step's observation).
CHUNK_STEP = "chunk_step"
#: Radius of the PushT agent (px).
AGENT_RADIUS = 15.0


def touching(agent: np.ndarray, keypoints: np.ndarray, margin: float) -> bool:
    """Whether the agent (x, y) is within its radius plus ``margin`` px of the T fitted to ``keypoints``."""
    from lerobot_dcdp.sim.pusht_geometry import distance_to_t, rot

    pose = block_pose_from_keypoints(keypoints)
    local = rot(-pose[2]) @ (np.asarray(agent, dtype=float) - pose[:2])
    return distance_to_t(local) <= AGENT_RADIUS + margin


def carried(command: np.ndarray, keypoints_then: np.ndarray, keypoints_now: np.ndarray) -> np.ndarray:
    """``command`` (x, y) moved with the rigid motion that best takes ``keypoints_then`` onto
    ``keypoints_now`` (both (N, 2))."""
    import torch

    from lerobot_dcdp.model.correction import anchor_actions, rigid_fit_2d

    then = torch.as_tensor(np.asarray(keypoints_then, dtype=float)[None])
    now = torch.as_tensor(np.asarray(keypoints_now, dtype=float)[None])
    rotation, translation = rigid_fit_2d(then, now)
    point = torch.as_tensor(np.asarray(command, dtype=float)[None])
    return anchor_actions(point, rotation, translation)[0].numpy()


class PushTNudge(Teleoperator):
    """Scripted correcting person as a teleoperator; see the module docstring."""

    config_class = PushTNudgeConfig
    name = "pusht_nudge"

    def __init__(self, config: PushTNudgeConfig) -> None:
        super().__init__(config)
        self.config = config
        self._connected = False
        self.reset()

    @property
    def action_features(self) -> dict[str, type]:
        return dict.fromkeys(AGENT_NAMES, float)

    @property
    def feedback_features(self) -> dict[str, type]:
        return {**dict.fromkeys(AGENT_NAMES + KEYPOINT_NAMES + COMMAND_NAMES, float), CHUNK_STEP: int}

    @property
    def is_connected(self) -> bool:
        return self._connected

    @property
    def is_calibrated(self) -> bool:
        return True

    @property
    def block_speed(self) -> float:
        """The person's running estimate of the block's own speed (px/step), from steps without contact."""
        return self._speed

    @property
    def noticing(self) -> bool:
        """Whether the person currently judges that the world moves the block (and carries the command)."""
        return self._speed > self.config.notice_speed

    def calibrate(self) -> None:
        """Nothing to calibrate."""

    def configure(self) -> None:
        """Nothing to configure."""

    @check_if_already_connected
    def connect(self, calibrate: bool = True) -> None:
        self._connected = True
        self.reset()

    def reset(self) -> None:
        """Forget the scene (call at the start of every episode)."""
        self._speed = 0.0
        self._keypoints: np.ndarray | None = None
        self._was_free = False
        self._reference: np.ndarray | None = None  # keypoints when the running chunk was planned
        self._command: np.ndarray | None = None

    @check_if_not_connected
    def send_feedback(self, feedback: dict[str, Any]) -> None:
        """Show the person the scene and the robot's command (see the module docstring for the names)."""
        missing = [k for k in self.feedback_features if k not in feedback]
        if missing:
            raise ValueError(
                "pusht_nudge needs the pusht_sim observation, the robot's command and its chunk step as "
                f"feedback; missing {missing[:4]}{' ...' if len(missing) > 4 else ''}"
            )
        agent = np.array([float(feedback[k]) for k in AGENT_NAMES])
        kp = np.array([float(feedback[k]) for k in KEYPOINT_NAMES]).reshape(-1, 2)
        command = np.array([float(feedback[k]) for k in COMMAND_NAMES])
        step = int(feedback[CHUNK_STEP])
        if not (np.isfinite(agent).all() and np.isfinite(kp).all() and np.isfinite(command).all()):
            raise ValueError("pusht_nudge feedback holds a non-finite value")
        if step < 0:
            raise ValueError(f"pusht_nudge feedback chunk_step must be >= 0, got {step}")
        free = not touching(agent, kp, self.config.contact_margin)
        if free and self._was_free and self._keypoints is not None:
            speed = float(np.linalg.norm(kp.mean(0) - self._keypoints.mean(0)))
            self._speed += self.config.smoothing * (speed - self._speed)
        if step == 0 or self._reference is None:
            self._reference = kp
        self._was_free, self._keypoints, self._command = free, kp, command

    @check_if_not_connected
    def get_action(self) -> dict[str, float]:
        """The robot's command, carried with the block since the chunk was planned once the person notices
        the world moving it."""
        if self._command is None:
            raise RuntimeError(
                "pusht_nudge has not seen the scene: call send_feedback(observation) before get_action()"
            )
        target = self._command
        if self.noticing:
            target = carried(self._command, self._reference, self._keypoints)
        return {AGENT_NAMES[0]: float(target[0]), AGENT_NAMES[1]: float(target[1])}

    @check_if_not_connected
    def disconnect(self) -> None:
        self._connected = False


__all__ = ["AGENT_RADIUS", "CHUNK_STEP", "COMMAND_NAMES", "PushTNudge", "carried", "touching"]
