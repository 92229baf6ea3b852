"""Loading the frozen base policy a corrector wraps, and checking it is the one stage 1 used."""

from __future__ import annotations

import re
from pathlib import Path

import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.pretrained import PreTrainedPolicy

_HUB_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*/[A-Za-z0-9][A-Za-z0-9_.-]*$")


def resolve_base_reference(ref: str, relative_to: str | Path | None = None) -> str:
    """A local directory or a Hub repo id for a base reference.

    A relative ``ref`` is looked up first beside the corrector (``relative_to``: a saved corrector stores its
    local base relative to its own folder), then in the working directory; ``ref`` is taken for a Hub id only
    when no local candidate exists.

    Raises:
        ValueError: ``ref`` is neither an existing directory nor shaped like ``user/name``; the message names
            every place tried.
    """
    path = Path(ref).expanduser()
    tried = []
    candidates = [path] if path.is_absolute() else []
    if not path.is_absolute():
        if relative_to is not None and Path(relative_to).is_dir():
            candidates.append(Path(relative_to) / path)
        candidates.append(path)
    for cand in candidates:
        if cand.is_dir():
            return str(cand)
        tried.append(str(cand.resolve()))
    if _HUB_ID.match(ref) and not path.exists():
        return ref
    raise ValueError(
        f"base_policy_path={ref!r} is neither a local pretrained_model directory (tried {tried}) nor a Hub "
        "repo id (user/name)"
    )


def portable_base_reference(ref: str, relative_to: str | Path | None, save_directory: str | Path) -> str:
    """What a corrector saved in ``save_directory`` records as its base: a local base's path relative to
    that directory (so the pair can be moved together and loaded from any working directory), a Hub id as is.
    """
    import os

    resolved = resolve_base_reference(ref, relative_to)
    if not Path(resolved).is_dir():
        return ref
    return os.path.relpath(Path(resolved).resolve(), Path(save_directory).resolve())


def load_base_policy(
    ref: str, device: str | None, relative_to: str | Path | None = None, weights: bool = True
) -> PreTrainedPolicy:
    """Load a pretrained policy of any registered type, frozen and in eval mode.

    ``weights=False``: build it from its ``config.json`` alone (untrained weights, no pretrained backbone
    download): what a corrector needs of a base that plans on another machine (its chunk lengths, inputs
    and observation history), never its actions."""
    from lerobot.policies.factory import get_policy_class

    path = resolve_base_reference(ref, relative_to)
    try:
        cfg = PreTrainedConfig.from_pretrained(path)
    except Exception as e:  # a missing folder taken for a Hub id fails inside huggingface_hub
        if Path(path).is_dir():
            raise ValueError(
                f"base_policy_path={ref!r}: {Path(path).resolve()} holds no readable policy config.json ({e})"
            ) from e
        looked = [str((Path(relative_to) / ref).resolve())] if relative_to else []
        looked.append(str(Path(ref).expanduser().resolve()))
        raise ValueError(
            f"base_policy_path={ref!r} is not a local pretrained_model directory (looked in "
            f"{', '.join(looked)}; working directory {Path.cwd()}) and no Hub repo of that name could be "
            "read. Fix: pass the base's absolute path (--policy.base_policy_path=/path/to/pretrained_model) "
            "or run from the directory the relative path starts in"
        ) from e
    if device:
        cfg.device = device
    if weights:
        base = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
    else:
        for field in ("pretrained_backbone_weights", "vision_backbone_weights"):
            if hasattr(cfg, field):
                setattr(cfg, field, None)
        base = get_policy_class(cfg.type)(cfg)
    base.eval()
    for p in base.parameters():
        p.requires_grad_(False)
    return base


def load_base_stats(ref: str, relative_to: str | Path | None = None) -> dict[str, tuple[str, dict]]:
    """How the base's saved normalisers treat each feature: ``{key: (mode, stats)}``.

    ``mode`` is the base normaliser's mode for the feature's type (``MIN_MAX``, ``MEAN_STD``, ...), or
    ``IDENTITY`` for a feature it leaves raw; ``stats`` are float32 tensors. Only a missing processor file is
    tolerated (with a warning); a file that exists but cannot be read raises.
    """
    import logging

    from lerobot.processor import PolicyProcessorPipeline

    path = Path(resolve_base_reference(ref, relative_to))
    out: dict[str, tuple[str, dict]] = {}
    for name in ("policy_preprocessor.json", "policy_postprocessor.json"):
        if path.is_dir() and not (path / name).is_file():
            logging.warning("dcdp: base %s has no %s; its statistics are not used", path, name)
            continue
        pipe = PolicyProcessorPipeline.from_pretrained(str(path), name)
        for step in pipe.steps:
            stats, feats = getattr(step, "stats", None), getattr(step, "features", None)
            if not stats or feats is None:
                continue
            for key, ft in feats.items():
                if key in out or key not in stats:
                    continue
                mode = getattr(step, "norm_map", {}).get(ft.type, "IDENTITY")
                mode = getattr(mode, "value", mode)
                tensors = {
                    k: torch.as_tensor(v, dtype=torch.float32).reshape(-1) for k, v in stats[key].items()
                }
                out[key] = (str(mode), tensors)
    return out


