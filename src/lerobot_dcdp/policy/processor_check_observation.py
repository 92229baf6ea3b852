"""``dcdp_check_observation``: refuse an observation feature of the wrong shape before anything else reads it.

LeRobot's normaliser (``normalizer_processor``) broadcasts each feature against its saved statistics, so a
15-wide ``observation.environment_state`` given to a policy declared 16-wide ends there as ``RuntimeError:
The size of tensor a (15) must match the size of tensor b (16)``, which names neither the feature nor the
shapes. This step sits in the DCDP pre-processor right after ``dcdp_split_state``
(:mod:`lerobot_dcdp.policy.processor_split_state`), before every LeRobot step: the split must run first,
because a robot's flattened ``observation.state`` (18 wide for PushT) has its declared shape only once it is
cut into the policy's inputs. The policy's own check (:mod:`lerobot_dcdp.policy.observation_check`) still
runs on the pre-processed batch for what only the policy knows (missing keys, batch size within a chunk,
non-finite values).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from typing import Any

from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry, RobotObservation


def _dims(shape: tuple[int, ...]) -> str:
    return ", ".join(map(str, shape))


@dataclass
@ProcessorStepRegistry.register(name="dcdp_check_observation")
class CheckObservationProcessorStep(ObservationProcessorStep):
    """Check the shape of every declared input feature an observation carries.

    A feature's trailing dimensions must equal its declared shape; any leading dimensions (batch, time)
    are allowed, since the pre-processor sees unbatched robot observations, batched env observations and
    training batches holding an observation history. Keys the observation lacks pass (the policy's own
    check names missing keys after the pre-processor, which may still rename keys), as do keys the step
    does not declare.

    Attributes:
        shapes: Each checked observation key and its declared shape (without batch or time dimensions).
    """

    shapes: dict[str, tuple[int, ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        shapes: dict[str, tuple[int, ...]] = {}
        for key, shape in dict(self.shapes).items():
            dims = tuple(int(d) for d in shape)
            if not dims or any(d < 1 for d in dims):
                raise ValueError(
                    f"dcdp_check_observation: {key!r} needs a shape of dimensions >= 1, got {shape!r}"
                )
            shapes[str(key)] = dims
        self.shapes = shapes

    @classmethod
    def from_features(
        cls, features: Mapping[str, PolicyFeature] | None, skip: Collection[str] = ()
    ) -> CheckObservationProcessorStep | None:
        """The step for a policy's input features, or ``None`` when none is to be checked.

        Args:
            features: The policy's ``config.input_features``.
            skip: Keys never checked (a DCDP config's recorded-plan columns: training context, no input).

        Returns:
            A step checking every non-``ACTION`` feature not in ``skip``, in input-feature order.
        """
        shapes = {
            key: tuple(ft.shape)
            for key, ft in (features or {}).items()
            if ft.type is not FeatureType.ACTION and key not in skip
        }
        return cls(shapes=shapes) if shapes else None

    def observation(self, observation: RobotObservation) -> RobotObservation:
        """Return ``observation`` unchanged once every declared feature in it has its declared shape.

        Raises:
            ValueError: A feature is not an array, or its trailing dimensions are not its declared shape;
                the message names the feature, the expected and the got shape.
        """
        for key, expected in self.shapes.items():
            if key not in observation:
                continue
            value = observation[key]
            if not hasattr(value, "shape"):
                raise ValueError(
                    f"dcdp_check_observation: observation {key!r} is not an array ({type(value).__name__}); "
                    f"expected shape (..., {_dims(expected)})"
                )
            got = tuple(int(d) for d in value.shape)
            if len(got) < len(expected) or got[len(got) - len(expected) :] != expected:
                raise ValueError(
                    f"dcdp_check_observation: observation {key!r} has shape {got}, expected "
                    f"(..., {_dims(expected)}): the policy declares it with shape {expected} after any batch "
                    "and time dimensions (the env or robot does not give the observation the corrector and "
                    "its base were trained on)"
                )
        return observation

    def get_config(self) -> dict[str, Any]:
        """The declared shapes, as JSON lists."""
        return {"shapes": {key: list(shape) for key, shape in self.shapes.items()}}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        """The features as they are: the step only checks."""
        return features
