"""PushT with a block-drift perturbation: the ``pusht_perturbed`` LeRobot env type.

The T block of gym-pusht's ``PushTEnv`` is translated by a small offset once per control step, right
before the inner env's physics step (equivalently: after the previous step's physics), so the
observation, reward, ``coverage`` and ``is_success`` returned by that step already describe the
perturbed state. Translating ``block.position`` is the only perturbation that works in this
simulator: the space has ``damping=0`` (bodies keep no velocity between physics substeps), so
velocities or impulses are wiped out immediately.

Three pieces are exposed:

* :class:`BlockPerturbation`: a ``gymnasium.Wrapper`` around a ``PushTEnv``;
* :func:`make_perturbed_env` and the gymnasium id :data:`GYM_ID` (``lerobot_dcdp/PushTPerturbed-v0``)
  for plain-gymnasium users and scripts;
* :class:`PushTPerturbedEnvConfig`: LeRobot's ``pusht`` env config plus the perturbation flags,
  registered as ``--env.type=pusht_perturbed``. It builds its own vector envs from a picklable
  module-level factory, so ``--eval.use_async_envs=true`` works (LeRobot 0.6.1's stock ``pusht`` fails
  there with ``Namespace gym_pusht not found`` in the forkserver workers).

See ``docs/ENV.md`` for the semantics.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from lerobot.envs.configs import EnvConfig, PushtEnv

from lerobot_dcdp.sim.pusht_geometry import ARENA_HI, ARENA_LO, block_vertices, clip_offset

#: The observation type that returns the 96x96 frame, the agent position *and* the block keypoints: for
#: teachers, labels and reports beside an image policy (a policy reads only the features it declares).
PIXELS_KEYPOINTS = "pixels_environment_state_agent_pos"
#: gym-pusht's own observation types and :data:`PIXELS_KEYPOINTS`.
OBS_TYPES = ("state", "environment_state_agent_pos", "pixels", "pixels_agent_pos", PIXELS_KEYPOINTS)
#: Gymnasium id registered on import of this module.
GYM_ID = "lerobot_dcdp/PushTPerturbed-v0"
#: Episode length of gym-pusht's PushT-v0 (and of the protocol).
MAX_EPISODE_STEPS = 300
#: Perturbation modes.
PERTURBATION_MODES = ("none", "constant", "random")
#: The authors' direction set of the random mode (degrees, pixel frame: 0 = +x, 90 = +y).
DEFAULT_DIRECTIONS_DEG: tuple[float, ...] = (-45.0, 0.0, 45.0, 90.0, 135.0)
#: Mixed with the episode seed so the perturbation stream is independent of the env's own RNG.
PERTURBATION_SEED_SALT = 0xDCD9
#: Language task reported to LeRobot (same string as the ``dcdp-pusht-demos`` datasets).
TASK_DESCRIPTION = "Push the T-shaped block onto the T-shaped target."
#: Short task name reported to LeRobot as ``task``.
TASK_NAME = "PushTPerturbed-v0"


def validate_perturbation(
    perturbation: str,
    magnitude: float,
    direction_deg: float,
    resample_every: int,
    directions_deg: Sequence[float],
) -> None:
    """Check the perturbation parameters.

    Raises:
        ValueError: naming the first bad field.
    """
    if perturbation not in PERTURBATION_MODES:
        raise ValueError(f"perturbation must be one of {PERTURBATION_MODES}, got {perturbation!r}")
    if not _is_finite_number(magnitude) or magnitude < 0:
        raise ValueError(f"magnitude must be a finite number >= 0 (px per control step), got {magnitude!r}")
    if not _is_finite_number(direction_deg):
        raise ValueError(f"direction_deg must be a finite number of degrees, got {direction_deg!r}")
    if (
        isinstance(resample_every, bool)
        or not isinstance(resample_every, int | np.integer)
        or resample_every < 1
    ):
        raise ValueError(f"resample_every must be an integer >= 1 (control steps), got {resample_every!r}")
    if (
        isinstance(directions_deg, str | bytes)
        or not isinstance(directions_deg, Sequence)
        or len(directions_deg) == 0
        or not all(_is_finite_number(d) for d in directions_deg)
    ):
        raise ValueError(f"directions_deg must be a non-empty list of finite degrees, got {directions_deg!r}")


def _is_finite_number(x: object) -> bool:
    return not isinstance(x, bool) and isinstance(x, int | float | np.number) and math.isfinite(float(x))


def _unit(deg: float) -> np.ndarray:
    rad = math.radians(deg)
    return np.array([math.cos(rad), math.sin(rad)])


class BlockPerturbation(gym.Wrapper):
    """Translate gym-pusht's T block by ``magnitude`` px once per control step.

    The offset is applied right before the inner env's ``step`` (so before its physics), clipped per axis
    with :func:`~lerobot_dcdp.sim.pusht_geometry.clip_offset` so that every T corner stays inside the arena,
    and the block's linear and angular velocity are zeroed after the move.

    Modes:
        ``none``: pass-through (the info keys are still reported, with a zero offset).
        ``constant``: fixed direction ``direction_deg``.
        ``random``: a direction drawn uniformly from ``directions_deg`` at reset and re-drawn before steps
        ``resample_every``, ``2 * resample_every``, ... (0-based step index; a redraw may repeat).

    Seeding: ``reset(seed=s)`` re-seeds the wrapper's RNG from ``SeedSequence([s, PERTURBATION_SEED_SALT])``,
    so the perturbation sequence is a function of the episode seed; ``reset()`` without a seed continues
    the stream.

    Info keys (reset and step): ``perturbation_offset`` (float64 (2,), the offset applied this step after
    clipping; zeros on reset), ``perturbation_direction_deg`` (current direction; NaN in mode ``none``),
    ``perturbation_clipped`` (the arena shortened this step's offset).

    Args:
        env: a gym-pusht ``PushTEnv`` (possibly wrapped; the block is reached through ``env.unwrapped``).
        perturbation: ``none``, ``constant`` or ``random``.
        magnitude: px per control step (Euclidean norm of the requested offset).
        direction_deg: direction of the ``constant`` mode, degrees in the pixel frame (0 = +x, 90 = +y).
        resample_every: control steps between direction draws of the ``random`` mode.
        directions_deg: the set the ``random`` mode draws from.
    """

    #: Queried by ``lerobot-eval`` through ``VectorEnv.call``.
    task: str = TASK_NAME
    task_description: str = TASK_DESCRIPTION

    def __init__(
        self,
        env: gym.Env,
        perturbation: str = "none",
        magnitude: float = 1.0,
        direction_deg: float = 45.0,
        resample_every: int = 50,
        directions_deg: Sequence[float] = DEFAULT_DIRECTIONS_DEG,
    ) -> None:
        super().__init__(env)
        validate_perturbation(perturbation, magnitude, direction_deg, resample_every, directions_deg)
        self.perturbation = perturbation
        self.magnitude = float(magnitude)
        self.direction_deg = float(direction_deg)
        self.resample_every = int(resample_every)
        self.directions_deg = tuple(float(d) for d in directions_deg)
        self._rng = np.random.default_rng()
        self._t = 0
        self._dir_deg = self._initial_direction()

    def _initial_direction(self) -> float:
        if self.perturbation == "constant":
            return self.direction_deg
        if self.perturbation == "random":
            return self.directions_deg[int(self._rng.integers(len(self.directions_deg)))]
        return math.nan

    @property
    def current_direction_deg(self) -> float:
        """Direction (degrees) that the next step uses unless a redraw is due; NaN in mode ``none``."""
        return self._dir_deg

    def _info(self, info: dict[str, Any], offset: np.ndarray, clipped: bool) -> dict[str, Any]:
        info["perturbation_offset"] = np.asarray(offset, dtype=np.float64).copy()
        info["perturbation_direction_deg"] = float(self._dir_deg)
        info["perturbation_clipped"] = bool(clipped)
        return info

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the inner env; re-seed the perturbation RNG when ``seed`` is given."""
        if seed is not None:
            self._rng = np.random.default_rng(np.random.SeedSequence([int(seed), PERTURBATION_SEED_SALT]))
        obs, info = self.env.reset(seed=seed, options=options)
        self._t = 0
        self._dir_deg = self._initial_direction()
        return obs, self._info(info, np.zeros(2), False)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        """Move the block by this step's offset, then step the inner env."""
        applied = np.zeros(2)
        clipped = False
        if self.perturbation != "none":
            if self.perturbation == "random" and self._t > 0 and self._t % self.resample_every == 0:
                self._dir_deg = self.directions_deg[int(self._rng.integers(len(self.directions_deg)))]
            block = self.env.unwrapped.block
            requested = self.magnitude * _unit(self._dir_deg)
            verts = block_vertices(tuple(block.position), float(block.angle))
            applied, hit = clip_offset(verts, requested, ARENA_LO, ARENA_HI)
            clipped = bool(hit.any())
            if np.any(applied != 0.0):
                x, y = block.position
                block.position = (x + float(applied[0]), y + float(applied[1]))
                block.velocity = (0.0, 0.0)
                block.angular_velocity = 0.0
        self._t += 1
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._info(info, applied, clipped)


class KeypointObservation(gym.ObservationWrapper):
    """Add the block's keypoints (``environment_state``, 16 values in world px) to a ``pixels_agent_pos``
    observation of gym-pusht's ``PushTEnv``, read from the simulator after every reset and step."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        if env.unwrapped.obs_type != "pixels_agent_pos":
            raise ValueError(
                f"KeypointObservation wraps obs_type='pixels_agent_pos', got {env.unwrapped.obs_type!r}"
            )
        spaces = dict(env.observation_space.spaces)
        spaces["environment_state"] = gym.spaces.Box(low=0.0, high=512.0, shape=(16,), dtype=np.float64)
        self.observation_space = gym.spaces.Dict(spaces)

    def observation(self, observation: dict) -> dict:
        """The observation with ``environment_state`` added (gym-pusht's ``get_keypoints``, flattened)."""
        u = self.env.unwrapped
        return {**observation, "environment_state": u.get_keypoints(u._block_shapes).flatten()}


def _make_wrapped_pusht(
    perturbation: str = "none",
    magnitude: float = 1.0,
    direction_deg: float = 45.0,
    resample_every: int = 50,
    directions_deg: Sequence[float] = DEFAULT_DIRECTIONS_DEG,
    **pusht_kwargs: Any,
) -> BlockPerturbation:
    """Entry point of :data:`GYM_ID`: ``BlockPerturbation(PushTEnv(**pusht_kwargs))`` (no TimeLimit).

    ``obs_type=PIXELS_KEYPOINTS`` builds a ``pixels_agent_pos`` env under :class:`KeypointObservation`.
    """
    from gym_pusht.envs.pusht import PushTEnv  # imported here so workers import gym-pusht themselves

    obs_type = pusht_kwargs.get("obs_type", "state")
    if obs_type not in OBS_TYPES:
        raise ValueError(f"obs_type must be one of {OBS_TYPES}, got {obs_type!r}")
    if obs_type == PIXELS_KEYPOINTS:
        inner: gym.Env = KeypointObservation(PushTEnv(**{**pusht_kwargs, "obs_type": "pixels_agent_pos"}))
    else:
        inner = PushTEnv(**pusht_kwargs)
    return BlockPerturbation(
        inner,
        perturbation=perturbation,
        magnitude=magnitude,
        direction_deg=direction_deg,
        resample_every=resample_every,
        directions_deg=directions_deg,
    )


def register_gym_id() -> None:
    """Register :data:`GYM_ID` with gymnasium (idempotent)."""
    if GYM_ID not in gym.registry:
        gym.register(
            GYM_ID,
            entry_point=f"{__name__}:_make_wrapped_pusht",
            max_episode_steps=MAX_EPISODE_STEPS,
            kwargs={"obs_type": "state"},
        )


register_gym_id()


def make_perturbed_env(
    perturbation: str = "none",
    magnitude: float = 1.0,
    direction_deg: float = 45.0,
    resample_every: int = 50,
    directions_deg: Sequence[float] = DEFAULT_DIRECTIONS_DEG,
    max_episode_steps: int = MAX_EPISODE_STEPS,
    disable_env_checker: bool = True,
    **pusht_kwargs: Any,
) -> gym.Env:
    """``gym.make(GYM_ID, ...)``: a perturbed PushT with gymnasium's TimeLimit and order enforcing.

    Args:
        perturbation: ``none``, ``constant`` or ``random``.
        magnitude: px per control step.
        direction_deg: direction of the ``constant`` mode (degrees, pixel frame).
        resample_every: steps between direction draws of the ``random`` mode.
        directions_deg: direction set of the ``random`` mode.
        max_episode_steps: TimeLimit (``-1`` for none).
        disable_env_checker: skip gymnasium's passive env checker.
        **pusht_kwargs: gym-pusht's own arguments (``obs_type``, ``render_mode``, ``observation_width``, ...);
            ``obs_type`` may also be :data:`PIXELS_KEYPOINTS` (frame, agent position and block keypoints).

    Returns:
        The env; ``env.unwrapped`` is the ``PushTEnv``, ``env.get_wrapper_attr("current_direction_deg")``
        reaches the perturbation state.
    """
    return gym.make(
        GYM_ID,
        max_episode_steps=max_episode_steps,
        disable_env_checker=disable_env_checker,
        perturbation=perturbation,
        magnitude=magnitude,
        direction_deg=direction_deg,
        resample_every=resample_every,
        directions_deg=tuple(directions_deg),
        **pusht_kwargs,
    )


def make_vector_member(freeze_after_episode_end: bool = True, **kwargs: Any) -> gym.Env:
    """Build one sub-env of a LeRobot vector env (module level, so ``functools.partial`` of it pickles).

    Args:
        freeze_after_episode_end: wrap in LeRobot's ``FreezeAfterEpisodeEnd`` so a finished sub-env stops
            simulating while the rest of the batch runs.
        **kwargs: arguments of :func:`make_perturbed_env`.
    """
    env = make_perturbed_env(**kwargs)
    if freeze_after_episode_end:
        from lerobot.envs.utils import FreezeAfterEpisodeEnd

        env = FreezeAfterEpisodeEnd(env)
    return env


@EnvConfig.register_subclass("pusht_perturbed")
@dataclass
class PushTPerturbedEnvConfig(PushtEnv):
    """LeRobot's ``pusht`` env config plus a block-drift perturbation (``--env.type=pusht_perturbed``).

    Every ``--env.*`` flag of ``pusht`` keeps its meaning. Added flags: ``perturbation``
    (``none``/``constant``/``random``), ``magnitude`` (px per control step), ``direction_deg`` (constant
    mode), ``resample_every`` and ``directions_deg`` (random mode). ``--env.obs_type`` also takes
    ``pixels_environment_state_agent_pos``: the frame, the agent position and the block keypoints together
    (``observation.image``, ``observation.state``, ``observation.environment_state``), so an image policy
    runs beside a teacher or a report that reads the keypoints.
    """

    perturbation: str = "none"
    magnitude: float = 1.0
    direction_deg: float = 45.0
    resample_every: int = 50
    directions_deg: list[float] = field(default_factory=lambda: list(DEFAULT_DIRECTIONS_DEG))

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type must be one of {OBS_TYPES}, got {self.obs_type!r}")
        if self.obs_type == PIXELS_KEYPOINTS:
            from lerobot.configs.types import FeatureType, PolicyFeature

            self.features["pixels"] = PolicyFeature(
                type=FeatureType.VISUAL, shape=(self.observation_height, self.observation_width, 3)
            )
            self.features["environment_state"] = PolicyFeature(type=FeatureType.ENV, shape=(16,))
        validate_perturbation(
            self.perturbation, self.magnitude, self.direction_deg, self.resample_every, self.directions_deg
        )
        n = self.episode_length
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"episode_length must be an integer >= 1, got {n!r}")

    @property
    def perturbation_kwargs(self) -> dict[str, Any]:
        """The perturbation arguments of :class:`BlockPerturbation`."""
        return {
            "perturbation": self.perturbation,
            "magnitude": float(self.magnitude),
            "direction_deg": float(self.direction_deg),
            "resample_every": int(self.resample_every),
            "directions_deg": tuple(float(d) for d in self.directions_deg),
        }

    @property
    def gym_kwargs(self) -> dict:
        """``pusht``'s gym kwargs (incl. ``max_episode_steps``) plus the perturbation arguments."""
        return {**super().gym_kwargs, **self.perturbation_kwargs}

    def create_envs(
        self, n_envs: int, use_async_envs: bool = False
    ) -> dict[str, dict[int, gym.vector.VectorEnv]]:
        """Build ``{"pusht_perturbed": {0: vec_env}}`` with ``n_envs`` sub-envs.

        Sub-envs come from a ``functools.partial`` of the module-level :func:`make_vector_member`, so
        ``AsyncVectorEnv`` workers (forkserver) import this module, and with it gym-pusht, themselves.
        Autoreset is ``NEXT_STEP`` and each sub-env freezes after its episode ends (as LeRobot does for
        its own multi-process benchmarks), so ``is_success`` arrives in the step's ``info``.
        """
        if n_envs < 1:
            raise ValueError(f"n_envs must be >= 1, got {n_envs}")
        factory = functools.partial(
            make_vector_member, disable_env_checker=self.disable_env_checker, **self.gym_kwargs
        )
        fns = [factory for _ in range(n_envs)]
        autoreset = gym.vector.AutoresetMode.NEXT_STEP
        if use_async_envs and n_envs > 1:
            vec: gym.vector.VectorEnv = gym.vector.AsyncVectorEnv(
                fns, context="forkserver", autoreset_mode=autoreset
            )
        else:
            vec = gym.vector.SyncVectorEnv(fns, autoreset_mode=autoreset)
        return {self.type: {0: vec}}