def check_against_base(config, base: PreTrainedPolicy, chunk_length: int, max_length: int) -> None:
    """Refuse a corrector config its base cannot serve, naming the fix; without dataset/env features, take
    the base's.

    Args:
        config: The corrector's ``DCDPConfig`` (its ``input_features`` / ``output_features`` may be empty).
        base: The loaded base policy.
        chunk_length: Actions the base returns per call (``ChunkSource.chunk_length``).
        max_length: The most actions one call can return (``ChunkSource.max_length``).
    """
    bcfg = base.config
    if config.n_action_steps > chunk_length:
        raise ValueError(
            f"n_action_steps={config.n_action_steps} exceeds the base's chunk: base type {bcfg.type!r} "
            f"returns {chunk_length} actions per call; use --policy.n_action_steps between 1 and "
            f"{chunk_length}"
        )
    if config.n_action_steps + config.inference_delay > max_length:
        raise ValueError(
            f"inference_delay={config.inference_delay} needs n_action_steps + inference_delay = "
            f"{config.n_action_steps + config.inference_delay} actions per chunk, but base type "
            f"{bcfg.type!r} returns at most {max_length}"
        )
    if config.output_features and bcfg.output_features:
        ours, theirs = config.action_feature, bcfg.action_feature
        if ours is not None and theirs is not None and tuple(ours.shape) != tuple(theirs.shape):
            raise ValueError(
                f"feature mismatch on 'action': dataset/env shape {tuple(ours.shape)}, "
                f"base {tuple(theirs.shape)}"
            )
    if not config.input_features:
        config.input_features = dict(bcfg.input_features)
        config.output_features = dict(bcfg.output_features)
        return
    for key, ft in (bcfg.input_features or {}).items():
        if key not in config.input_features:
            raise ValueError(
                f"feature mismatch: the base needs input {key!r}, which the dataset/env does not provide "
                f"(has {sorted(config.input_features)}). Fix: train on a dataset that records {key!r} "
                "(re-record or convert it with that feature), evaluate in an env observation type "
                "that reports it (PushT keypoints: --env.obs_type=environment_state_agent_pos), or "
                "wrap a base trained without it"
            )
        if tuple(config.input_features[key].shape) != tuple(ft.shape):
            raise ValueError(
                f"feature mismatch on {key!r}: dataset/env shape {tuple(config.input_features[key].shape)}, "
                f"base {tuple(ft.shape)}"
            )


def load_reference_policy(ref: str, base: PreTrainedPolicy, device: str | None) -> PreTrainedPolicy:
    """Load BID's weak reference policy (``bid_weak_policy_path``) for ``base``: it must read no input the
    base lacks and return the base's action (its statistics may differ: the caller maps between the two).

    Raises:
        ValueError: naming the feature the two policies do not share.
    """
    weak = load_base_policy(ref, device)
    theirs, ours = weak.config, base.config
    if tuple(theirs.action_feature.shape) != tuple(ours.action_feature.shape):
        raise ValueError(
            f"bid_weak_policy_path={ref!r} returns actions of shape {tuple(theirs.action_feature.shape)}, "
            f"the base {tuple(ours.action_feature.shape)}"
        )
    missing = sorted(set(theirs.input_features or {}) - set(ours.input_features or {}))
    if missing:
        raise ValueError(f"bid_weak_policy_path={ref!r} reads {missing}, which the base does not")
    return weak


def default_image_backbone(base: PreTrainedPolicy, base_location: str = "local") -> str:
    """What ``backbone='auto'`` becomes for a corrector that reads a camera: ``base_encoder`` where the base
    lends one image encoder here (:func:`base_image_encoder`), else ``resnet18``. A frozen random ResNet18,
    average-pooled, carries nothing of the object's motion to a linear probe; a trained base's encoder does
    (``scripts/encoder_probe.py``, docs/FINDINGS.md)."""
    try:
        base_image_encoder(base, base_location)
    except ValueError:
        return "resnet18"
    return "base_encoder"


def base_image_encoder(base: PreTrainedPolicy, base_location: str = "local") -> tuple[torch.nn.Module, int]:
    """The base's own frozen image encoder and its output width, for ``backbone='base_encoder'``: the
    ``rgb_encoder`` of LeRobot's diffusion and VQ-BeT policies (it crops as the base does), the only one of a
    base with one camera and separate encoders per camera.

    Raises:
        ValueError: for a base without such an encoder, several per-camera encoders, or a base whose weights
            are not loaded here (``base_location='remote'``).
    """
    if base_location != "local":
        raise ValueError(
            "backbone='base_encoder' reads the base's trained image encoder, which a remote base "
            "(base_location='remote') does not load here: use backbone='resnet18' or base_location='local'"
        )
    inner = getattr(base, {"diffusion": "diffusion", "vqbet": "vqbet"}.get(base.config.type, ""), None)
    encoder = getattr(inner, "rgb_encoder", None)
    if encoder is None:
        raise ValueError(
            f"backbone='base_encoder' needs a base with one image encoder (LeRobot diffusion or vqbet "
            f"reading a camera); base type {base.config.type!r} has none: use backbone='resnet18'"
        )
    if isinstance(encoder, torch.nn.ModuleList):  # use_separate_rgb_encoder_per_camera
        if len(encoder) != 1:
            raise ValueError(
                f"backbone='base_encoder': the base has one image encoder per camera ({len(encoder)}), the "
                "corrector one for all: use backbone='resnet18'"
            )
        encoder = encoder[0]
    return encoder, int(encoder.feature_dim)
