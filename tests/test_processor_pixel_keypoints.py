"""`dcdp_pixel_keypoints`: the pre-processor step writing the object's keypoints estimated from the frame."""

from __future__ import annotations

import json

import pytest
import torch
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import PolicyProcessorPipeline
from lerobot.processor.converters import batch_to_transition, transition_to_batch
from safetensors.torch import save_file

from lerobot_dcdp.model.pixel_keypoints import (
    CONFIG_NAME,
    WEIGHTS_NAME,
    PixelKeypointNet,
    PixelKeypointsConfig,
)
from lerobot_dcdp.policy.processor_pixel_keypoints import PixelKeypointsProcessorStep

CAMERA = {"observation.image": PolicyFeature(FeatureType.VISUAL, (3, 24, 24))}


def _reader_folder(path, seed: int = 0) -> PixelKeypointNet:
    """A random reader on 3x24x24 frames (4 outputs), saved as dcdp-fit-pixel-keypoints saves one."""
    torch.manual_seed(seed)
    cfg = PixelKeypointsConfig(
        image_shape=(3, 24, 24),
        n_outputs=4,
        channels=(4, 8),
        n_maps=4,
        hidden_dim=8,
        shift=[100.0, 200.0, 300.0, 400.0],
        scale=[10.0, 20.0, 30.0, 40.0],
    )
    net = PixelKeypointNet(cfg).eval()
    path.mkdir()
    (path / CONFIG_NAME).write_text(
        json.dumps(
            {**cfg.to_dict(), "image_key": "observation.image", "target_key": "observation.environment_state"}
        )
    )
    save_file(net.state_dict(), str(path / WEIGHTS_NAME))
    return net


def test_step_writes_the_readers_estimate_for_any_leading_dims(tmp_path) -> None:
    net = _reader_folder(tmp_path / "reader")
    step = PixelKeypointsProcessorStep.from_folder(tmp_path / "reader")
    assert (step.image_key, step.output_key, step.n_outputs) == (
        "observation.image",
        "observation.environment_state",
        4,
    )
    frames = torch.rand(2, 3, 3, 24, 24)  # batch, history
    truth = torch.full((2, 3, 4), -1.0)
    out = step.observation(
        {
            "observation.image": frames,
            "observation.state": torch.zeros(2, 3, 2),
            "observation.environment_state": truth,
        }
    )
    with torch.no_grad():
        expected = net(frames)
    assert out["observation.environment_state"].shape == (2, 3, 4)
    torch.testing.assert_close(out["observation.environment_state"], expected)  # replaces the recorded truth
    assert out["observation.environment_state"].mean() > 50  # raw units: de-standardised by the fit's shift
    # a robot's uint8 frame reads as the same [0, 1] frame
    raw = (frames[0, 0] * 255).round().to(torch.uint8)
    torch.testing.assert_close(step.estimate(raw), step.estimate(raw.float() / 255))
    # no frame: unchanged
    obs = {"observation.state": torch.zeros(1, 2)}
    assert step.observation(obs) is obs


def test_step_refuses_frames_of_another_size(tmp_path) -> None:
    _reader_folder(tmp_path / "reader")
    step = PixelKeypointsProcessorStep.from_folder(tmp_path / "reader", output_key="observation.kp")
    with pytest.raises(ValueError, match=r"'observation.image' has shape \(1, 3, 96, 96\).*3, 24, 24"):
        step.observation({"observation.image": torch.rand(1, 3, 96, 96)})


def test_step_declares_its_output_and_round_trips_with_its_weights(tmp_path) -> None:
    _reader_folder(tmp_path / "reader", seed=3)
    step = PixelKeypointsProcessorStep.from_folder(tmp_path / "reader", output_key="observation.kp")
    feats = step.transform_features({PipelineFeatureType.OBSERVATION: CAMERA})
    assert feats[PipelineFeatureType.OBSERVATION]["observation.kp"] == PolicyFeature(FeatureType.ENV, (4,))
    pipe = PolicyProcessorPipeline(
        steps=[step], name="pre", to_transition=batch_to_transition, to_output=transition_to_batch
    )
    pipe.save_pretrained(tmp_path / "saved")
    assert list((tmp_path / "saved").glob("*dcdp_pixel_keypoints.safetensors"))
    loaded = PolicyProcessorPipeline.from_pretrained(
        tmp_path / "saved", "pre.json", to_transition=batch_to_transition, to_output=transition_to_batch
    )
    frames = {"observation.image": torch.rand(3, 3, 24, 24)}
    torch.testing.assert_close(loaded(dict(frames))["observation.kp"], pipe(dict(frames))["observation.kp"])
    # a fresh step of the same architecture (random weights) differs: the weights came from the file
    fresh = PixelKeypointsProcessorStep(output_key="observation.kp", reader=step.get_config()["reader"])
    img = frames["observation.image"]
    assert not torch.allclose(fresh.estimate(img), step.estimate(img))
