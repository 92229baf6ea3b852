"""A simulated PushT robot for ``lerobot-rollout``: gym-pusht plus the ``pusht_perturbed`` block drift.

The robot speaks LeRobot's robot contract (``connect`` / ``get_observation`` / ``send_action`` /
``disconnect``) on top of :func:`~lerobot_dcdp.sim.envs.pusht_perturbed.make_perturbed_env`:

* observation: the agent position ``x.pos``, ``y.pos``, then the 8 block keypoints ``kp{i}_x.pos``,
  ``kp{i}_y.pos`` (px): ``observation.state`` (2) followed by ``observation.environment_state`` (16) of
  the PushT datasets (``dcdp-pusht-demos``) and of the shipped bases;
* action: the agent's target position ``x.pos``, ``y.pos`` (px), clipped to the 512 x 512 arena.

LeRobot's ``lerobot-rollout`` keeps only scalar features named ``*.pos`` / ``*.vel`` (and cameras), hence
the suffix, and joins them in this order into one 18-wide ``observation.state`` (also what a recording
strategy writes). The DCDP pre-processor's first step, ``dcdp_split_state``
(:mod:`lerobot_dcdp.policy.processor_split_state`), cuts it back into the two keys the policy reads.
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from lerobot.robots import Robot
from lerobot.utils.decorators import check_if_already_connected, check_if_not_connected

from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env
from lerobot_dcdp.sim.robots.config_pusht_sim import PushTSimConfig

logger = logging.getLogger(__name__)

#: Agent position (observation) and target position (action), px.
AGENT_NAMES: tuple[str, ...] = ("x.pos", "y.pos")
#: The 8 block keypoints of gym-pusht's ``environment_state``, px, as (x, y) pairs.
KEYPOINT_NAMES: tuple[str, ...] = tuple(f"kp{i}_{axis}.pos" for i in range(8) for axis in "xy")


class PushTSim(Robot):
    """gym-pusht's PushT (state observations) with optional block drift, as a LeRobot robot.

    Simulated time advances only through :meth:`send_action` (one 0.1 s control step per action in
    lock-step mode; in ``realtime`` mode as many steps as the wall clock says are due, see
    :class:`PushTSimConfig`). ``connect()`` starts an episode from ``config.seed``. Without
    ``config.episode_steps`` it never ends: the simulation keeps running after success, as a robot would.
    With it, an episode ends after that many steps (or at success, ``end_on_success``), is recorded in
    :attr:`episodes` (and ``config.episodes_path``), and the next starts at once from the next seed: the
    scene jumps, as it would after a reset between a real robot's episodes; the client is not told (in
    ``realtime`` mode, steps the world runs under a late tick's previous target may cross into the next
    episode, as they would on a robot).

    Attributes:
        actions_sent: ``send_action`` calls since ``connect()``.
        sim_steps: Simulated control steps since ``connect()``.
        late_actions: (``realtime``) actions before which more than one step was due.
        held_steps: (``realtime``) steps the world ran under a previous target because the new action was
            late.
        superseded_actions: (``realtime``) actions replaced by a newer one before any step was due (sent
            less than a step after the previous one, e.g. right after a late tick): never executed.
        coverage: Goal coverage after the latest step; ``max_coverage`` and ``succeeded`` since ``connect()``.
        episodes: Finished episodes since ``connect()`` (``episode_steps`` only), one record each: ``episode``
            (from 0), ``seed``, ``steps``, ``score`` (the episode's max reward, LeRobot's ``avg_max_reward``
            term), ``max_coverage``, ``success``.
    """

    config_class = PushTSimConfig
    name = "pusht_sim"

    def __init__(self, config: PushTSimConfig) -> None:
        super().__init__(config)
        self.config = config
        #: the wall clock of ``realtime`` mode (seconds); a test may substitute a controlled one
        self.clock = time.perf_counter
        self._env: Any = None
        self._obs: dict[str, np.ndarray] | None = None
        self._reset_stats()

    def _reset_stats(self) -> None:
        self._target: np.ndarray | None = None
        self._anchor: float | None = None
        self._steps_since_anchor = 0
        self.actions_sent = 0
        self.sim_steps = 0
        self.late_actions = 0
        self.held_steps = 0
        self.superseded_actions = 0
        self.coverage = 0.0
        self.max_coverage = 0.0
        self.succeeded = False
        self.episodes: list[dict[str, Any]] = []
        self._start_episode_stats()

    def _start_episode_stats(self) -> None:
        self._episode_steps = 0
        self._episode_reward = 0.0
        self._episode_coverage = 0.0
        self._episode_success = False

    # ------------------------------------------------------------------ features
    @property
    def observation_features(self) -> dict[str, type]:
        return dict.fromkeys(AGENT_NAMES + KEYPOINT_NAMES, float)

    @property
    def action_features(self) -> dict[str, type]:
        return dict.fromkeys(AGENT_NAMES, float)

    # ------------------------------------------------------------------ connection
    @property
    def is_connected(self) -> bool:
        return self._env is not None

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        """Nothing to calibrate in simulation."""

    def configure(self) -> None:
        """Nothing to configure in simulation."""

    @check_if_already_connected
    def connect(self, calibrate: bool = True) -> None:
        """Build the simulation and start an episode from ``config.seed``."""
        cfg = self.config
        env = make_perturbed_env(
            perturbation=cfg.perturbation,
            magnitude=cfg.magnitude,
            direction_deg=cfg.direction_deg,
            resample_every=cfg.resample_every,
            directions_deg=cfg.directions_deg,
            max_episode_steps=-1,
            obs_type="environment_state_agent_pos",
        )
        self._obs, _ = env.reset(seed=cfg.seed)
        self._reset_stats()
        if cfg.episodes_path is not None:
            Path(cfg.episodes_path).parent.mkdir(parents=True, exist_ok=True)
        self._sim_dt = 1.0 / float(env.unwrapped.control_hz)
        self._low = env.action_space.low.astype(np.float64)
        self._high = env.action_space.high.astype(np.float64)
        self._env = env
        logger.info(f"{self} connected (perturbation={cfg.perturbation}, magnitude={cfg.magnitude}).")

    @check_if_not_connected
    def disconnect(self) -> None:
        """Close the simulation and log what happened in it."""
        self._env.close()
        self._env = None
        logger.info(
            f"{self} disconnected: actions={self.actions_sent} sim_steps={self.sim_steps} "
            f"late_actions={self.late_actions} held_steps={self.held_steps} "
            f"superseded_actions={self.superseded_actions} "
            f"max_coverage={self.max_coverage:.3f} success={self.succeeded}"
            + (f" episodes={len(self.episodes)} mean_score={self.mean_score():.3f}" if self.episodes else "")
        )

    def mean_score(self) -> float:
        """Mean ``score`` of the finished :attr:`episodes` (0.0 when none finished)."""
        return float(np.mean([e["score"] for e in self.episodes])) if self.episodes else 0.0

    # ------------------------------------------------------------------ I/O
    @check_if_not_connected
    def get_observation(self) -> dict[str, float]:
        """The agent position and the block keypoints after the latest simulated step (px)."""
        values = np.concatenate([self._obs["agent_pos"], self._obs["environment_state"]])
        return {k: float(v) for k, v in zip(AGENT_NAMES + KEYPOINT_NAMES, values, strict=True)}

    @check_if_not_connected
    def send_action(self, action: dict[str, Any]) -> dict[str, float]:
        """Set the agent's target position and advance the simulation.

        Keys other than ``x.pos`` / ``y.pos`` are ignored (LeRobot's return-to-initial-position sends every
        ``*.pos`` key of the observation).

        Args:
            action: At least ``{"x.pos": float, "y.pos": float}``, px.

        Returns:
            The target actually used: clipped to the arena.

        Raises:
            ValueError: a key is missing or a value is not a finite number.
        """
        missing = [k for k in AGENT_NAMES if k not in action]
        if missing:
            raise ValueError(f"pusht_sim action is missing {missing}; expected keys {list(AGENT_NAMES)}")
        try:
            target = np.array([float(action[k]) for k in AGENT_NAMES])
        except (TypeError, ValueError) as err:
            raise ValueError(f"pusht_sim action values must be numbers, got {action!r}") from err
        if not np.isfinite(target).all():
            raise ValueError(f"pusht_sim action values must be finite, got {action!r}")
        target = np.clip(target, self._low, self._high)
        previous = self._target if self._target is not None else np.asarray(self._obs["agent_pos"], float)
        self._target = target
        self.actions_sent += 1
        if not self.config.realtime:
            self._step(target)
        else:
            now = self.clock()
            if self._anchor is None:
                self._anchor = now
            # steps due since the first action: one at the first action, then one per elapsed 0.1 s,
            # rounded to the nearest step so that on-time ticks never alias to 0 or 2 steps
            due = 1 + math.floor((now - self._anchor) / self._sim_dt + 0.5)
            n = due - self._steps_since_anchor
            if n > 1:
                self.late_actions += 1
                self.held_steps += n - 1
            elif n < 1:
                self.superseded_actions += 1
            for i in range(n):
                self._step(previous if i < n - 1 else target)
            self._steps_since_anchor += max(n, 0)
        return {k: float(v) for k, v in zip(AGENT_NAMES, target, strict=True)}

    def _step(self, target: np.ndarray) -> None:
        self._obs, reward, _, _, info = self._env.step(target.astype(np.float32))
        self.sim_steps += 1
        self.coverage = float(info.get("coverage", 0.0))
        self.max_coverage = max(self.max_coverage, self.coverage)
        success = bool(info.get("is_success", False))
        self.succeeded = self.succeeded or success
        cfg = self.config
        if cfg.episode_steps is None:
            return
        self._episode_steps += 1
        self._episode_reward = max(self._episode_reward, float(reward))
        self._episode_coverage = max(self._episode_coverage, self.coverage)
        self._episode_success = self._episode_success or success
        if self._episode_steps >= cfg.episode_steps or (success and cfg.end_on_success):
            self._finish_episode()

    def _finish_episode(self) -> None:
        """Record the episode that just ended and start the next one from the next seed."""
        cfg = self.config
        k = len(self.episodes)
        record = {
            "episode": k,
            "seed": None if cfg.seed is None else cfg.seed + k,
            "steps": self._episode_steps,
            "score": self._episode_reward,
            "max_coverage": self._episode_coverage,
            "success": self._episode_success,
        }
        self.episodes.append(record)
        if cfg.episodes_path is not None:  # one short line per append-mode write; no fsync on the tick
            with open(cfg.episodes_path, "a") as f:
                f.write(json.dumps(record) + "\n")
        logger.info(f"{self} episode {k} ended: {record}")
        self._obs, _ = self._env.reset(seed=None if cfg.seed is None else cfg.seed + k + 1)
        self._start_episode_stats()

    @property
    @check_if_not_connected
    def block_pose(self) -> tuple[float, float, float]:
        """The T block's ``(x, y, angle)`` in the simulation (px, px, rad)."""
        block = self._env.unwrapped.block
        return float(block.position[0]), float(block.position[1]), float(block.angle)
