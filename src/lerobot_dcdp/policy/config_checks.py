"""Validation of :class:`~lerobot_dcdp.policy.configuration_dcdp.DCDPConfig`'s options, one pure function per
group.

Each ``check_*`` function reads a group of option values (keyword arguments named as the ``--policy.*``
flags) and raises one ``ValueError`` naming the first bad option and what it must be; it returns nothing
and changes nothing. ``DCDPConfig.__post_init__`` calls them in turn, so the flags stay flat, as LeRobot's
own policy configs have them.
"""

from __future__ import annotations

import difflib

from lerobot_dcdp.model.completion_gate import GATED_MODES  # noqa: F401  (re-exported: a config check)

EXECUTION_MODES = ("dcdp", "open_loop", "closed_loop", "temporal_ensemble", "object_anchored", "bid")
CORRECTIONS = ("reconstruct", "residual")
BACKBONES = ("auto", "mlp", "resnet18", "base_encoder")
KERNEL_CHOICES = ("auto", "on", "off")
PLANNING_MODES = ("sync", "async")
PLANNING_CLOCKS = ("wall", "steps")
BASE_LOCATIONS = ("local", "remote")
#: Execution modes that run one chunk for several ticks (the ones asynchronous planning applies to).
CHUNK_MODES = ("dcdp", "open_loop", "object_anchored")
PLANNER_PRIORITIES = ("normal", "idle")
MOTION_LABELS = ("observed", "added", "graded")


def check_choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    """Refuse a value outside ``choices``, suggesting the closest valid one."""
    if value in choices:
        return
    close = difflib.get_close_matches(str(value).replace("-", "_"), choices, n=1, cutoff=0.5)
    hint = f" -- did you mean {close[0]!r}? (--policy.{name}={close[0]})" if close else ""
    raise ValueError(f"{name} must be one of {choices}, got {value!r}{hint}")


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_execution(
    *,
    base_policy_path: str | None,
    n_history: int,
    n_action_steps: int,
    inference_delay: int,
    execution: str,
    te_weight: float,
) -> None:
    """The base, the chunk and how it is executed."""
    if not base_policy_path:
        raise ValueError(
            "base_policy_path is required: the pretrained_model directory or Hub id of the frozen "
            "chunking policy to correct (--policy.base_policy_path=...)"
        )
    if n_history < 2:
        raise ValueError(f"n_history must be >= 2 (differentials need two frames), got {n_history}")
    if n_action_steps < 1:
        raise ValueError(f"n_action_steps must be >= 1, got {n_action_steps}")
    if inference_delay < 0:
        raise ValueError(f"inference_delay must be >= 0 control steps, got {inference_delay}")
    check_choice("execution", execution, EXECUTION_MODES)
    if not 0.0 < te_weight <= 1.0:
        raise ValueError(f"te_weight must be in (0, 1], got {te_weight}")


def check_planning(
    *,
    execution: str,
    planning: str,
    planning_clock: str,
    planner_cpus: list[int] | None,
    planner_priority: str,
    ticks_per_step: int,
    base_location: str,
) -> None:
    """Where and when the base plans (synchronous or on a worker, local or remote) and the tick rate."""
    check_choice("planning", planning, PLANNING_MODES)
    check_choice("planning_clock", planning_clock, PLANNING_CLOCKS)
    if planner_cpus is not None:
        if (
            not planner_cpus
            or len(set(planner_cpus)) != len(planner_cpus)
            or any(not _is_int(c) or c < 0 for c in planner_cpus)
        ):
            raise ValueError(f"planner_cpus must be distinct CPU numbers >= 0, got {planner_cpus!r}")
        if planning != "async":
            raise ValueError("planner_cpus pins the async worker: use it with --policy.planning=async")
    check_choice("planner_priority", planner_priority, PLANNER_PRIORITIES)
    if planner_priority != "normal" and planning != "async":
        raise ValueError("planner_priority schedules the async worker: use it with --policy.planning=async")
    if not _is_int(ticks_per_step) or ticks_per_step < 1:
        raise ValueError(f"ticks_per_step must be an integer >= 1, got {ticks_per_step!r}")
    check_choice("base_location", base_location, BASE_LOCATIONS)
    if base_location == "remote" and planning != "async":
        raise ValueError(
            "base_location='remote' plans every chunk on the remote base: use --policy.planning=async"
        )
    if planning == "async" and execution not in CHUNK_MODES:
        raise ValueError(
            f"planning='async' applies to the chunk modes {CHUNK_MODES}; execution={execution!r} "
            "replans every step (use --policy.planning=sync)"
        )


