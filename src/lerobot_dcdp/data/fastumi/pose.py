"""Pose math for FastUMI actions: products, conjugates and rotations of scalar-last (``xyzw``) quaternions,
a pose expressed in another pose's frame and back, and absolute actions turned into relative ones."""

from __future__ import annotations

import numpy as np


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
    """``q`` scaled to unit norm along its last axis."""
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
    """Turn absolute actions into UMI-style relative actions (see ``features.RELATIVE_DESCRIPTION``).

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
