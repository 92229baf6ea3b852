"""``dcdp_state_history``: unflatten a state history a remote client packed into one ``observation.state``.

LeRobot 0.6.1's stock policy server (``python -m lerobot.async_inference.policy_server``) feeds a policy one
observation: it builds ``observation.state`` from the robot's scalar features, runs the base's saved
pre-processor and calls ``predict_action_chunk`` on a freshly loaded policy, whose observation queues are
empty. A base that reads ``n_obs_steps > 1`` frames (diffusion) then needs the frames in the batch itself,
``(B, n_obs_steps, width)``; given one frame it fails (``mat1 and mat2 shapes cannot be multiplied``).
:class:`~lerobot_dcdp.deploy.remote_planner.RemotePlanner` therefore declares ``n_obs_steps`` copies of the
robot's
scalar features (the older frames under suffixed names, oldest first), so the server builds one
``(B, n_obs_steps * width)`` state; this step, first in the served base's pre-processor
(``dcdp-serve-base``), reshapes it to ``(B, n_obs_steps, width)`` before ``dcdp_split_state`` cuts the last
axis into the policy's keys. A single frame (``width`` values, e.g. from LeRobot's own ``RobotClient``) is
repeated ``n_obs_steps`` times, as LeRobot fills a policy's queue at an episode's first step.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry, RobotObservation
from lerobot.utils.constants import OBS_STATE

logger = logging.getLogger(__name__)


@dataclass
@ProcessorStepRegistry.register(name="dcdp_state_history")
class StateHistoryProcessorStep(ObservationProcessorStep):
    """Reshape a flattened ``observation.state`` history ``(..., n_obs_steps * width)`` to
    ``(..., n_obs_steps, width)`` (oldest frame first).

    Attributes:
        n_obs_steps: Frames the policy reads (its ``config.n_obs_steps``).
        width: Values of one frame's ``observation.state`` as the robot flattens it (the sum of the
            policy's 1-D state and environment-state widths when ``dcdp_split_state`` follows).
    """

    n_obs_steps: int = 1
    width: int = 1

    def __post_init__(self) -> None:
        self.n_obs_steps, self.width = int(self.n_obs_steps), int(self.width)
        if self.n_obs_steps < 1 or self.width < 1:
            raise ValueError(
                f"dcdp_state_history: n_obs_steps and width must be >= 1, got {self.n_obs_steps}, "
                f"{self.width}"
            )
        self._warned = False

    def observation(self, observation: RobotObservation) -> RobotObservation:
        """Unflatten ``observation.state``; an observation without it passes through.

        Raises:
            ValueError: The state is neither ``n_obs_steps * width`` nor ``width`` wide.
        """
        state = observation.get(OBS_STATE)
        if state is None or self.n_obs_steps == 1:
            return observation
        state = torch.as_tensor(state)
        n, w = self.n_obs_steps, self.width
        if state.ndim >= 1 and state.shape[-1] == n * w:
            observation[OBS_STATE] = state.reshape(*state.shape[:-1], n, w)
        elif state.ndim >= 1 and state.shape[-1] == w:
            if not self._warned:
                logger.warning(
                    "dcdp_state_history: one frame (%d values) instead of %d frames; repeating it (the "
                    "policy sees no motion). A dcdp RemotePlanner sends the history.",
                    w,
                    n,
                )
                self._warned = True
            observation[OBS_STATE] = state.unsqueeze(-2).expand(*state.shape[:-1], n, w).clone()
        else:
            raise ValueError(
                f"dcdp_state_history: {OBS_STATE} has shape {tuple(state.shape)}; expected {n} frames of {w} "
                f"values flattened ({n * w}) or one frame ({w})"
            )
        return observation

    def get_config(self) -> dict[str, Any]:
        """``n_obs_steps`` and ``width``."""
        return {"n_obs_steps": self.n_obs_steps, "width": self.width}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        """A flattened history feature ``(n_obs_steps * width,)`` becomes one frame ``(width,)``."""
        obs = features.get(PipelineFeatureType.OBSERVATION, {})
        state = obs.get(OBS_STATE)
        if state is None or tuple(state.shape) != (self.n_obs_steps * self.width,) or self.n_obs_steps == 1:
            return features
        new_obs = {**obs, OBS_STATE: PolicyFeature(type=state.type, shape=(self.width,))}
        return {**features, PipelineFeatureType.OBSERVATION: new_obs}