def check_correction(
    *,
    execution: str,
    correction: str,
    anchor_feature: str | None,
    anchor_input: bool,
    change_scale: float,
    compiled_kernel: str,
    completion_radius: float | None,
    lead_steps: int,
    lead_window: int,
    lead_tolerance: float,
    lead_repeats: int,
    lead_noise: float,
) -> None:
    """How the corrector corrects: its recipe, the anchor keypoints, the compiled path, the gate and the
    scene lead."""
    check_choice("correction", correction, CORRECTIONS)
    if execution == "object_anchored" and not anchor_feature:
        raise ValueError(
            "execution='object_anchored' needs anchor_feature: the observation key holding the object's "
            "xy keypoints (PushT: --policy.anchor_feature=observation.environment_state)"
        )
    if anchor_input and not (anchor_feature and correction == "residual"):
        raise ValueError("anchor_input needs correction='residual' and an anchor_feature")
    if not change_scale > 0:
        raise ValueError(f"change_scale must be > 0, got {change_scale}")
    check_choice("compiled_kernel", compiled_kernel, KERNEL_CHOICES)
    if completion_radius is not None and not completion_radius > 0:
        raise ValueError(
            f"completion_radius must be > 0 (or None: no gate fitted), got {completion_radius!r}"
        )
    if not _is_int(lead_steps) or lead_steps < 0:
        raise ValueError(f"lead_steps must be an int >= 0 (0: no scene lead), got {lead_steps!r}")
    if not _is_int(lead_window) or lead_window < 2:
        raise ValueError(
            f"lead_window must be an int >= 2 (steps of the object's motion), got {lead_window!r}"
        )
    if not lead_tolerance >= 0:
        raise ValueError(
            f"lead_tolerance must be >= 0 (a fraction of the motion's length), got {lead_tolerance!r}"
        )
    if not lead_noise >= 0:
        raise ValueError(f"lead_noise must be >= 0 (the tracker's per-step noise), got {lead_noise!r}")
    if not _is_int(lead_repeats) or lead_repeats < 2:
        raise ValueError(
            f"lead_repeats must be an int >= 2 (steps that repeat the world's motion), got {lead_repeats!r}"
        )
    if lead_steps and lead_repeats > lead_window:
        raise ValueError(
            f"lead_repeats ({lead_repeats}) must be <= lead_window ({lead_window}): the window holds the "
            "steps that repeat the world's motion"
        )
    if lead_steps and not anchor_feature:
        raise ValueError(
            "lead_steps needs anchor_feature: the observation key holding the object's xy keypoints, whose "
            "motion the scene is led by"
        )


