"""The benchmark gives each folder the PushT observation type carrying what it reads and no more."""

from __future__ import annotations

from types import SimpleNamespace

from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_dcdp.benchmark.modes import obs_type

IMAGE = PolicyFeature(FeatureType.VISUAL, (3, 96, 96))
STATE = PolicyFeature(FeatureType.STATE, (2,))
KP = PolicyFeature(FeatureType.ENV, (16,))


def _policy(base: dict, inputs: dict, corrector: list[str], anchor=None, reader=None) -> SimpleNamespace:
    config = SimpleNamespace(
        input_features=inputs,
        corrector_features=corrector,
        anchor_feature=anchor,
        keypoint_reader_path=reader,
    )
    return SimpleNamespace(config=config, base=SimpleNamespace(config=SimpleNamespace(input_features=base)))


def test_each_folder_gets_the_observation_it_reads() -> None:
    keypoint_base = {"observation.state": STATE, "observation.environment_state": KP}
    image_base = {"observation.image": IMAGE, "observation.state": STATE}
    # a keypoint corrector around a keypoint base
    kp = _policy(
        keypoint_base, keypoint_base, ["observation.environment_state"], "observation.environment_state"
    )
    assert obs_type(kp) == "environment_state_agent_pos"
    # an image corrector whose keypoints come from the frame: no simulator keypoints, even when its training
    # dataset held them (declared, never read)
    inputs = {**image_base, "observation.environment_state": KP, "observation.kp_estimate": KP}
    image = _policy(image_base, inputs, ["observation.kp_estimate"], "observation.kp_estimate", "reader")
    assert obs_type(image) == "pixels_agent_pos"
    # the privileged rule around an image base: the simulator's keypoints beside the frame
    privileged = _policy(
        image_base, {**image_base, "observation.environment_state": KP}, [], "observation.environment_state"
    )
    assert obs_type(privileged) == "pixels_environment_state_agent_pos"
    # a keypoint base with a corrector reading pixels (the reader's estimate under another key)
    pix = _policy(
        keypoint_base,
        {**keypoint_base, "observation.kp_estimate": KP},
        ["observation.kp_estimate"],
        "observation.kp_estimate",
        "reader",
    )
    assert obs_type(pix) == "pixels_environment_state_agent_pos"
