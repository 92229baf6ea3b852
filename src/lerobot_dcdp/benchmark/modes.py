"""The model folders the benchmark runs: loading a corrector with its base (and its identity), which
methods a folder can run, and switching it to a method's execution mode."""

from __future__ import annotations

from typing import Any

from lerobot_dcdp.benchmark.identity import lead_identity
from lerobot_dcdp.model.correction import state_dict_sha256


def load_model(corrector_dir: str, device: str | None = None) -> tuple[Any, Any, Any, dict]:
    """The corrector (with its base) and the processors saved beside it.

    Args:
        corrector_dir: The corrector folder.
        device: Where the policy runs (default: the folder's; e.g. ``cuda`` for BID's sampling).

    Returns:
        ``(policy, preprocessor, postprocessor, identity)``; the identity (paths, hashes, parameter count,
        completion gate and scene lead) is what a stored cell is reused by.
    """
    import lerobot_policy_dcdp  # noqa: F401
    from lerobot_dcdp.policy.loader import load_dcdp

    policy, pre, post = load_dcdp(corrector_dir, device=device)
    identity = {
        "corrector": corrector_dir,
        "corrector_sha256": policy.corrector_sha256(),
        "base": policy.config.base_policy_path,
        "base_type": policy.config.base_policy_type,
        "base_weights_sha256": policy.config.base_weights_sha256,
        "corrector_params": sum(p.numel() for p in policy.parameters()),
    }
    if policy.completion_gate is not None:  # not part of corrector_sha256: its own identity
        identity["completion_gate_sha256"] = state_dict_sha256(policy.completion_gate.state_dict())
    identity.update(lead_identity(policy.config))
    policy.folder_lead_steps = policy.config.lead_steps  # set_mode turns it off for the plain rule only
    return policy, pre, post, identity


def set_mode(policy: Any, method: str, delay: int = 0) -> None:
    """Run ``policy`` as the benchmark's ``method``: an execution mode, ``object_anchored`` always the plain
    rule, ``gated_anchored`` the rule with the folder's completion gate; ``dcdp`` and ``gated_anchored``
    with the folder's scene lead (``lead_steps``; the other modes never lead).

    Args:
        policy: A loaded DCDP policy.
        method: A benchmark method (``METHODS``).
        delay: Inference delay in control steps.

    Raises:
        ValueError: ``delay`` is out of range for the base, or ``gated_anchored`` without a completion gate.
    """
    limit = policy.source.max_length - policy.config.n_action_steps
    if not 0 <= delay <= limit:
        raise ValueError(f"inference_delay {delay} is out of range for this base: 0..{limit}")
    if method == "gated_anchored" and policy.completion_gate is None:
        raise ValueError("gated_anchored needs a folder with a completion gate (dcdp-fit-completion-gate)")
    policy.config.execution = "object_anchored" if method == "gated_anchored" else method
    policy.config.completion_gate = policy.completion_gate is not None and method != "object_anchored"
    if not hasattr(policy, "folder_lead_steps"):  # load_model records it; else the first call does
        policy.folder_lead_steps = policy.config.lead_steps
    policy.config.lead_steps = policy.folder_lead_steps if method in ("dcdp", "gated_anchored") else 0
    policy.config.inference_delay = delay
    policy.config.ticks_per_step = 1  # lock-step: every env step is one planned step
    policy.reset()


def obs_type(policy: Any) -> str:
    """The PushT observation type that gives ``policy`` (corrector and base) what it reads and no more: the
    frame when it reads a camera, the block keypoints when it reads them from the env (the keypoint reader's
    estimate in its pre-processor comes from the frame), the agent position always."""
    from lerobot.configs.types import FeatureType

    cfg = policy.config
    declared = cfg.input_features or {}
    read = [*cfg.corrector_features, *([cfg.anchor_feature] if cfg.anchor_feature else [])]
    feats = {**(policy.base.config.input_features or {}), **{k: declared[k] for k in read if k in declared}}
    estimated = (cfg.anchor_feature or "observation.environment_state") if cfg.keypoint_reader_path else None
    camera = any(f.type is FeatureType.VISUAL for f in feats.values()) or estimated is not None
    keypoints = any(f.type is FeatureType.ENV and k != estimated for k, f in feats.items())
    if camera:
        return "pixels_environment_state_agent_pos" if keypoints else "pixels_agent_pos"
    return "environment_state_agent_pos"


def runs(method: str, policy: Any) -> bool:
    """Whether ``policy``'s folder can run ``method``: the anchorings need an anchor feature, the gated one a
    fitted completion gate, BID a base that samples."""
    if method == "object_anchored":
        return bool(policy.config.anchor_feature)
    if method == "gated_anchored":
        return bool(policy.config.anchor_feature) and policy.completion_gate is not None
    if method == "bid":
        from lerobot_dcdp.runtime.execution_modes import DETERMINISTIC_BASES

        return policy.config.base_policy_type not in DETERMINISTIC_BASES
    return True
