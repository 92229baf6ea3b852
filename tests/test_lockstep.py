"""The one lock-step rollout loop: episode ends, what ``act`` and ``on_step`` see, per-env results."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_dcdp.sim.lockstep import run_lockstep


class CountingEnv:
    """Observation = steps taken; reward = -1 + action; succeeds at ``success_at`` steps, truncates at
    ``truncate_at``."""

    def __init__(self, success_at: int | None = None, truncate_at: int | None = None) -> None:
        self.success_at, self.truncate_at, self.t, self.seed = success_at, truncate_at, 0, None

    def reset(self, seed=None):
        self.t, self.seed = 0, seed
        return {"t": self.t}, {}

    def step(self, action):
        self.t += 1
        success = self.success_at is not None and self.t >= self.success_at
        trunc = self.truncate_at is not None and self.t >= self.truncate_at
        return {"t": self.t}, float(action[0]) - 1.0, False, trunc, {"is_success": success}


def test_each_env_runs_until_its_own_end_and_the_caller_sees_every_step() -> None:
    envs = [CountingEnv(success_at=2), CountingEnv(truncate_at=4), CountingEnv()]
    seen_active, stepped = [], []

    def act(obs, active):
        seen_active.append(active.tolist())
        return np.array([[o["t"] * 0.5] for o in obs])

    out = run_lockstep(
        envs, [7, 8, 9], act, max_steps=5, on_step=lambda i, o, r, info: stepped.append((i, o["t"]))
    )
    assert [e.seed for e in envs] == [7, 8, 9]
    assert out.steps == [2, 4, 5] and out.successes == [True, False, False]
    assert [o["t"] for o in out.obs] == [2, 4, 5]  # an ended env keeps its last observation
    assert seen_active == [[True, True, True]] * 2 + [[False, True, True]] * 2 + [[False, False, True]]
    assert stepped.count((0, 2)) == 1 and not any(i == 0 and t > 2 for i, t in stepped)
    assert len(stepped) == 2 + 4 + 5
    # best reward: action t * 0.5 at step t -> reward 0.5 t - 1, largest at the last step taken
    assert out.max_rewards == pytest.approx([0.5 * 1 - 1, 0.5 * 3 - 1, 0.5 * 4 - 1])


def test_stops_once_every_env_ended_and_refuses_mismatched_seeds() -> None:
    calls = []
    out = run_lockstep([CountingEnv(success_at=1)], [0], lambda o, a: calls.append(1) or np.ones((1, 1)), 50)
    assert out.steps == [1] and len(calls) == 1
    with pytest.raises(ValueError, match="2 envs but 1 seeds"):
        run_lockstep([CountingEnv(), CountingEnv()], [0], lambda o, a: np.ones((2, 1)), 3)
