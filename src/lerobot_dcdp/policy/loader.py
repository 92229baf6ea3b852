"""The one way to load a DCDP policy with its processors: a trained corrector folder, or a bare base wrapped.

Every tool that runs a DCDP policy outside LeRobot's own CLIs (the benchmark, the correction recorders,
residual RL, the robot client) loads it here, so a folder behaves the same everywhere: a folder whose config
turns its fitted completion gate off runs without one, and the processors are the ones saved in the folder
(for a bare base, the base's own pipelines behind the policy's input step).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy


@dataclass
class LoadedPolicy:
    """A DCDP policy in eval mode and the pipelines that feed it and read its actions."""

    policy: DCDPPolicy
    preprocessor: Any
    postprocessor: Any

    def __iter__(self):
        """``policy, pre, post = load_dcdp(...)``."""
        return iter((self.policy, self.preprocessor, self.postprocessor))


def load_dcdp(
    path: str | Path | None = None,
    *,
    base: str | Path | None = None,
    execution: str | None = None,
    anchor_feature: str | None = None,
    config: DCDPConfig | None = None,
    device: str | None = None,
    extra_inputs: dict | None = None,
    keypoint_reader: str | Path | None = None,
) -> LoadedPolicy:
    """Load a DCDP policy from a corrector folder (``path``) or around a bare base (``base``).

    Args:
        path: A trained corrector's ``pretrained_model`` folder.
        base: A base policy's ``pretrained_model`` folder, wrapped with no corrector (a training-free mode).
        execution: The execution mode to run (default: the folder's; ``open_loop`` around a bare base).
        anchor_feature: The object keypoints' feature, where the folder names none (or around a base).
        config: Flags parsed over the folder's config (``path`` only), as ``--policy.*`` overrides are.
        device: Where the policy and its pre-processor's device step run (default: the folder's, else CPU).
        extra_inputs: Around a bare base, observation features (key -> ``PolicyFeature``) the wrapper reads
            beside the base's own, e.g. the object's keypoints an image base never reads but the training-free
            anchoring does.
        keypoint_reader: Around a bare base, a frame -> keypoints reader's folder (``keypoint_reader_path``):
            the pre-processor writes the object's keypoints estimated from the camera (training-free
            anchoring from pixels).

    Returns:
        The policy in eval mode with its pre- and post-processor.

    Raises:
        ValueError: neither or both of ``path`` and ``base``; ``execution='dcdp'`` around a bare base.
    """
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    if (path is None) == (base is None):
        raise ValueError("give exactly one of path (a trained corrector) or base (a bare base policy)")
    if path is not None:
        policy = DCDPPolicy.from_pretrained(str(path), config=config)
        if not policy.config.completion_gate:  # a folder that turns its fitted gate off runs without one
            policy.completion_gate = None
        policy.config.anchor_feature = policy.config.anchor_feature or anchor_feature
    else:
        if execution == "dcdp":
            raise ValueError("execution='dcdp' needs a trained corrector: pass its folder, not a bare base")
        cfg = DCDPConfig(
            base_policy_path=str(base),
            anchor_feature=anchor_feature,
            device=device or "cpu",
            keypoint_reader_path=str(keypoint_reader) if keypoint_reader else None,
        )
        if extra_inputs or keypoint_reader:
            from lerobot.configs.policies import PreTrainedConfig

            base_config = PreTrainedConfig.from_pretrained(str(base))
            cfg.input_features = {**base_config.input_features, **(extra_inputs or {})}
            cfg.output_features = dict(base_config.output_features)
        policy = DCDPPolicy(cfg)
    if execution is not None:
        policy.config.execution = execution
    policy.eval()
    if path is not None:
        pre, post = folder_processors(policy.config, path, device or policy.config.device or "cpu")
    else:
        pre, post = make_dcdp_pre_post_processors(policy.config)
    return LoadedPolicy(policy, pre, post)


def folder_processors(config: DCDPConfig, path: str | Path, device: str) -> tuple[Any, Any]:
    """The pre- and post-processor saved in the corrector folder ``path``, the device step on ``device``."""
    from lerobot.policies.factory import make_pre_post_processors

    return make_pre_post_processors(
        config, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": device}}
    )
