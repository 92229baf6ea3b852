"""``dcdp-fastumi-to-lerobot``: convert FastUMI / FastUMI Pro HDF5 episodes into a LeRobotDataset v3.

Every input file is validated before anything is written. The dataset is built in a hidden temporary
directory next to ``--root`` and renamed into place only once complete, so a failed or interrupted run
leaves nothing behind. See ``docs/FASTUMI.md`` for the formats, flags and action representations.

Example::

    dcdp-fastumi-to-lerobot --input /data/fastumi --repo-id local/fastumi_cups --root /data/lerobot/cups

The conversion and the command live here; their parts beside it: ``arguments`` (the parser), ``features``
(the dataset's features and action representations), ``pose`` (the pose math of relative actions),
``output_dir`` (the output directory's checks and cleanup) and ``reader`` (finding, validating and
streaming the episodes).
"""

from __future__ import annotations

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

from lerobot_dcdp.data.atomic_dataset import replace_dir
from lerobot_dcdp.data.fastumi.arguments import build_parser
from lerobot_dcdp.data.fastumi.features import (
    ABSOLUTE_REPRESENTATION,
    ACTION_MODES,
    DELTA_NAMES,
    MIN_IMAGE_SIZE,
    QUATERNION_ORDER,
    RELATIVE_DESCRIPTION,
    RELATIVE_REPRESENTATION,
    build_features,
    robot_type,
)
from lerobot_dcdp.data.fastumi.output_dir import (
    TMP_MARK,
    abandon,
    check_output,
    missing_parents,
    remove_empty,
)
from lerobot_dcdp.data.fastumi.pose import (
    compose_pose,
    quat_conj,
    quat_mul,
    quat_rotate,
    relative_pose,
    to_relative_actions,
)
from lerobot_dcdp.data.fastumi.reader import (
    LAYOUTS,
    EpisodeSpec,
    FastUMIFormatError,
    inspect_dataset,
    iter_frames,
    read_vectors,
    resolve_fps,
)

logger = logging.getLogger(__name__)

# the names callers import from this module (``main`` is the console script)
__all__ = [
    "ABSOLUTE_REPRESENTATION",
    "ACTION_MODES",
    "DELTA_NAMES",
    "MIN_IMAGE_SIZE",
    "QUATERNION_ORDER",
    "RELATIVE_DESCRIPTION",
    "RELATIVE_REPRESENTATION",
    "build_features",
    "build_parser",
    "compose_pose",
    "convert_fastumi",
    "main",
    "quat_conj",
    "quat_mul",
    "quat_rotate",
    "relative_pose",
    "robot_type",
    "to_relative_actions",
]


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
    _check_arguments(action, layout, image_size, fps)
    input_path = Path(input_dir).absolute()
    out = Path(root).absolute()
    if input_path == out or out in input_path.parents:
        raise FileExistsError(f"refusing to write {out}: it would contain/replace the input {input_path}")
    check_output(out, force)

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
    _write_dataset(out, repo_id, dataset_fps, features, specs, image_size, action)
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


def _check_arguments(action: str, layout: str, image_size: int, fps: int | None) -> None:
    """Check :func:`convert_fastumi`'s options.

    Raises:
        ValueError: An unknown action or layout, an odd or too small image size, or a non-positive fps.
    """
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


def _write_dataset(
    out: Path,
    repo_id: str,
    fps: int,
    features: dict[str, dict],
    specs: list[EpisodeSpec],
    image_size: int,
    action: str,
) -> None:
    """Build the dataset in a hidden temporary directory beside ``out`` and rename it into place.

    On any failure (an interrupt included) the half-written dataset is abandoned and the temporary
    directory and the parents of ``out`` this call created are removed before the error propagates.

    Args:
        out: The dataset directory (absolute; replaced when it exists).
        repo_id: Dataset id.
        fps: Frames per second.
        features: The features (:func:`build_features`).
        specs: The validated episodes, in order.
        image_size: Side of the stored square frames.
        action: ``"absolute"`` or ``"delta"``.
    """
    created_parents = missing_parents(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}{TMP_MARK}", dir=out.parent))
    dataset = None
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        dataset = LeRobotDataset.create(
            repo_id=repo_id,
            fps=fps,
            features=features,
            root=tmp / "dataset",
            robot_type=robot_type(specs[0]),
            use_videos=True,
        )
        for ep_idx, spec in enumerate(specs):
            _write_episode(dataset, spec, image_size, action, f"{ep_idx + 1}/{len(specs)}")
        dataset.finalize()
        staging = tmp / "dataset" / "images"
        if staging.exists():
            shutil.rmtree(staging)
        replace_dir(tmp / "dataset", out, tmp)
    except BaseException:
        if dataset is not None:
            abandon(dataset)
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if not out.exists():
            remove_empty(created_parents)


def _write_episode(dataset: Any, spec: EpisodeSpec, image_size: int, action: str, progress: str) -> None:
    """Add one episode's frames to ``dataset`` and save the episode (frames streamed by :func:`iter_frames`).

    Args:
        dataset: The ``LeRobotDataset`` being written.
        spec: The validated episode.
        image_size: Side of the stored square frames.
        action: ``"absolute"`` or ``"delta"`` (converted with :func:`to_relative_actions`).
        progress: ``<episode>/<episodes>`` for the progress line.
    """
    t0 = time.perf_counter()
    state, act = read_vectors(spec)
    if action == "delta":
        act = to_relative_actions(state, act, len(spec.arms), spec.pose_dim)
    for t, images in enumerate(iter_frames(spec, image_size)):
        frame: dict[str, Any] = {f"observation.images.{k}": v for k, v in images.items()}
        frame["observation.state"] = state[t]
        frame["action"] = act[t]
        frame["task"] = spec.task
        dataset.add_frame(frame)
    dataset.save_episode()
    logger.info(
        "episode %s %s: %d frames in %.1fs",
        progress,
        spec.path.name,
        spec.num_frames,
        time.perf_counter() - t0,
    )


def _raise_interrupt(signum: int, _frame: Any) -> None:
    """SIGTERM handler: raise ``KeyboardInterrupt`` so a conversion cleans up as on Ctrl-C."""
    raise KeyboardInterrupt(f"signal {signum}")


def _log_progress_to_stderr() -> None:
    """Print this module's progress lines (message only) on stderr, independent of whatever configured the
    root logger; a logger that already has a handler is left as it is."""
    if not logger.handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False


def main(argv: list[str] | None = None) -> int:
    """CLI entry point. Returns 0 on success; bad input prints one ``error:`` line and exits with 2.

    Args:
        argv: Arguments (default: ``sys.argv[1:]``).

    Returns:
        Process exit status.
    """
    args = build_parser().parse_args(argv)
    os.environ.setdefault("SVT_LOG", "1")  # keep SVT-AV1's banner out of the output (errors only)
    _log_progress_to_stderr()
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
