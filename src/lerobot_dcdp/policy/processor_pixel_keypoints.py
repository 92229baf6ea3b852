"""``dcdp_pixel_keypoints``: estimate the object's keypoints from the camera frame, in the pre-processor.

The image path of DCDP. The residual corrector, the training-free anchoring and the completion gate read the
object's keypoints and what changed since the plan; a camera robot has none at run time. This step runs a
frozen frame -> keypoints reader (:class:`~lerobot_dcdp.model.pixel_keypoints.PixelKeypointNet`, fitted by
``dcdp-fit-pixel-keypoints`` on frames whose keypoints were known at training time) on ``image_key`` and
writes its estimate to ``output_key`` (PushT: ``observation.environment_state``), so everything downstream
runs unchanged on the estimate, and the env or robot only gives the frame and the robot's state.

It sits in the DCDP pre-processor right after ``dcdp_split_state`` and before ``dcdp_check_observation``
and LeRobot's normaliser: the reader reads the raw frame (values in [0, 1]), as it was fitted. An estimate
replaces keypoints the observation already holds (a recorded dataset's simulator keypoints), so the
corrector trains on what it will read at run time. Its weights are saved with the pre-processor
(``policy_preprocessor_step_*_dcdp_pixel_keypoints.safetensors``), so a trained corrector folder needs no
reader folder.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry, RobotObservation
from torch import Tensor

from lerobot_dcdp.model.pixel_keypoints import PixelKeypointNet, PixelKeypointsConfig, load_reader


@dataclass
@ProcessorStepRegistry.register(name="dcdp_pixel_keypoints")
class PixelKeypointsProcessorStep(ObservationProcessorStep):
    """Write the reader's keypoint estimate of ``image_key`` to ``output_key``.

    Frames may carry any leading dimensions (an env's batch, a training batch's history); observations
    without ``image_key`` pass unchanged.

    Attributes:
        image_key: The camera observation the reader reads, (..., C, H, W) in [0, 1].
        output_key: Where the estimated keypoints go, (..., n_outputs) in the keypoints' raw units.
        reader: The reader's architecture (:class:`PixelKeypointsConfig` fields); its weights are the step's
            state dict.
    """

    image_key: str = "observation.image"
    output_key: str = "observation.environment_state"
    reader: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.net = PixelKeypointNet(PixelKeypointsConfig(**self.reader)).eval()
        self.net.requires_grad_(False)

    @classmethod
    def from_folder(cls, path: str | Path, output_key: str | None = None) -> PixelKeypointsProcessorStep:
        """The step of a reader folder saved by ``dcdp-fit-pixel-keypoints`` (its weights loaded).

        Args:
            path: The reader's folder.
            output_key: Where the estimate goes; default the key the reader was fitted to (its target).
        """
        net, image_key, target_key = load_reader(path)
        step = cls(image_key=image_key, output_key=output_key or target_key, reader=net.config.to_dict())
        step.net.load_state_dict(net.state_dict())
        return step

    @property
    def n_outputs(self) -> int:
        """Width of the keypoint vector the step writes."""
        return self.net.config.n_outputs

    def estimate(self, frames: Tensor) -> Tensor:
        """The reader's keypoints of ``frames`` (..., C, H, W), float32 on the frames' device.

        Raises:
            ValueError: The frames' trailing shape is not the one the reader was fitted on.
        """
        expected = tuple(self.net.config.image_shape)
        if tuple(frames.shape[-3:]) != expected:
            raise ValueError(
                f"dcdp_pixel_keypoints: {self.image_key!r} has shape {tuple(frames.shape)}, the reader was "
                f"fitted on (..., {', '.join(map(str, expected))}) frames"
            )
        if frames.dtype == torch.uint8:  # a robot's raw camera frame
            frames = frames.float() / 255
        net = self.net.to(frames.device)
        with torch.no_grad():
            return net(frames.float())

    def observation(self, observation: RobotObservation) -> RobotObservation:
        """``observation`` with ``output_key`` set to the estimate from ``image_key`` (if it has a frame)."""
        frames = observation.get(self.image_key)
        if frames is None:
            return observation
        out = dict(observation)
        out[self.output_key] = self.estimate(torch.as_tensor(frames))
        return out

    def get_config(self) -> dict[str, Any]:
        """The keys and the reader's architecture (JSON-ready)."""
        reader = self.net.config.to_dict()
        return {"image_key": self.image_key, "output_key": self.output_key, "reader": reader}

    def state_dict(self) -> dict[str, Tensor]:
        """The reader's weights and its normalisation buffers."""
        return {k: v.detach().cpu().contiguous() for k, v in self.net.state_dict().items()}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        """Load the reader's weights (all of them: a partial reader is refused by ``strict`` loading)."""
        self.net.load_state_dict(state)

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        """The features plus ``output_key`` (an environment-state vector of the reader's width)."""
        obs = dict(features.get(PipelineFeatureType.OBSERVATION, {}))
        obs[self.output_key] = PolicyFeature(type=FeatureType.ENV, shape=(self.n_outputs,))
        return {**features, PipelineFeatureType.OBSERVATION: obs}


def reader_step(config) -> PixelKeypointsProcessorStep | None:
    """The step of a DCDP config's ``keypoint_reader_path`` (writing to its ``anchor_feature`` when set);
    ``None`` without a reader."""
    if not config.keypoint_reader_path:
        return None
    return PixelKeypointsProcessorStep.from_folder(config.keypoint_reader_path, config.anchor_feature)


def declare_reader_output(config) -> None:
    """Add the reader's estimate and its camera to ``config.input_features`` where they are not there: a
    dataset without the object's keypoints (the policy reads them from the pre-processor), or one holding the
    precomputed estimate without the camera (``dcdp-precompute-keypoints --drop-cameras``: at run time the
    reader reads the camera)."""
    if not config.keypoint_reader_path or config.input_features is None:
        return
    feats = config.input_features
    key = config.anchor_feature
    has_output = key in feats if key else any(f.type is FeatureType.ENV for f in feats.values())
    if has_output and any(f.type is FeatureType.VISUAL for f in feats.values()):
        return  # e.g. a trained folder: nothing to read from the reader's folder
    step = reader_step(config)
    declared = {
        step.output_key: PolicyFeature(type=FeatureType.ENV, shape=(step.n_outputs,)),
        step.image_key: PolicyFeature(type=FeatureType.VISUAL, shape=tuple(step.net.config.image_shape)),
    }
    config.input_features = {**feats, **{k: v for k, v in declared.items() if k not in feats}}


def with_reader_stats(config, stats: dict) -> dict:
    """``stats`` with the reader's estimate's mean and std (the keypoint statistics it was fitted on) when
    the dataset has none for it: a dataset of frames without the object's keypoints still standardises what
    the corrector reads."""
    step = reader_step(config)
    if step is None or "mean" in stats.get(step.output_key, {}):
        return stats
    cfg = step.net.config
    if not cfg.shift or not cfg.scale:
        return stats
    return {**stats, step.output_key: {"mean": torch.tensor(cfg.shift), "std": torch.tensor(cfg.scale)}}
