"""The scripted-expert demonstrations: loadable, successful, replayable, deterministic."""

from __future__ import annotations

import gym_pusht  # noqa: F401
import gymnasium as gym
import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_dcdp.data.pusht_demos import record_demonstrations, run_episode


def test_dataset_loads_and_every_episode_succeeds(demo_root) -> None:
    ds = LeRobotDataset("local/test", root=demo_root)
    assert ds.meta.total_episodes == 2 and ds.fps == 10
    assert set(ds.meta.features) >= {
        "observation.state",
        "observation.environment_state",
        "action",
        "next.reward",
        "next.success",
        "next.done",
    }
    ep = np.asarray(ds.hf_dataset["episode_index"])
    succ = np.asarray(ds.hf_dataset["next.success"]).reshape(-1)
    for e in range(2):
        idx = np.flatnonzero(ep == e)
        assert succ[idx].any(), "every kept episode reaches success"
        assert succ[idx[-1]], "every episode's last frame is in the success state"
    item = ds[0]
    assert item["observation.environment_state"].shape == (16,) and item["action"].shape == (2,)
    assert item["task"]


def test_actions_are_smooth_and_replay_reproduces_success(demo_root) -> None:
    ds = LeRobotDataset("local/test", root=demo_root)
    ep = np.asarray(ds.hf_dataset["episode_index"])
    actions = np.stack([np.asarray(a, dtype=np.float32) for a in ds.hf_dataset["action"]])
    idx = np.flatnonzero(ep == 0)
    jumps = np.linalg.norm(np.diff(actions[idx], axis=0), axis=1)
    assert jumps.max() <= 20.0 + 1e-3  # the expert's max_step
    env = gym.make("gym_pusht/PushT-v0", obs_type="environment_state_agent_pos", max_episode_steps=400)
    env.reset(seed=0)  # episode 0 was recorded from env seed 0
    success = False
    for a in actions[idx]:
        _, _, term, _, info = env.step(a.astype(np.float64))
        success |= bool(info["is_success"])
    assert success


def test_same_seed_same_data() -> None:
    a, b = run_episode(3), run_episode(3)
    assert np.array_equal(a.action, b.action) and np.array_equal(a.env_state, b.env_state)
    assert a.success
    c = run_episode(4)
    assert a.action.shape != c.action.shape or not np.array_equal(a.action, c.action)


@pytest.mark.parametrize("seed", [777, 778, 779, 780])
def test_hold_frames_keep_the_success_state(seed: int) -> None:
    ep = run_episode(seed)
    assert ep.success and ep.success_flags[-1]


def test_refuses_eval_seeds_and_foreign_folders_even_with_force(tmp_path) -> None:
    with pytest.raises(ValueError, match="seed"):
        record_demonstrations(tmp_path / "x", episodes=5, seed=99_999, progress=False)
    (tmp_path / "y").mkdir()
    (tmp_path / "y" / "file").write_text("keep")
    for force in (False, True):
        with pytest.raises(ValueError, match="not an output of dcdp-pusht-demos"):
            record_demonstrations(tmp_path / "y", episodes=1, progress=False, force=force)
    assert (tmp_path / "y" / "file").read_text() == "keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["y"]


def test_force_replaces_an_earlier_output_and_leaves_other_runs_tmp(tmp_path) -> None:
    root = tmp_path / "demos"
    record_demonstrations(root, episodes=1, seed=3, progress=False)
    with pytest.raises(ValueError, match="already exists"):
        record_demonstrations(root, episodes=1, seed=3, progress=False)
    (tmp_path / ".demos.tmp-other").mkdir()  # another run's folder (live or killed): never ours to delete
    record_demonstrations(root, episodes=1, seed=4, progress=False, force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".demos.tmp-other", "demos"]
    assert LeRobotDataset("local/test", root=root).meta.total_episodes == 1


def test_too_few_successes_is_one_clear_error(tmp_path, monkeypatch) -> None:
    from lerobot_dcdp.data import pusht_demos as demos

    monkeypatch.setattr(
        demos,
        "run_episode",
        lambda s, *a, **k: demos.Episode(
            s, False, *(np.zeros((1, 2)),) * 3, np.zeros(1), np.zeros(1, bool), None
        ),
    )
    with pytest.raises(ValueError, match="only 0 of"):
        record_demonstrations(tmp_path / "z", episodes=1, progress=False)
    assert not (tmp_path / "z").exists()
