"""Processors of a DCDP policy: exactly the base's own saved pipelines.

Wrapper and base must see identical normalised inputs, so the corrector never builds a normaliser from
the training dataset: it loads the base's ``policy_preprocessor.json`` / ``policy_postprocessor.json``
(with the base's statistics and LeRobot's standard step names) and only moves the device step to
``config.device``.
"""

from __future__ import annotations

import logging
from typing import Any

import torch
from lerobot.processor import PolicyAction, PolicyProcessorPipeline
from lerobot.processor.converters import (
    batch_to_transition,
    policy_action_to_transition,
    transition_to_batch,
    transition_to_policy_action,
)

from lerobot_dcdp.base_policy import resolve_base_reference
from lerobot_dcdp.configuration_dcdp import DCDPConfig


def make_dcdp_pre_post_processors(
    config: DCDPConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """The base policy's pre/post-processors (its statistics win over ``dataset_stats``)."""
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
    from lerobot.processor import DeviceProcessorStep

    for step in pre.steps:
        if isinstance(step, DeviceProcessorStep) and config.device:
            step.device = config.device
            step.__post_init__()
    return pre, post
