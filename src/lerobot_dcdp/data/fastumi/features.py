"""The LeRobot features of a converted FastUMI dataset: the action representations (absolute, or relative
to the current pose), how they are named and described in ``meta/info.json``, the stored image size and the
``robot_type``."""

from __future__ import annotations

from typing import Any

from lerobot_dcdp.data.fastumi.spec import POSE_NAMES, EpisodeSpec

ACTION_MODES: tuple[str, ...] = ("absolute", "delta")
QUATERNION_ORDER = "xyzw"
DELTA_NAMES: tuple[str, ...] = ("dx", "dy", "dz", "dqx", "dqy", "dqz", "dqw")
ABSOLUTE_REPRESENTATION = "absolute_tcp_pose"
RELATIVE_REPRESENTATION = "relative_tcp_pose"
RELATIVE_DESCRIPTION = (
    "action[t] = pose of action[t+1] expressed in the TCP frame of observation.state[t]: "
    "d_pos = R(q_state[t])^T (p_action[t+1] - p_state[t]), d_quat = q_state[t]^-1 * q_action[t+1] "
    "(xyzw, unit, dqw >= 0); gripper (if any) is the absolute width of action[t+1]; the last frame holds "
    "zero translation, identity rotation and its own gripper width. Recover the absolute target with "
    "p = p_state + R(q_state) d_pos, q = q_state * d_quat."
)
# yuv420p needs even sides; LeRobot's default encoder (SVT-AV1) kills the process (SIGFPE) below ~32 px.
MIN_IMAGE_SIZE = 32


def build_features(spec: EpisodeSpec, image_size: int, action: str = "absolute") -> dict[str, dict]:
    """LeRobot feature spec for episodes shaped like ``spec``.

    The representation of ``observation.state`` and ``action`` is recorded in each feature's ``info``
    block of ``meta/info.json`` (``representation``, ``quaternion_order``, ``source`` and, for delta
    actions, a ``description``); delta action dimensions are also named ``dx, dy, dz, dqx, ...``.

    Args:
        spec: A validated episode.
        image_size: Side of the stored square frames.
        action: ``"absolute"`` or ``"delta"``.

    Returns:
        The features dict for ``LeRobotDataset.create``.
    """
    names = spec.vector_names
    n_dim = len(names)
    features: dict[str, dict] = {}
    for cam in spec.cameras:
        features[f"observation.images.{cam.name}"] = {
            "dtype": "video",
            "shape": (image_size, image_size, 3),
            "names": ["height", "width", "channels"],
        }
    prefix = "robot_<i>/" if spec.dual_arm else ""
    features["observation.state"] = {
        "dtype": "float32",
        "shape": (n_dim,),
        "names": names,
        "info": {
            "representation": ABSOLUTE_REPRESENTATION,
            "quaternion_order": QUATERNION_ORDER,
            "source": f"{prefix}observations/qpos",
        },
    }
    action_info: dict[str, Any] = {
        "representation": ABSOLUTE_REPRESENTATION,
        "quaternion_order": QUATERNION_ORDER,
        "source": f"{prefix}action",
    }
    action_names = names
    if action == "delta":
        action_info["representation"] = RELATIVE_REPRESENTATION
        action_info["description"] = RELATIVE_DESCRIPTION
        rename = dict(zip(POSE_NAMES, DELTA_NAMES, strict=True))
        action_names = []
        for n in names:
            arm, _, base = n.rpartition("_") if spec.dual_arm else ("", "", n)
            base = rename.get(base, base)
            action_names.append(f"{arm}_{base}" if arm else base)
    features["action"] = {"dtype": "float32", "shape": (n_dim,), "names": action_names, "info": action_info}
    return features


def robot_type(spec: EpisodeSpec) -> str:
    """``robot_type`` stored in ``info.json``: ``fastumi``, ``fastumi_pro`` or ``fastumi_pro_bimanual``."""
    return f"{spec.layout}_bimanual" if spec.dual_arm else spec.layout
