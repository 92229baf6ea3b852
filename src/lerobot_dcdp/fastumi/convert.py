"""``dcdp-fastumi-to-lerobot``: convert FastUMI / FastUMI Pro HDF5 episodes into a LeRobotDataset v3.

Every input file is validated before anything is written. The dataset is built in a hidden temporary
directory next to ``--root`` and renamed into place only once complete, so a failed or interrupted run
leaves nothing behind. See ``docs/FASTUMI.md`` for the formats, flags and action representations.

Example::

    dcdp-fastumi-to-lerobot --input /data/fastumi --repo-id local/fastumi_cups --root /data/lerobot/cups
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_dcdp.atomic_dataset import replace_dir
from lerobot_dcdp.fastumi.reader import (
    LAYOUTS,
    POSE_NAMES,
    EpisodeSpec,
    FastUMIFormatError,
    inspect_dataset,
    iter_frames,
    read_vectors,
    resolve_fps,
)

logger = logging.getLogger(__name__)

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
_TMP_MARK = ".fastumi-tmp-"
# yuv420p needs even sides; LeRobot's default encoder (SVT-AV1) kills the process (SIGFPE) below ~32 px.
MIN_IMAGE_SIZE = 32


# --------------------------------------------------------------------------------------------- pose math


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-last (``xyzw``) quaternions, broadcasting over leading dims.

    Args:
        a: ``(..., 4)`` quaternions.
        b: ``(..., 4)`` quaternions.

    Returns:
        ``a * b`` as ``(..., 4)``.
    """
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse for unit quaternions) of ``xyzw`` quaternions."""
    return q * np.array([-1.0, -1.0, -1.0, 1.0], dtype=q.dtype)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (``(..., 3)``) by unit ``xyzw`` quaternions ``q`` (``(..., 4)``)."""
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def relative_pose(cur: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """Express poses ``nxt`` in the frames of poses ``cur`` (both ``(..., 7)`` = xyz + xyzw).

    Args:
        cur: Reference poses.
        nxt: Target poses.

    Returns:
        ``(..., 7)`` relative poses ``[d_pos (in cur's frame), d_quat (unit, dqw >= 0)]``.
    """
    cur = cur.astype(np.float64)
    nxt = nxt.astype(np.float64)
    qc, qn = _normalize(cur[..., 3:7]), _normalize(nxt[..., 3:7])
    inv = quat_conj(qc)
    d_pos = quat_rotate(inv, nxt[..., :3] - cur[..., :3])
    d_quat = _normalize(quat_mul(inv, qn))
    d_quat = np.where(d_quat[..., 3:4] < 0, -d_quat, d_quat)
    return np.concatenate([d_pos, d_quat], axis=-1)


def compose_pose(cur: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """Inverse of :func:`relative_pose`: absolute poses from reference poses and relative poses.

    Args:
        cur: ``(..., 7)`` reference poses.
        rel: ``(..., 7)`` relative poses.

    Returns:
        ``(..., 7)`` absolute poses.
    """
    cur = cur.astype(np.float64)
    rel = rel.astype(np.float64)
    qc = _normalize(cur[..., 3:7])
    pos = cur[..., :3] + quat_rotate(qc, rel[..., :3])
    quat = _normalize(quat_mul(qc, rel[..., 3:7]))
    return np.concatenate([pos, quat], axis=-1)


def to_relative_actions(state: np.ndarray, action: np.ndarray, n_arms: int, pose_dim: int) -> np.ndarray:
    """Turn absolute actions into UMI-style relative actions (see ``RELATIVE_DESCRIPTION``).

    Args:
        state: ``(T, n_arms * pose_dim)`` absolute observed poses.
        action: ``(T, n_arms * pose_dim)`` absolute action poses.
        n_arms: Number of arms (blocks of ``pose_dim`` columns).
        pose_dim: 7 (pose) or 8 (pose + gripper).

    Returns:
        ``(T, n_arms * pose_dim)`` float32 relative actions.
    """
    num = state.shape[0]
    out = np.zeros((num, n_arms * pose_dim), dtype=np.float64)
    for arm in range(n_arms):
        c = arm * pose_dim
        out[:, c + 6] = 1.0  # identity rotation (kept by the last frame)
        if num > 1:
            out[:-1, c : c + 7] = relative_pose(state[:-1, c : c + 7], action[1:, c : c + 7])
        if pose_dim == 8:
            out[:-1, c + 7] = action[1:, c + 7]
            out[-1, c + 7] = action[-1, c + 7]
    return out.astype(np.float32)


# ----------------------------------------------------------------------------------------------- features


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


# ---------------------------------------------------------------------------------------------- conversion


def convert_fastumi(
    input_dir: str | Path,
    repo_id: str,
    root: str | Path,
    fps: int | None = None,
    image_size: int = 224,
    task: str | None = None,
    action: str = "absolute",
    force: bool = False,
    layout: str = "auto",
) -> dict[str, Any]:
    """Convert a folder of FastUMI episodes into a LeRobotDataset v3 at ``root``.

    Args:
        input_dir: ``<input_dir>/<task>/episode_<idx>.hdf5`` and/or ``<input_dir>/episode_<idx>.hdf5``.
        repo_id: Dataset id, e.g. ``local/fastumi_cups`` (nothing is pushed anywhere).
        root: Output dataset directory (must not exist unless ``force``).
        fps: Frame rate override; default: the files' ``fps`` attribute, else 20.
        image_size: Side of the stored square RGB frames.
        task: Task string for all episodes; default: each episode's task folder name.
        action: ``"absolute"`` (file actions as they are) or ``"delta"`` (relative to the current pose).
        force: Replace an existing dataset at ``root``.
        layout: ``"auto"``, ``"fastumi"`` or ``"fastumi_pro"``.

    Returns:
        Summary: ``root``, ``repo_id``, ``episodes``, ``frames``, ``fps``, ``layout``, ``robot_type``,
        ``cameras``, ``action``, ``image_size``, ``tasks``, ``seconds``.

    Raises:
        FastUMIFormatError: Bad input (nothing is written).
        FileExistsError: ``root`` exists and ``force`` is false, it is not a dataset that may be replaced,
            or it contains the input.
        ValueError: Bad arguments.
    """
    started = time.perf_counter()
    if action not in ACTION_MODES:
        raise ValueError(f"action must be one of {ACTION_MODES}, got {action!r}")
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if image_size < MIN_IMAGE_SIZE or image_size % 2:
        raise ValueError(
            f"image_size must be even and >= {MIN_IMAGE_SIZE} (video encoding), got {image_size}"
        )
    if fps is not None and fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")

    input_path = Path(input_dir).absolute()
    out = Path(root).absolute()
    if input_path == out or out in input_path.parents:
        raise FileExistsError(f"refusing to write {out}: it would contain/replace the input {input_path}")
    _check_output(out, force)

    specs = inspect_dataset(input_path, layout=layout, task=task)
    dataset_fps = resolve_fps(specs, fps)
    ref = specs[0]
    features = build_features(ref, image_size, action)
    logger.info(
        "Validated %d episode(s), %d frames, layout %s, cameras %s, %d fps",
        len(specs),
        sum(s.num_frames for s in specs),
        robot_type(ref),
        [c.name for c in ref.cameras],
        dataset_fps,
    )

    created_parents = _missing_parents(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}{_TMP_MARK}", dir=out.parent))
    dataset = None
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        dataset = LeRobotDataset.create(
            repo_id=repo_id,
            fps=dataset_fps,
            features=features,
            root=tmp / "dataset",
            robot_type=robot_type(ref),
            use_videos=True,
        )
        state_key = "observation.state"
        for ep_idx, spec in enumerate(specs):
            t0 = time.perf_counter()
            state, act = read_vectors(spec)
            if action == "delta":
                act = to_relative_actions(state, act, len(spec.arms), spec.pose_dim)
            for t, images in enumerate(iter_frames(spec, image_size)):
                frame: dict[str, Any] = {f"observation.images.{k}": v for k, v in images.items()}
                frame[state_key] = state[t]
                frame["action"] = act[t]
                frame["task"] = spec.task
                dataset.add_frame(frame)
            dataset.save_episode()
            logger.info(
                "episode %d/%d %s: %d frames in %.1fs",
                ep_idx + 1,
                len(specs),
                spec.path.name,
                spec.num_frames,
                time.perf_counter() - t0,
            )
        dataset.finalize()
        staging = tmp / "dataset" / "images"
        if staging.exists():
            shutil.rmtree(staging)
        replace_dir(tmp / "dataset", out, tmp)
    except BaseException:
        if dataset is not None:
            _abandon(dataset)
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if not out.exists():
            for parent in created_parents:
                with contextlib.suppress(OSError):
                    parent.rmdir()

    return {
        "root": str(out),
        "repo_id": repo_id,
        "episodes": len(specs),
        "frames": sum(s.num_frames for s in specs),
        "fps": dataset_fps,
        "layout": ref.layout,
        "robot_type": robot_type(ref),
        "cameras": [f"observation.images.{c.name}" for c in ref.cameras],
        "action": action,
        "image_size": image_size,
        "tasks": sorted({s.task for s in specs}),
        "seconds": round(time.perf_counter() - started, 3),
    }


def _check_output(out: Path, force: bool) -> None:
    if not (out.exists() or out.is_symlink()):
        return
    if not force:
        raise FileExistsError(f"{out} already exists; pass --force to replace it")
    if out.is_symlink() or not out.is_dir():
        raise FileExistsError(f"refusing to replace {out}: not a directory")
    if any(out.iterdir()) and not (out / "meta" / "info.json").is_file():
        raise FileExistsError(
            f"refusing to replace {out}: not empty and not a LeRobot dataset (no meta/info.json)"
        )


def _missing_parents(out: Path) -> list[Path]:
    """Ancestors of ``out`` that do not exist yet, deepest first (removed again on failure)."""
    missing = []
    for parent in out.parents:
        if parent.exists():
            break
        missing.append(parent)
    return missing


def _abandon(dataset: Any) -> None:
    """Stop a half-written dataset's writers so nothing recreates files after the temp dir is removed."""
    with contextlib.suppress(Exception):
        dataset.clear_episode_buffer()
    with contextlib.suppress(Exception):
        dataset.finalize()
    # GC safety nets (``__del__``) of the writer and the metadata would otherwise flush into the deleted dir.
    for obj in (getattr(dataset, "writer", None), getattr(dataset, "meta", None)):
        if obj is not None:
            with contextlib.suppress(Exception):
                obj._finalized = True
    with contextlib.suppress(Exception):
        dataset._is_finalized = True


# ---------------------------------------------------------------------------------------------------- CLI


def _positive_int(text: str) -> int:
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _image_size(text: str) -> int:
    value = int(text)
    if value < MIN_IMAGE_SIZE or value % 2:
        raise argparse.ArgumentTypeError(f"must be even and >= {MIN_IMAGE_SIZE} (video encoding), got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of ``dcdp-fastumi-to-lerobot``."""
    p = argparse.ArgumentParser(
        prog="dcdp-fastumi-to-lerobot",
        description="Convert FastUMI / FastUMI Pro HDF5 episodes into a LeRobotDataset v3.",
    )
    p.add_argument("--input", required=True, help="folder of <task>/episode_<idx>.hdf5 or episode_<idx>.hdf5")
    p.add_argument("--repo-id", required=True, help="dataset id, e.g. local/fastumi_cups (not pushed)")
    p.add_argument("--root", required=True, help="output dataset directory")
    p.add_argument(
        "--fps", type=_positive_int, default=None, help="override the frame rate (default: file, else 20)"
    )
    p.add_argument("--image-size", type=_image_size, default=224, help="side of the square RGB frames (224)")
    p.add_argument("--task", default=None, help="task string for all episodes (default: task folder name)")
    p.add_argument("--action", choices=ACTION_MODES, default="absolute", help="action representation")
    p.add_argument("--layout", choices=LAYOUTS, default="auto", help="input layout (default: detect)")
    p.add_argument("--force", action="store_true", help="replace an existing dataset at --root")
    return p


def _raise_interrupt(signum: int, _frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def main(argv: list[str] | None = None) -> int:
    """CLI entry point. Returns 0 on success; bad input prints one ``error:`` line and exits with 2.

    Args:
        argv: Arguments (default: ``sys.argv[1:]``).

    Returns:
        Process exit status.
    """
    args = build_parser().parse_args(argv)
    os.environ.setdefault("SVT_LOG", "1")  # keep SVT-AV1's banner out of the output (errors only)
    if not logger.handlers:  # progress lines on stderr, independent of whatever configured the root logger
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False
    with contextlib.suppress(ValueError):  # not in the main thread: keep the default handler
        signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        summary = convert_fastumi(
            args.input,
            args.repo_id,
            args.root,
            fps=args.fps,
            image_size=args.image_size,
            task=args.task,
            action=args.action,
            force=args.force,
            layout=args.layout,
        )
    except (FastUMIFormatError, FileExistsError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted; no dataset was written", file=sys.stderr)
        return 130
    print(
        f"Wrote {summary['episodes']} episode(s), {summary['frames']} frames at {summary['fps']} fps "
        f"({summary['robot_type']}, action={summary['action']}) to {summary['root']} "
        f"in {summary['seconds']:.1f}s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
