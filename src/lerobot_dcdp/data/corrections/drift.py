"""The drift of a recorded episode and the gym env that runs it.

Drift per episode is drawn from the episode's seed: none with probability ``static_fraction``, else constant
(direction uniform on the circle) or random (5 directions drawn uniformly, redrawn every 25/50/100 steps),
with a magnitude uniform in ``[0, max_magnitude]`` px/step. ``pusht_perturbed`` (the default env) applies it;
any other registered LeRobot env runs as its ``--env.*`` flags configure it, without drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class DriftSpec:
    """The perturbation of one recorded episode."""

    perturbation: str
    magnitude: float
    direction_deg: float
    directions_deg: tuple[float, ...]
    resample_every: int

    def env_kwargs(self) -> dict:
        return {
            "perturbation": self.perturbation,
            "magnitude": self.magnitude,
            "direction_deg": self.direction_deg,
            "directions_deg": self.directions_deg,
            "resample_every": self.resample_every,
        }


def drift_for_seed(seed: int, max_magnitude: float, static_fraction: float) -> DriftSpec:
    """The drift of episode ``seed`` (a pure function of its arguments)."""
    rng = np.random.default_rng([seed, 7_919])
    static = rng.random() < static_fraction
    kind = "constant" if rng.random() < 0.5 else "random"
    mag = float(rng.uniform(0.0, max_magnitude))
    direction = float(rng.uniform(0.0, 360.0))
    dirs = tuple(float(d) for d in rng.uniform(0.0, 360.0, 5))
    every = int(rng.choice([25, 50, 100]))
    if static or mag == 0.0:
        return DriftSpec("none", 0.0, direction, dirs, every)
    return DriftSpec(kind, mag, direction, dirs, every)


def drift_specs(
    seeds: list[int], drifting: bool, max_magnitude: float, static_fraction: float
) -> list[DriftSpec]:
    """The drift of each episode: drawn per seed (:func:`drift_for_seed`) when the env drifts
    (``pusht_perturbed``), else none."""
    if drifting:
        return [drift_for_seed(s, max_magnitude, static_fraction) for s in seeds]
    return [DriftSpec("none", 0.0, 0.0, (0.0,), 50) for _ in seeds]


def episode_env(env_config, spec: DriftSpec, max_steps: int):
    """One episode's gym env: ``pusht_perturbed`` (the default) with the episode's drawn drift, or any other
    registered LeRobot env type as its ``--env.*`` flags configure it (its own dynamics; no drift drawn)."""
    import gymnasium as gym

    from lerobot_dcdp.sim.envs.pusht_perturbed import PushTPerturbedEnvConfig, make_perturbed_env

    if env_config is None:
        return make_perturbed_env(
            obs_type="environment_state_agent_pos", max_episode_steps=max_steps, **spec.env_kwargs()
        )
    if isinstance(env_config, PushTPerturbedEnvConfig):
        # the config's own episode length gives way to max_steps (its gym kwargs hold max_episode_steps too)
        drift = spec.env_kwargs()
        own = {k: v for k, v in env_config.gym_kwargs.items() if k not in drift and k != "max_episode_steps"}
        return make_perturbed_env(max_episode_steps=max_steps, **own, **drift)
    import importlib

    importlib.import_module(env_config.package_name)
    kwargs = {**env_config.gym_kwargs, "max_episode_steps": max_steps}
    return gym.make(f"{env_config.package_name}/{env_config.task}", disable_env_checker=True, **kwargs)
