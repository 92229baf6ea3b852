"""Pure correction math and PushT geometry: no simulator, no policy."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_dcdp.model.correction import (
    from_unit_range,
    sliding_windows,
    state_dict_sha256,
    temporal_ensemble_step,
    to_unit_range,
)
from lerobot_dcdp.sim.pusht_geometry import GOAL_POSE, clip_offset, densify, keypoint_error, keypoints


def test_unit_range_round_trip_and_bounds() -> None:
    low, high = torch.tensor([-2.0, 0.0]), torch.tensor([2.0, 10.0])
    a = torch.tensor([[-2.0, 0.0], [2.0, 10.0], [0.0, 5.0]])
    u = to_unit_range(a, low, high)
    assert torch.equal(u, torch.tensor([[-1.0, -1.0], [1.0, 1.0], [0.0, 0.0]]))
    torch.testing.assert_close(from_unit_range(u, low, high), a)


def test_temporal_ensemble_matches_hand_computation() -> None:
    c1 = torch.tensor([[[1.0], [2.0], [3.0]]])
    c2 = torch.tensor([[[10.0], [20.0], [30.0]]])
    p1 = temporal_ensemble_step(None, c1, 0.5)
    assert torch.equal(p1, c1)
    p2 = temporal_ensemble_step(p1, c2, 0.5)
    # step t+1 overlaps: new 10 with old 2, new 20 with old 3, new 30 has no previous estimate
    assert torch.equal(p2, torch.tensor([[[6.0], [11.5], [30.0]]]))
    p3 = temporal_ensemble_step(p2, c2, 0.25)
    assert torch.equal(p3[0, :, 0], torch.tensor([0.25 * 10 + 0.75 * 11.5, 0.25 * 20 + 0.75 * 30, 30.0]))


def test_sliding_windows_end_at_each_step() -> None:
    x = torch.arange(2 * 6 * 3, dtype=torch.float32).reshape(2, 6, 3)
    w = sliding_windows(x, 4)
    assert w.shape == (2, 3, 4, 3)
    for s in range(3):
        assert torch.equal(w[:, s], x[:, s : s + 4])


def test_state_dict_hash_sees_every_byte() -> None:
    sd = {"a": torch.zeros(3), "b": torch.ones(2, 2), "n": torch.tensor(5)}
    h = state_dict_sha256(sd)
    assert h == state_dict_sha256({k: v.clone() for k, v in reversed(list(sd.items()))})
    sd2 = {k: v.clone() for k, v in sd.items()}
    sd2["b"][1, 1] = 1.0000001
    assert state_dict_sha256(sd2) != h
    assert state_dict_sha256({**sd, "a": torch.zeros(3, dtype=torch.float64)}) != h


def test_densify_caps_the_step_and_hits_waypoints() -> None:
    out = densify(np.zeros(2), [np.array([30.0, 40.0]), np.array([30.0, 41.0])], max_step=20.0)
    steps = np.linalg.norm(np.diff(np.vstack([np.zeros(2), *out]), axis=0), axis=1)
    assert steps.max() <= 20.0 + 1e-9
    assert np.allclose(out[2], [30, 40]) and np.allclose(out[-1], [30, 41]) and len(out) == 4


def test_clip_offset_keeps_the_t_inside() -> None:
    verts = keypoints(np.array([256.0, 256.0, 0.0]))
    off, hit = clip_offset(verts, np.array([1.0, -1.0]))
    assert np.allclose(off, [1, -1]) and not hit.any()
    near_wall = keypoints(np.array([501.0 - 60.0, 256.0, 0.0]))  # right end of the bar at x = 501
    off, hit = clip_offset(near_wall, np.array([3.0, 2.0]), lo=9.0, hi=502.0)
    assert off[0] == pytest.approx(1.0) and off[1] == 2.0 and hit.tolist() == [True, False]


def test_goal_keypoint_error_is_zero() -> None:
    assert keypoint_error(GOAL_POSE) == 0.0
    assert keypoint_error(GOAL_POSE + np.array([3.0, 4.0, 0.0])) == pytest.approx(5.0)
