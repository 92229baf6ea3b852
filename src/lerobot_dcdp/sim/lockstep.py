"""One lock-step rollout loop over a batch of gym envs, shared by the benchmark, the recorder and the expert.

Every step the caller's ``act`` sees all observations and returns one action per env; the envs still running
take their action; an env's episode ends on termination, truncation, success (``info["is_success"]``) or
``max_steps``. Callers hook in per env after each step (``on_step``) for what they record.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass
class LockstepResult:
    """Per-env outcome of :func:`run_lockstep`.

    Attributes:
        obs: Each env's last observation (after its final step).
        successes: Whether ``info["is_success"]`` was reported.
        max_rewards: The largest reward of each episode.
        steps: Steps each env took.
    """

    obs: list[dict]
    successes: list[bool] = field(default_factory=list)
    max_rewards: list[float] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)


def run_lockstep(
    envs: list,
    seeds: list[int],
    act: Callable[[list[dict], np.ndarray], np.ndarray],
    max_steps: int,
    on_step: Callable[[int, dict, float, dict], None] | None = None,
) -> LockstepResult:
    """Reset ``envs[i]`` with ``seeds[i]`` and run them side by side.

    Args:
        envs: Gym envs (not closed here).
        seeds: One reset seed per env.
        act: ``act(obs, active)`` -> actions (n, A): ``obs`` holds every env's current observation (ended
            envs keep their last one), ``active`` which envs still run; rows of ended envs are ignored.
        max_steps: Step limit of every episode.
        on_step: ``on_step(i, obs, reward, info)`` after env ``i`` stepped.

    Returns:
        The last observations and per-env success, best reward and step count.
    """
    if len(envs) != len(seeds):
        raise ValueError(f"{len(envs)} envs but {len(seeds)} seeds")
    obs = [env.reset(seed=s)[0] for env, s in zip(envs, seeds, strict=True)]
    n = len(envs)
    active = np.ones(n, dtype=bool)
    success = np.zeros(n, dtype=bool)
    best = np.full(n, -np.inf)
    steps = np.zeros(n, dtype=int)
    for _ in range(max_steps):
        actions = act(obs, active.copy())
        for i in np.flatnonzero(active):
            o, r, term, trunc, info = envs[i].step(actions[i])
            obs[i] = o
            steps[i] += 1
            best[i] = max(best[i], float(r))
            success[i] = success[i] or bool(info.get("is_success", False))
            if on_step is not None:
                on_step(int(i), o, float(r), info)
            if term or trunc or success[i]:
                active[i] = False
        if not active.any():
            break
    best[steps == 0] = 0.0
    return LockstepResult(obs, success.tolist(), best.tolist(), steps.tolist())
