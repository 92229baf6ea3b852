"""Reading FastUMI episode files with h5py: opening them, fetching a dataset, reading the pose arrays and
reading image frames in blocks of one HDF5 chunk; every failure becomes a :class:`FastUMIFormatError`."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

try:
    import h5py
except ImportError as err:  # an optional dependency
    raise ImportError("the FastUMI tools need h5py: pip install 'lerobot_policy_dcdp[fastumi]'") from err
import numpy as np

from lerobot_dcdp.data.fastumi.spec import FastUMIFormatError


def open_episode(path: str | Path) -> h5py.File:
    """Open an episode file read-only, turning every failure into a :class:`FastUMIFormatError`.

    Args:
        path: HDF5 file.

    Returns:
        The open file (caller closes it).
    """
    path = Path(path)
    try:
        if not h5py.is_hdf5(path):
            raise FastUMIFormatError(path, None, "not an HDF5 file")
        return h5py.File(path, "r")
    except FastUMIFormatError:
        raise
    except (OSError, ValueError) as exc:
        raise FastUMIFormatError(path, None, f"cannot open HDF5 file (truncated or corrupt?): {exc}") from exc


def get_dataset(f: h5py.File, key: str, path: Path) -> h5py.Dataset:
    """The dataset at ``key``.

    Raises:
        FastUMIFormatError: The key is missing or is a group.
    """
    obj = f.get(key)
    if obj is None:
        raise FastUMIFormatError(path, key, "missing key")
    if not isinstance(obj, h5py.Dataset):
        raise FastUMIFormatError(path, key, "expected a dataset, found a group")
    return obj


def read_pose_array(f: h5py.File, key: str, path: Path, pose_dim: int) -> np.ndarray:
    """The first ``pose_dim`` columns of the ``(T, 7)`` or ``(T, 8)`` pose dataset at ``key``.

    Args:
        f: Open episode file.
        key: The dataset's key (qpos or action).
        path: The file's path (for error messages).
        pose_dim: Columns to read: 7 (pose) or 8 (pose + gripper).

    Returns:
        ``(T, pose_dim)`` float32.

    Raises:
        FastUMIFormatError: Wrong shape (or too few columns for ``pose_dim``), not numbers, or unreadable.
    """
    ds = get_dataset(f, key, path)
    if ds.ndim != 2 or ds.shape[1] not in (7, 8):
        raise FastUMIFormatError(path, key, f"expected shape (T, 7) or (T, 8), got {ds.shape}")
    if ds.shape[1] < pose_dim:
        raise FastUMIFormatError(
            path, key, f"layout fastumi_pro needs (T, 8) pose + gripper, got {ds.shape}; use --layout fastumi"
        )
    if not np.issubdtype(ds.dtype, np.number):
        raise FastUMIFormatError(path, key, f"expected numbers, got dtype {ds.dtype}")
    try:
        arr = ds[:, :pose_dim]
    except (OSError, RuntimeError, ValueError) as exc:
        raise FastUMIFormatError(path, key, f"cannot read data (truncated or corrupt?): {exc}") from exc
    return arr.astype(np.float32, copy=False)


def read_block(
    ds: h5py.Dataset, start: int, stop: int, path: Path, key: str, out: np.ndarray | None = None
) -> np.ndarray:
    """Frames ``start`` to ``stop - 1`` of an image dataset.

    Args:
        ds: The ``(T, H, W, 3)`` dataset.
        start: First frame.
        stop: One past the last frame.
        path: The file's path (for error messages).
        key: The dataset's key (for error messages).
        out: A buffer of at least ``stop - start`` frames to read into, or ``None`` for a new array.

    Returns:
        The frames (``out`` itself when given, whole).

    Raises:
        FastUMIFormatError: The block cannot be read (e.g. a corrupt chunk).
    """
    try:
        if out is None:
            return ds[start:stop]
        ds.read_direct(out, np.s_[start:stop], np.s_[0 : stop - start])
        return out
    except (OSError, RuntimeError, ValueError) as exc:
        raise FastUMIFormatError(
            path, key, f"cannot read frames {start}..{stop - 1} (truncated or corrupt?): {exc}"
        ) from exc


def iter_camera(ds: h5py.Dataset, path: Path, key: str) -> Iterator[np.ndarray]:
    """Every frame of an image dataset, in order, read one HDF5 chunk along ``T`` at a time (one frame for a
    contiguous dataset) into a reused buffer: each yielded frame is a view that the next block overwrites."""
    num = ds.shape[0]
    step = int(ds.chunks[0]) if ds.chunks else 1
    buf = np.empty((min(step, num), *ds.shape[1:]), dtype=ds.dtype)
    for start in range(0, num, step):
        stop = min(start + step, num)
        read_block(ds, start, stop, path, key, out=buf)
        yield from buf[: stop - start]
