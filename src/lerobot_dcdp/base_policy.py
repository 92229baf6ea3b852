"""Loading the frozen base policy a corrector wraps, and checking it is the one stage 1 used."""

from __future__ import annotations

import re
from pathlib import Path

from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.pretrained import PreTrainedPolicy

_HUB_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*/[A-Za-z0-9][A-Za-z0-9_.-]*$")


def resolve_base_reference(ref: str, relative_to: str | Path | None = None) -> str:
    """A local directory (as given, or relative to the corrector's own directory) or a Hub repo id.

    Raises:
        ValueError: ``ref`` is neither an existing directory nor shaped like ``user/name``.
    """
    path = Path(ref).expanduser()
    if path.is_dir():
        return str(path)
    if relative_to is not None and not path.is_absolute():
        cand = Path(relative_to) / path
        if cand.is_dir():
            return str(cand)
    if _HUB_ID.match(ref) and not path.exists():
        return ref
    raise ValueError(
        f"base_policy_path={ref!r} is neither a local pretrained_model directory nor a Hub repo id"
    )


def load_base_policy(ref: str, device: str | None, relative_to: str | Path | None = None) -> PreTrainedPolicy:
    """Load a pretrained policy of any registered type, frozen and in eval mode."""
    from lerobot.policies.factory import get_policy_class

    path = resolve_base_reference(ref, relative_to)
    try:
        cfg = PreTrainedConfig.from_pretrained(path)
    except FileNotFoundError as e:
        raise ValueError(f"base_policy_path={ref!r}: no policy config.json found ({e})") from e
    if device:
        cfg.device = device
    base = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
    base.eval()
    for p in base.parameters():
        p.requires_grad_(False)
    return base


def load_base_action_stats(ref: str, relative_to: str | Path | None = None) -> dict | None:
    """The base's own action statistics, from its saved post-processor (None when it has none)."""
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.utils.constants import ACTION

    path = resolve_base_reference(ref, relative_to)
    try:
        post = PolicyProcessorPipeline.from_pretrained(path, "policy_postprocessor.json")
    except Exception:  # noqa: BLE001 - a base saved without processors: fall back to the unit range
        return None
    for step in post.steps:
        stats = getattr(step, "stats", None)
        if stats and ACTION in stats:
            return stats[ACTION]
    return None
