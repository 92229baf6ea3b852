"""`pusht_perturbed` with obs_type=pixels_environment_state_agent_pos: frame, agent and keypoints together."""

import numpy as np
import pytest

from lerobot_dcdp.sim.envs.pusht_perturbed import (
    PIXELS_KEYPOINTS,
    PushTPerturbedEnvConfig,
    make_perturbed_env,
)


def _rollout(obs_type: str, steps: int = 5) -> list[dict]:
    env = make_perturbed_env("constant", 2.0, 30.0, obs_type=obs_type)
    obs, _ = env.reset(seed=100_000)
    out = [obs]
    for i in range(steps):
        obs, *_ = env.step(np.array([200.0 + 10 * i, 300.0]))
        out.append(obs)
    env.close()
    return out


def test_each_part_equals_the_stock_observation_type_on_the_same_episode():
    """The frame equals `pixels_agent_pos`'s, the keypoints `environment_state_agent_pos`'s, step by step
    under the same drift, so the block in the frame and in the keypoints is the same (perturbed) block."""
    both = _rollout(PIXELS_KEYPOINTS)
    pixels = _rollout("pixels_agent_pos")
    keypoints = _rollout("environment_state_agent_pos")
    for b, p, k in zip(both, pixels, keypoints, strict=True):
        assert set(b) == {"pixels", "agent_pos", "environment_state"}
        assert b["pixels"].shape == (96, 96, 3) and b["pixels"].dtype == np.uint8
        np.testing.assert_array_equal(b["pixels"], p["pixels"])
        np.testing.assert_allclose(b["environment_state"], k["environment_state"])
        np.testing.assert_allclose(b["agent_pos"], k["agent_pos"])
    moved = both[-1]["environment_state"] - both[0]["environment_state"]
    assert np.abs(moved).max() > 1.0  # the drift shows in the keypoints


def test_config_declares_image_state_and_keypoints_and_lerobot_maps_them():
    from lerobot.envs.utils import preprocess_observation

    cfg = PushTPerturbedEnvConfig(obs_type=PIXELS_KEYPOINTS, perturbation="random", magnitude=1.0)
    assert {"pixels", "environment_state", "agent_pos"} <= set(cfg.features)
    vec = cfg.create_envs(2)[cfg.type][0]
    obs, _ = vec.reset(seed=[1, 2])
    batch = preprocess_observation(obs)
    vec.close()
    assert batch["observation.image"].shape == (2, 3, 96, 96)
    assert batch["observation.environment_state"].shape == (2, 16)
    assert batch["observation.state"].shape == (2, 2)


def test_unknown_obs_type_is_refused_by_name():
    with pytest.raises(ValueError, match="obs_type must be one of"):
        PushTPerturbedEnvConfig(obs_type="pixels_keypoints")
