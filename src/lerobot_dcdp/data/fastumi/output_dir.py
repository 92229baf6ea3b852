"""The converter's output directory: which existing ``--root`` may be replaced, the hidden temporary
directory the dataset is built in, and cleaning up after a failed or interrupted run."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

#: marks the temporary directory ``.<root name><TMP_MARK><random>`` the dataset is built in, beside ``root``
TMP_MARK = ".fastumi-tmp-"


def check_output(out: Path, force: bool) -> None:
    """Check that a dataset may be written at ``out``: it does not exist, or (with ``force``) it is a
    directory that is empty or holds a LeRobot dataset.

    Raises:
        FileExistsError: ``out`` exists without ``force``, is not a directory, or is a non-empty directory
            without ``meta/info.json``.
    """
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


def missing_parents(out: Path) -> list[Path]:
    """Ancestors of ``out`` that do not exist yet, deepest first (removed again on failure)."""
    missing = []
    for parent in out.parents:
        if parent.exists():
            break
        missing.append(parent)
    return missing


def remove_empty(parents: list[Path]) -> None:
    """Remove each of ``parents`` (deepest first) that is an empty directory; leave the others."""
    for parent in parents:
        with contextlib.suppress(OSError):
            parent.rmdir()


def abandon(dataset: Any) -> None:
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
