"""Make a copy of a base policy that LeRobot's stock policy server can serve to ``dcdp-robot-client``.

``python -m lerobot.async_inference.policy_server`` (LeRobot 0.6.1) loads the folder a client names with the
base's own saved pre-/post-processors and feeds it the robot's scalar features as one ``observation.state``.
Three things stop a PushT base (and any base reading several vector inputs or frames) from running there as
it was saved; the copy fixes them without touching the weights:

* the robot flattens ``observation.state`` and ``observation.environment_state`` into one vector: the copy's
  pre-processor starts with ``dcdp_split_state`` (:mod:`lerobot_dcdp.policy.processor_split_state`);
* a base with ``n_obs_steps > 1`` (diffusion) gets no history from the server (its queues stay empty): the
  client packs the frames into ``observation.state`` and ``dcdp_state_history``
  (:mod:`lerobot_dcdp.policy.processor_state_history`) unflattens them, in front of the split;
* the stock server never runs LeRobot's plugin discovery (``register_third_party_plugins``), so a step saved
  under its registry name (``dcdp_split_state``) is unknown there: the copy names both steps by import path
  (``"class": "lerobot_dcdp...."``), which LeRobot's loader imports (this registers the plugin as well).

A horizon-slicing base (diffusion) returns ``n_action_steps`` actions per call; the copy sets
``n_action_steps = horizon - n_obs_steps + 1`` (the most one denoised horizon holds, what dcdp's
``ChunkSource.max_length`` reads locally) so the client's ``--actions_per_chunk`` decides how many come back.

Usage::

    dcdp-serve-base --base models/pusht-diffusion-state --out runs/served/pusht-diffusion-state
    python -m lerobot.async_inference.policy_server --host=127.0.0.1 --port=8080   # same machine as --out
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path
from typing import Any

from lerobot_dcdp.data.atomic_dataset import staged_dir

#: Import paths written into the served copy's pre-processor (the stock server imports them).
SPLIT_STEP_CLASS = "lerobot_dcdp.policy.processor_split_state.SplitStateProcessorStep"
HISTORY_STEP_CLASS = "lerobot_dcdp.policy.processor_state_history.StateHistoryProcessorStep"
_OUR_STEPS = {"dcdp_split_state", "dcdp_state_history", SPLIT_STEP_CLASS, HISTORY_STEP_CLASS}
#: What the stock server overrides in every pre-processor (``PolicyServer.SendPolicyInstructions``).
_SERVER_OVERRIDDEN = ("rename_observations_processor", "device_processor")
#: Written beside the weights: what was changed, for the client and for people.
MANIFEST = "dcdp_served_base.json"


def served_steps(config) -> list[dict[str, Any]]:
    """The processor entries the served copy puts in front of the base's pre-processor.

    Args:
        config: The base's ``PreTrainedConfig``.

    Returns:
        ``dcdp_state_history`` (when ``n_obs_steps > 1``) and ``dcdp_split_state`` (when the base reads
        ``observation.state`` and another 1-D vector input), as ``"class"`` entries.

    Raises:
        ValueError: The base reads several frames and cameras (the stock server sends one image per camera).
    """
    from lerobot_dcdp.policy.processor_split_state import VECTOR_FEATURE_TYPES, SplitStateProcessorStep

    feats = dict(config.input_features or {})
    n_obs = int(getattr(config, "n_obs_steps", 1) or 1)
    steps: list[dict[str, Any]] = []
    if n_obs > 1:
        if config.image_features:
            raise ValueError(
                f"base type {config.type!r} reads n_obs_steps={n_obs} frames and cameras "
                f"{sorted(config.image_features)}: LeRobot's policy server passes one image per camera, so "
                "the image history cannot reach it; serve a base with n_obs_steps=1"
            )
        width = sum(
            int(ft.shape[0])
            for ft in feats.values()
            if ft.type in VECTOR_FEATURE_TYPES and len(ft.shape) == 1
        )
        steps.append({"class": HISTORY_STEP_CLASS, "config": {"n_obs_steps": n_obs, "width": width}})
    split = SplitStateProcessorStep.from_features(feats)
    if split is not None:
        steps.append({"class": SPLIT_STEP_CLASS, "config": split.get_config()})
    return steps


def make_server_base(base: str | Path, out: str | Path) -> Path:
    """Write the served copy of ``base`` to ``out`` (replaced atomically if it exists).

    Args:
        base: A local ``pretrained_model`` folder of a base LeRobot's server supports (``act``,
            ``diffusion``, ...).
        out: Destination folder; pass this path (as the server's machine sees it) to the robot client.

    Returns:
        ``out``.

    Raises:
        ValueError: ``base`` is no local policy folder, its type is not served by LeRobot's server, or its
            pre-processor lacks a step the server overrides.
    """
    import lerobot.policies  # noqa: F401  (registers every policy config type)
    from lerobot.async_inference.constants import SUPPORTED_POLICIES
    from lerobot.configs.policies import PreTrainedConfig

    src = Path(base)
    if not (src / "config.json").is_file():
        raise ValueError(f"--base {base}: no config.json there (a local pretrained_model folder is needed)")
    config = PreTrainedConfig.from_pretrained(str(src))
    if config.type not in SUPPORTED_POLICIES:
        raise ValueError(
            f"base type {config.type!r} is not served by LeRobot's policy server (it serves "
            f"{SUPPORTED_POLICIES})"
        )
    pre = json.loads((src / "policy_preprocessor.json").read_text())
    names = [s.get("registry_name") or s.get("class", "").rsplit(".", 1)[-1] for s in pre["steps"]]
    missing = [n for n in _SERVER_OVERRIDDEN if n not in names]
    if missing:
        raise ValueError(f"{src}/policy_preprocessor.json lacks {missing}, which LeRobot's server overrides")
    ours = served_steps(config)
    kept = [s for s in pre["steps"] if (s.get("registry_name") or s.get("class")) not in _OUR_STEPS]
    pre["steps"] = ours + kept
    cfg_json = json.loads((src / "config.json").read_text())
    changed: dict[str, Any] = {}
    if all(isinstance(cfg_json.get(k), int) for k in ("horizon", "n_obs_steps", "n_action_steps")):
        longest = cfg_json["horizon"] - cfg_json["n_obs_steps"] + 1
        if cfg_json["n_action_steps"] != longest:
            changed["n_action_steps"] = [cfg_json["n_action_steps"], longest]
            cfg_json["n_action_steps"] = longest
    manifest = {
        "base": str(src.resolve()),
        "policy_type": config.type,
        "n_obs_steps": int(getattr(config, "n_obs_steps", 1) or 1),
        "pre_processor_steps_added": ours,
        "config_changed": changed,
    }
    with staged_dir(out) as built:
        shutil.copytree(src, built)
        (built / "policy_preprocessor.json").write_text(json.dumps(pre, indent=4) + "\n")
        (built / "config.json").write_text(json.dumps(cfg_json, indent=4) + "\n")
        (built / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return Path(out)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-serve-base", description=__doc__.splitlines()[0])
    p.add_argument("--base", required=True, help="the base's local pretrained_model folder")
    p.add_argument("--out", required=True, help="where to write the served copy (replaced if it exists)")
    a = p.parse_args(argv)
    try:
        out = make_server_base(a.base, a.out)
    except ValueError as err:
        p.error(str(err))
    print(f"served copy of {a.base} written to {out}; on that machine run:")
    print("  python -m lerobot.async_inference.policy_server --host=0.0.0.0 --port=8080")
    print(f"and point dcdp-robot-client at it with --base_path={Path(out).resolve()}")


if __name__ == "__main__":
    main()
