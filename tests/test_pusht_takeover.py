"""Takeover recording (DAgger-style data): a policy drives first, the expert is recorded from there."""

from __future__ import annotations

import gym_pusht  # noqa: F401
import gymnasium as gym
import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_dcdp.data.pusht_demos import MARKER, record_demonstrations, run_episode
from lerobot_dcdp.data.takeover import PolicyLead, lead_steps_for


class ToCorner:
    """A lead that walks the agent towards one corner, and counts its resets."""

    def __init__(self) -> None:
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def __call__(self, obs: dict) -> np.ndarray:
        return np.asarray(obs["agent_pos"], float) + np.array([-15.0, -15.0])


def test_only_the_expert_is_recorded_from_the_state_the_lead_left() -> None:
    lead = ToCorner()
    ep = run_episode(5, lead=lead, lead_steps=12)
    assert lead.resets == 1 and ep.success and ep.success_flags[-1]
    env = gym.make("gym_pusht/PushT-v0", obs_type="environment_state_agent_pos", max_episode_steps=400)
    obs, _ = env.reset(seed=5)
    start = obs["agent_pos"].copy()
    for _ in range(12):
        obs, *_ = env.step(lead(obs))
    np.testing.assert_allclose(ep.state[0], obs["agent_pos"], atol=1e-4)
    np.testing.assert_allclose(ep.env_state[0], obs["environment_state"], atol=1e-4)
    assert np.linalg.norm(ep.state[0] - start) > 50  # the lead really drove (12 steps of ~15 px)
    for a in ep.action:  # the expert's recorded actions finish the job from there
        _, _, _, _, info = env.step(a.astype(np.float64))
    assert info["is_success"]
    plain = run_episode(5)
    assert len(plain.action) != len(ep.action) or not np.array_equal(plain.action, ep.action)


def test_an_episode_the_lead_solves_is_dropped() -> None:
    expert_actions = iter(run_episode(3, hold_steps=0).action)
    ep = run_episode(3, lead=lambda obs: next(expert_actions), lead_steps=400)
    assert not ep.success and len(ep.action) == 0 and ep.state.shape == (0, 2)


def test_lead_steps_are_seeded_and_in_range() -> None:
    steps = [lead_steps_for(s, 8, 20) for s in range(200)]
    assert min(steps) == 8 and max(steps) == 20
    assert steps == [lead_steps_for(s, 8, 20) for s in range(200)]


def test_takeover_dataset_from_a_pretrained_policy(act_base, tmp_path) -> None:
    root = tmp_path / "takeover"
    info = record_demonstrations(
        root, "local/t", episodes=1, seed=40, progress=False, takeover=(str(act_base), 3, 5)
    )
    ds = LeRobotDataset("local/t", root=root)
    assert ds.meta.total_episodes == 1 and np.asarray(ds.hf_dataset["next.success"]).reshape(-1)[-1]
    assert "takeover=" in (root / MARKER).read_text()
    # the recorded episode starts where the tiny ACT left the agent after lead_steps_for(seed) steps
    seed = info["seeds"][0]
    lead = PolicyLead(str(act_base))
    lead.reset()
    env = gym.make("gym_pusht/PushT-v0", obs_type="environment_state_agent_pos", max_episode_steps=400)
    obs, _ = env.reset(seed=seed)
    for _ in range(lead_steps_for(seed, 3, 5)):
        obs, *_ = env.step(lead(obs))
    np.testing.assert_allclose(ds[0]["observation.state"].numpy(), obs["agent_pos"], atol=1e-3)


def test_bad_takeover_arguments_fail_before_anything_is_written(act_base, tmp_path) -> None:
    with pytest.raises(ValueError, match="low <= high"):
        record_demonstrations(tmp_path / "a", episodes=1, progress=False, takeover=(str(act_base), 5, 2))
    with pytest.raises(ValueError, match="takeover policy"):
        record_demonstrations(
            tmp_path / "b", episodes=1, progress=False, takeover=(str(tmp_path / "none"), 1, 2)
        )
    with pytest.raises(ValueError, match="state-only"):
        record_demonstrations(
            tmp_path / "c", episodes=1, images=True, progress=False, takeover=(str(act_base), 1, 2)
        )
    assert list(tmp_path.iterdir()) == []
