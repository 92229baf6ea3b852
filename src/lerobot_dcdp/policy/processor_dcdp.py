"""Processors of a DCDP policy: the base's own saved pipelines, plus one step in front.

Wrapper and base must see identical normalised inputs, so the corrector never builds a normaliser from
the training dataset: it loads the base's ``policy_preprocessor.json`` / ``policy_postprocessor.json``
(with the base's statistics and LeRobot's standard step names) and only moves the device step to
``config.device``. In front of the pre-processor it puts two steps of its own:

1. ``dcdp_split_state`` (:class:`~lerobot_dcdp.policy.processor_split_state.SplitStateProcessorStep`),
   which lets stock ``lerobot-rollout`` feed the policy from a robot that flattens its state and the
   environment state into one ``observation.state``; it changes nothing for observations that carry the
   keys separately. It comes first: such a flattened state has its declared shape only once split.
2. ``dcdp_check_observation``
   (:class:`~lerobot_dcdp.policy.processor_check_observation.CheckObservationProcessorStep`), which
   refuses a feature of the wrong shape with one ``ValueError`` naming it, before LeRobot's normaliser
   fails on it with a bare broadcasting error.

With ``keypoint_reader_path`` a third step, ``dcdp_pixel_keypoints``
(:class:`~lerobot_dcdp.policy.processor_pixel_keypoints.PixelKeypointsProcessorStep`), sits between the two:
it writes the object's keypoints estimated from the camera frame, which the check and everything after it
read.
"""

from __future__ import annotations

import logging
from typing import Any

import torch
from lerobot.processor import DeviceProcessorStep, PolicyAction, PolicyProcessorPipeline
from lerobot.processor.converters import (
    batch_to_transition,
    policy_action_to_transition,
    transition_to_batch,
    transition_to_policy_action,
)

from lerobot_dcdp.policy.base_policy import resolve_base_reference
from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.processor_check_observation import CheckObservationProcessorStep
from lerobot_dcdp.policy.processor_pixel_keypoints import PixelKeypointsProcessorStep, reader_step
from lerobot_dcdp.policy.processor_split_state import SplitStateProcessorStep


def make_dcdp_pre_post_processors(
    config: DCDPConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """The base policy's pre/post-processors (its statistics win over ``dataset_stats``).

    The pre-processor starts with :class:`SplitStateProcessorStep` for ``config.input_features`` when the
    policy has ``observation.state`` and another vector input (a split step the base already has is
    replaced), then the keypoint reader's step when the config names a reader, then
    :class:`CheckObservationProcessorStep` for the policy's input features (the recorded
    plan columns excepted; a check step the base already has is replaced), then the base's own steps.
    """
    if dataset_stats is not None:
        logging.info("dcdp: normalising with the base policy's statistics, not the dataset's")
    path = resolve_base_reference(config.base_policy_path, config.pretrained_path)
    pre = PolicyProcessorPipeline.from_pretrained(
        path, "policy_preprocessor.json", to_transition=batch_to_transition, to_output=transition_to_batch
    )
    post = PolicyProcessorPipeline.from_pretrained(
        path,
        "policy_postprocessor.json",
        to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )
    for step in pre.steps:
        if isinstance(step, DeviceProcessorStep) and config.device:
            step.device = config.device
            step.__post_init__()
    steps = [s for s in pre.steps if not isinstance(s, CheckObservationProcessorStep)]
    reader = reader_step(config)
    own = {  # what the env or robot gives: not the reader's estimate
        k: v for k, v in (config.input_features or {}).items() if reader is None or k != reader.output_key
    }
    split = SplitStateProcessorStep.from_features(own)
    if split is not None:
        steps = [split, *(s for s in steps if not isinstance(s, SplitStateProcessorStep))]
    steps = [s for s in steps if not isinstance(s, PixelKeypointsProcessorStep)]
    after_split = 1 if steps and isinstance(steps[0], SplitStateProcessorStep) else 0
    check = CheckObservationProcessorStep.from_features(config.input_features, skip=config.plan_columns)
    if check is not None:  # right after the split (the base's own split when it has one and we none)
        steps.insert(after_split, check)
    if reader is not None:  # between the split and the check: the check sees the estimate
        steps.insert(after_split, reader)
    pre = PolicyProcessorPipeline(
        steps=steps, name=pre.name, to_transition=batch_to_transition, to_output=transition_to_batch
    )
    return pre, post
