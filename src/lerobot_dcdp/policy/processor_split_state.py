"""``dcdp_split_state``: split a robot's flattened ``observation.state`` into the policy's vector inputs.

LeRobot 0.6.1's ``lerobot-rollout`` builds a policy's input from the robot's features in one fixed way:
every scalar ``*.pos`` / ``*.vel`` feature goes, in the robot's feature order, into one
``observation.state``; there is no route to ``observation.environment_state``. A policy trained on the
PushT datasets reads ``observation.state`` (agent xy, 2) *and* ``observation.environment_state`` (block
keypoints, 16), so ``lerobot-rollout --robot.type=pusht_sim`` hands it an 18-wide ``observation.state``.
This step, first in the DCDP pre-processor, cuts such a vector back into the declared keys; observations
that already carry the keys separately (datasets, ``lerobot-eval``) pass through untouched.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry, RobotObservation
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE

#: Feature types whose 1-D features a robot may have flattened into ``observation.state``.
VECTOR_FEATURE_TYPES: tuple[FeatureType, ...] = (FeatureType.STATE, FeatureType.ENV)


def _layout(parts: Sequence[tuple[str, int]]) -> str:
    return " + ".join(f"{key} ({dim})" for key, dim in parts)


@dataclass
@ProcessorStepRegistry.register(name="dcdp_split_state")
class SplitStateProcessorStep(ObservationProcessorStep):
    """Split a flattened ``observation.state`` into the policy's vector input features.

    ``splits`` lists the policy's 1-D vector inputs, ``observation.state`` first, each with its width. If
    some of the other keys are missing from the observation and ``observation.state`` is exactly as wide
    as its own declared width plus theirs, it is cut, in ``splits`` order, into ``observation.state`` and
    the missing keys (a robot that concatenated its state and the environment state, in that order, as
    ``lerobot-rollout`` does). When no key is missing and ``observation.state`` has its declared width,
    the observation is returned as is. Any other width of ``observation.state`` is an error. An
    observation without ``observation.state`` passes through.

    Works on tensors and arrays, with or without leading (batch, time) dimensions: the split is along the
    last one, and the parts are views of the input.

    Attributes:
        splits: Ordered ``(key, width)`` pairs; the first key is ``observation.state``.
    """

    splits: list[tuple[str, int]] = field(default_factory=list)

    def __post_init__(self) -> None:
        splits = [(str(key), int(dim)) for key, dim in self.splits]
        if not splits or splits[0][0] != OBS_STATE:
            raise ValueError(f"dcdp_split_state: splits must start with {OBS_STATE}, got {self.splits!r}")
        keys = [key for key, _ in splits]
        if len(set(keys)) != len(keys) or any(dim < 1 for _, dim in splits):
            raise ValueError(f"dcdp_split_state: splits need distinct keys and widths >= 1, got {splits}")
        self.splits = splits

    @classmethod
    def from_features(cls, features: Mapping[str, PolicyFeature]) -> SplitStateProcessorStep | None:
        """The step for a policy's input features, or ``None`` when there is nothing to split into.

        Args:
            features: The policy's ``config.input_features``.

        Returns:
            A step splitting into ``observation.state`` then the other 1-D ``STATE`` / ``ENV`` features in
            input-feature order; ``None`` if ``observation.state`` is not among them or is the only one.
        """
        vectors = [
            (key, int(ft.shape[0]))
            for key, ft in features.items()
            if ft.type in VECTOR_FEATURE_TYPES and len(ft.shape) == 1
        ]
        state = [kd for kd in vectors if kd[0] == OBS_STATE]
        if not state or len(vectors) < 2:
            return None
        return cls(splits=state + [kd for kd in vectors if kd[0] != OBS_STATE])

    def _parts(self, present: Any) -> list[tuple[str, int]]:
        """``observation.state`` and the keys of ``splits`` that ``present`` lacks, in ``splits`` order."""
        return [self.splits[0], *((key, dim) for key, dim in self.splits[1:] if key not in present)]

    def observation(self, observation: RobotObservation) -> RobotObservation:
        """Split ``observation.state`` if a robot flattened the policy's vector inputs into it.

        Raises:
            ValueError: ``observation.state`` is neither its declared width (with the other keys present)
                nor the declared width plus that of the missing keys.
        """
        state = observation.get(OBS_STATE)
        if state is None:
            return observation
        parts = self._parts(observation)
        shape = tuple(getattr(state, "shape", ()))
        width = shape[-1] if shape else None
        expected = sum(dim for _, dim in parts)
        if width != expected:
            missing = ", ".join(key for key, _ in parts[1:])
            rule = (
                f"with {missing} missing from the observation it must hold {_layout(parts)} = {expected}"
                if missing
                else f"with the other inputs given separately it must hold {expected}"
            )
            got = f"has {width} values (shape {shape})" if shape else f"is not an array ({state!r:.60})"
            fix = (
                f"; the env or robot does not report {missing}: pick an observation type that does (PushT: "
                "--env.obs_type=environment_state_agent_pos) or a corrector trained on what it reports"
                if missing
                else ""
            )
            raise ValueError(
                f"dcdp_split_state: {OBS_STATE} {got}; {rule} (the policy's vector inputs: "
                f"{_layout(self.splits)}){fix}"
            )
        if len(parts) == 1:
            return observation  # already split
        start = 0
        for key, dim in parts:
            observation[key] = state[..., start : start + dim]
            start += dim
        return observation

    def get_config(self) -> dict[str, Any]:
        """The ``(key, width)`` pairs, as JSON lists."""
        return {"splits": [[key, dim] for key, dim in self.splits]}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        """Replace a flattened ``observation.state`` feature by the features it is split into.

        ``observation.state`` keeps its type; the other keys get ``ENV`` for
        ``observation.environment_state`` and ``STATE`` otherwise. Features that the step would pass
        through unchanged (or reject) are returned as they are.
        """
        obs = features.get(PipelineFeatureType.OBSERVATION, {})
        state = obs.get(OBS_STATE)
        if state is None or not state.shape:
            return features
        parts = self._parts(obs)
        if len(parts) == 1 or state.shape[-1] != sum(dim for _, dim in parts):
            return features
        new_obs: dict[str, PolicyFeature] = {}
        for key, ft in obs.items():
            if key != OBS_STATE:
                new_obs[key] = ft
                continue
            for part, dim in parts:
                kind = state.type if part == OBS_STATE else FeatureType.ENV if part == OBS_ENV_STATE else None
                new_obs[part] = PolicyFeature(type=kind or FeatureType.STATE, shape=(*state.shape[:-1], dim))
        return {**features, PipelineFeatureType.OBSERVATION: new_obs}
