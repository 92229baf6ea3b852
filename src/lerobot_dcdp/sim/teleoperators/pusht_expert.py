"""The scripted PushT expert behind LeRobot's ``Teleoperator`` interface.

A person correcting a robot watches the scene; this teleoperator watches it through
:meth:`PushTExpert.send_feedback`, which takes the robot's observation (the ``pusht_sim`` names: ``x.pos``,
``y.pos`` of the agent and ``kp{i}_{x,y}.pos`` of the 8 block keypoints, px). :meth:`PushTExpert.get_action`
returns the next target ``{"x.pos", "y.pos"}`` of a plan made by :class:`~lerobot_dcdp.sim.pusht_expert.
ScriptedExpert` from that observation alone -- the block pose fitted to the keypoints, the agent's velocity
from its last two positions -- re-planned every ``replan_every`` steps. It never reads a simulator, so it
drives the ``pusht_sim`` robot, a ``pusht`` gym env or recorded observations alike. With ``follow_block``
the targets sent between plans move with the block's deviation from the pose its plan predicted for that step
(:func:`follow_deviation`), and each plan simulates the block drifting as estimated from those deviations.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from lerobot.teleoperators import Teleoperator
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
from lerobot_dcdp.sim.teleoperators.config_pusht_expert import PushTExpertConfig

#: Simulated time of one control step (gym-pusht: 10 physics substeps of 0.01 s).
CONTROL_DT = 0.1


def block_pose_from_keypoints(keypoints: np.ndarray) -> np.ndarray:
    """The block pose ``(x, y, theta)`` whose T corners best fit ``keypoints`` (8, 2) (least squares)."""
    from lerobot_dcdp.sim.pusht_geometry import LOCAL_KP

    kp = np.asarray(keypoints, dtype=float).reshape(-1, 2)
    if kp.shape != LOCAL_KP.shape:
        raise ValueError(f"expected {len(LOCAL_KP)} block keypoints (x, y), got shape {kp.shape}")
    lc, oc = LOCAL_KP.mean(0), kp.mean(0)
    h = (LOCAL_KP - lc).T @ (kp - oc)
    theta = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(theta), math.sin(theta)
    position = oc - np.array([[c, -s], [s, c]]) @ lc
    return np.array([position[0], position[1], theta])


def follow_deviation(target: np.ndarray, predicted: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """``target`` carried along the rigid motion that takes the block from its ``predicted`` pose
    ``(x, y, theta)`` to its ``observed`` one: ``R(theta_o - theta_p) (target - p_p) + p_o``."""
    c, s = math.cos(observed[2] - predicted[2]), math.sin(observed[2] - predicted[2])
    d = np.asarray(target, dtype=float) - predicted[:2]
    return np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]]) + observed[:2]


class PushTExpert(Teleoperator):
    """Scripted PushT expert as a teleoperator; see the module docstring.

    Attributes:
        plans: Plans made since ``connect()`` (or :meth:`reset`).
    """

    @property
    def drift_estimate(self) -> np.ndarray:
        """The block's motion per step (px, x/y) that the expert's pushes do not explain, as estimated at its
        last plan and assumed by it (``follow_block`` only; zeros otherwise)."""
        return self._drift.copy()

    config_class = PushTExpertConfig
    name = "pusht_expert"

    def __init__(self, config: PushTExpertConfig) -> None:
        super().__init__(config)
        self.config = config
        self._expert = None
        self.reset()

    @property
    def action_features(self) -> dict[str, type]:
        return dict.fromkeys(AGENT_NAMES, float)

    @property
    def feedback_features(self) -> dict[str, type]:
        return dict.fromkeys(AGENT_NAMES + KEYPOINT_NAMES, float)

    @property
    def is_connected(self) -> bool:
        return self._expert is not None

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        """Nothing to calibrate."""

    def configure(self) -> None:
        """Nothing to configure."""

    @check_if_already_connected
    def connect(self, calibrate: bool = True) -> None:
        from lerobot_dcdp.sim.pusht_expert import ExpertConfig, ScriptedExpert

        self._expert = ScriptedExpert(ExpertConfig(max_step=self.config.max_step), seed=self.config.seed)
        self.reset()

    def reset(self) -> None:
        """Forget the current plan and the observations seen (call at the start of every episode)."""
        self._queue: list[np.ndarray] = []
        self._predicted: list[np.ndarray] | None = None  # block pose after each planned action
        self._drift = np.zeros(2)  # the block's motion per step that pushing does not explain (px)
        self._since_plan = 0
        self._agent: np.ndarray | None = None
        self._prev_agent: np.ndarray | None = None
        self._keypoints: np.ndarray | None = None
        self._last_target: np.ndarray | None = None
        self.plans = 0

    @check_if_not_connected
    def send_feedback(self, feedback: dict[str, Any]) -> None:
        """Show the expert the scene: a ``pusht_sim`` observation (named floats, px)."""
        missing = [k for k in self.feedback_features if k not in feedback]
        if missing:
            raise ValueError(
                f"pusht_expert needs the pusht_sim observation as feedback; missing {missing[:4]}"
                f"{' ...' if len(missing) > 4 else ''}"
            )
        agent = np.array([float(feedback[k]) for k in AGENT_NAMES])
        kp = np.array([float(feedback[k]) for k in KEYPOINT_NAMES]).reshape(-1, 2)
        if not (np.isfinite(agent).all() and np.isfinite(kp).all()):
            raise ValueError("pusht_expert feedback holds a non-finite value")
        self._prev_agent, self._agent, self._keypoints = self._agent, agent, kp

    @check_if_not_connected
    def get_action(self) -> dict[str, float]:
        """The expert's next target for the latest feedback; re-plans every ``replan_every`` steps."""
        if self._agent is None:
            raise RuntimeError(
                "pusht_expert has not seen the scene: call send_feedback(observation) before get_action()"
            )
        if not self._queue or self._since_plan >= self.config.replan_every:
            self._plan()
        target = self._queue.pop(0)
        if self.config.follow_block and self._predicted and self._since_plan > 0:
            predicted, observed = (
                self._predicted[self._since_plan - 1],
                block_pose_from_keypoints(self._keypoints),
            )
            target = np.clip(follow_deviation(target, predicted, observed), 20, 492)
        self._since_plan += 1
        self._last_target = target
        return {AGENT_NAMES[0]: float(target[0]), AGENT_NAMES[1]: float(target[1])}

    def _plan(self) -> None:
        from lerobot_dcdp.sim.pusht_geometry import densify

        pose = block_pose_from_keypoints(self._keypoints)
        if self.config.follow_block and self._predicted and self._since_plan > 0:
            # the unexplained motion since the last plan, per step, adds to the drift the plan assumed
            unexplained = pose[:2] - self._predicted[self._since_plan - 1][:2]
            self._drift = self._drift + unexplained / self._since_plan
        vel = (0.0, 0.0) if self._prev_agent is None else tuple((self._agent - self._prev_agent) / CONTROL_DT)
        prev = self._agent if self._last_target is None else self._last_target
        score, acts = self._expert.plan(prev, tuple(self._agent), vel, pose, drift=self._drift)
        self._predicted = None
        if score <= 0 or not acts:  # no push improves the pose: a small random step to escape
            goal = np.clip(self._agent + self._expert.rng.normal(0, 30, 2), 20, 492)
            acts = densify(prev, [goal], self.config.max_step)
        elif self.config.follow_block:  # the block's pose after each action, on the exact copy
            self._expert.sim.set_state(self._agent, vel, pose)
            self._predicted = self._expert.sim.run(acts)
        self._queue = [np.asarray(a, dtype=float) for a in acts]
        self._since_plan = 0
        self.plans += 1

    @check_if_not_connected
    def disconnect(self) -> None:
        self._expert = None
