"""Geometry of gym-pusht's T block (pure functions, no simulator needed)."""

from __future__ import annotations

import math

import numpy as np

#: T outline corners in the block's body frame (see ``PushTEnv.add_tee``): bar [-60, 60] x [0, 30],
#: stem [-15, 15] x [30, 120].
LOCAL_KP = np.array(
    [[-60, 0], [60, 0], [60, 30], [-60, 30], [-15, 30], [15, 30], [15, 120], [-15, 120]], dtype=float
)
#: Rectangles (x0, x1, y0, y1) of the T in the body frame.
RECTS = [(-60.0, 60.0, 0.0, 30.0), (-15.0, 15.0, 30.0, 120.0)]
#: Centre of gravity set by ``add_tee``.
COG = np.array([0.0, 45.0])
#: Goal pose (x, y, theta) of gym-pusht.
GOAL_POSE = np.array([256.0, 256.0, math.pi / 4])
#: Inner faces of the arena walls (segments at 5 and 506, radius 2) with a small margin.
ARENA_LO, ARENA_HI = 9.0, 502.0


def rot(theta: float) -> np.ndarray:
    """2x2 rotation matrix."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def keypoints(pose: np.ndarray) -> np.ndarray:
    """World coordinates (8, 2) of the T corners for a block pose (x, y, theta)."""
    pose = np.asarray(pose, dtype=float)
    return LOCAL_KP @ rot(pose[2]).T + pose[:2]


GOAL_KP = keypoints(GOAL_POSE)


def keypoint_error(pose: np.ndarray) -> float:
    """Mean distance (px) between the block's corners and the goal's corners."""
    return float(np.linalg.norm(keypoints(pose) - GOAL_KP, axis=1).mean())


def distance_to_t(p_local: np.ndarray) -> float:
    """Distance from a point in the body frame to the T (0 inside)."""
    d = math.inf
    for x0, x1, y0, y1 in RECTS:
        dx = max(x0 - p_local[0], 0.0, p_local[0] - x1)
        dy = max(y0 - p_local[1], 0.0, p_local[1] - y1)
        d = min(d, math.hypot(dx, dy))
    return d


def block_vertices(position: tuple[float, float], angle: float) -> np.ndarray:
    """World coordinates of the T corners from a pymunk body's position and angle."""
    return keypoints(np.array([position[0], position[1], angle]))


def clip_offset(
    verts: np.ndarray, offset: np.ndarray, lo: float = ARENA_LO, hi: float = ARENA_HI
) -> tuple[np.ndarray, np.ndarray]:
    """Largest per-axis part of ``offset`` that keeps every vertex inside ``[lo, hi]``.

    An offset never pushes a vertex further out; a vertex already outside is not pulled in either.

    Returns:
        (clipped offset, boolean per axis: the requested offset was reduced on that axis).
    """
    off = np.array(offset, dtype=float)
    hit = np.zeros(2, dtype=bool)
    for ax in range(2):
        vmin, vmax = verts[:, ax].min(), verts[:, ax].max()
        new = off[ax]
        if new < 0 and vmin + new < lo:
            new = min(max(lo - vmin, new), 0.0)
        if new > 0 and vmax + new > hi:
            new = max(min(hi - vmax, new), 0.0)
        hit[ax] = not math.isclose(new, off[ax])
        off[ax] = new
    return off, hit


def densify(start: np.ndarray, waypoints: list[np.ndarray], max_step: float) -> list[np.ndarray]:
    """Targets visiting ``waypoints`` in order with at most ``max_step`` px between consecutive targets.

    ``start`` is the previous target (not returned). Each waypoint is reached exactly.
    """
    out: list[np.ndarray] = []
    prev = np.asarray(start, dtype=float)
    for w in waypoints:
        w = np.asarray(w, dtype=float)
        n = max(int(math.ceil(np.linalg.norm(w - prev) / max_step - 1e-9)), 1)
        for i in range(1, n + 1):
            out.append(prev + (w - prev) * (i / n))
        prev = w
    return out


#: Edges of the T outline (start, end, outward normal) usable as push contacts (body frame).
EDGES_T = [
    ((-60, 0), (60, 0), (0, -1)),
    ((60, 0), (60, 30), (1, 0)),
    ((60, 30), (30, 30), (0, 1)),
    ((15, 45), (15, 120), (1, 0)),
    ((15, 120), (-15, 120), (0, 1)),
    ((-15, 120), (-15, 45), (-1, 0)),
    ((-30, 30), (-60, 30), (0, 1)),
    ((-60, 30), (-60, 0), (-1, 0)),
]