def check_synthesis(
    *,
    motion_max_speed: float | None,
    motion_max_turn_deg: float,
    motion_static_fraction: float,
    motion_label: str,
    motion_full_carry_at: float | None,
    motion_min_carry_speed: float,
    motions_per_sample: int,
    train_max_delay: int,
) -> None:
    """The object motion synthesised on plain demonstrations, and the late chunks of training."""
    if motion_max_speed is not None and not motion_max_speed >= 0:
        raise ValueError(f"motion_max_speed must be >= 0 (or None for the default), got {motion_max_speed}")
    if not motion_max_turn_deg >= 0:
        raise ValueError(f"motion_max_turn_deg must be >= 0, got {motion_max_turn_deg}")
    if not 0.0 <= motion_static_fraction <= 1.0:
        raise ValueError(f"motion_static_fraction must be in [0, 1], got {motion_static_fraction}")
    check_choice("motion_label", motion_label, MOTION_LABELS)
    if motion_full_carry_at is not None and not motion_full_carry_at > 0:
        raise ValueError(
            f"motion_full_carry_at must be > 0 (or None for the default), got {motion_full_carry_at}"
        )
    if not motion_min_carry_speed >= 0:
        raise ValueError(f"motion_min_carry_speed must be >= 0, got {motion_min_carry_speed}")
    if motion_max_speed is not None and motion_min_carry_speed > motion_max_speed:
        raise ValueError(
            f"motion_min_carry_speed ({motion_min_carry_speed}) is above motion_max_speed "
            f"({motion_max_speed}): no synthesised motion would be carried"
        )
    if motions_per_sample < 1:
        raise ValueError(f"motions_per_sample must be >= 1, got {motions_per_sample}")
    if train_max_delay < 0:
        raise ValueError(f"train_max_delay must be >= 0 control steps, got {train_max_delay}")


def check_network(
    *,
    backbone: str,
    feature_dim: int,
    state_hidden_dim: int,
    latent_dim: int,
    encoder_hidden_dim: int,
    decoder_hidden_dim: int,
    step_embed_dim: int,
    n_heads: int,
    kl_weight: float,
    diff_weight: float,
) -> None:
    """The corrector's networks: backbone, widths and loss weights."""
    check_choice("backbone", backbone, BACKBONES)
    widths = {
        "feature_dim": feature_dim,
        "state_hidden_dim": state_hidden_dim,
        "latent_dim": latent_dim,
        "encoder_hidden_dim": encoder_hidden_dim,
        "decoder_hidden_dim": decoder_hidden_dim,
        "step_embed_dim": step_embed_dim,
        "n_heads": n_heads,
    }
    for name, value in widths.items():
        if value < 1:
            raise ValueError(f"{name} must be >= 1, got {value}")
    if feature_dim % n_heads:
        raise ValueError(f"feature_dim ({feature_dim}) must be divisible by n_heads ({n_heads})")
    for name, value in (("kl_weight", kl_weight), ("diff_weight", diff_weight)):
        if value < 0:
            raise ValueError(f"{name} must be >= 0, got {value}")


#: Every option group's check, in the order ``DCDPConfig`` runs them.
def check_bid(
    *,
    execution: str,
    n_action_steps: int,
    inference_delay: int,
    bid_samples: int,
    bid_modes: int,
    bid_decay: float,
    bid_replan_every: int,
    bid_weak_policy_path: str | None,
) -> None:
    """Bidirectional Decoding's knobs (checked whatever the mode, so a bad flag fails at once)."""
    if not _is_int(bid_samples) or bid_samples < 1:
        raise ValueError(f"bid_samples must be an integer >= 1, got {bid_samples!r}")
    if not _is_int(bid_modes) or not 1 <= bid_modes <= bid_samples:
        raise ValueError(f"bid_modes must be an integer in [1, bid_samples={bid_samples}], got {bid_modes!r}")
    if not bid_decay > 0:
        raise ValueError(f"bid_decay must be > 0, got {bid_decay}")
    if not _is_int(bid_replan_every) or not 1 <= bid_replan_every <= n_action_steps:
        raise ValueError(
            f"bid_replan_every must be an integer in [1, n_action_steps={n_action_steps}], "
            f"got {bid_replan_every!r}"
        )
    if execution == "bid" and inference_delay:
        raise ValueError("execution='bid' plans on the tick it acts: it takes no inference_delay")
    if execution != "bid" and bid_weak_policy_path:
        raise ValueError(f"bid_weak_policy_path is read by execution='bid' only (execution={execution!r})")


CHECKS = (check_execution, check_planning, check_correction, check_synthesis, check_network, check_bid)
