"""Configuration of the simulated PushT robot (``--robot.type=pusht_sim``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.robots import RobotConfig

from lerobot_dcdp.sim.envs.pusht_perturbed import DEFAULT_DIRECTIONS_DEG, validate_perturbation


@RobotConfig.register_subclass("pusht_sim")
@dataclass
class PushTSimConfig(RobotConfig):
    """gym-pusht behind LeRobot's robot interface, with the ``pusht_perturbed`` block drift.

    The perturbation flags have the meaning of ``--env.*`` of ``pusht_perturbed`` (see ``docs/ENV.md``).

    Args:
        perturbation: ``none``, ``constant`` or ``random`` block drift.
        magnitude: Drift in px per simulated control step (0.1 s of simulated time).
        direction_deg: Direction of the ``constant`` drift, degrees in the pixel frame (0 = +x, 90 = +y).
        resample_every: Simulated steps between direction draws of the ``random`` drift.
        directions_deg: Direction set of the ``random`` drift.
        seed: Seed of the episode started on ``connect()`` (block pose, goal, random drift); ``None``:
            unseeded. With ``episode_steps``, episode ``k`` (from 0) uses ``seed + k``, the benchmark's one
            episode per seed.
        realtime: ``True``: simulated time follows the wall clock from the first action on: an action
            that arrives more than one control step (0.1 s) after the previous one first lets the world
            run the missed steps under the previous target, as a real robot would. ``False``: lock-step,
            every ``send_action`` advances the simulation by exactly one control step.
        episode_steps: Simulated steps after which an episode ends and the next one starts (the benchmark's
            300); ``None``: one episode that never ends (the robot keeps running after success).
        end_on_success: With ``episode_steps``, also end an episode at its first success (coverage > 0.95),
            as the benchmark and ``lerobot-eval`` do.
        episodes_path: With ``episode_steps``, a JSON Lines file to which every finished episode appends one
            record (``episode``, ``seed``, ``steps``, ``score`` = max reward, ``max_coverage``, ``success``),
            so that a client that never asks the robot (LeRobot's stock ``RobotClient``) can be scored;
            ``None``: kept in memory only (``PushTSim.episodes``).
        id: LeRobot's robot id (``--robot.id``); default ``pusht_sim``.
    """

    perturbation: str = "none"
    magnitude: float = 1.0
    direction_deg: float = 45.0
    resample_every: int = 50
    directions_deg: list[float] = field(default_factory=lambda: list(DEFAULT_DIRECTIONS_DEG))
    seed: int | None = 0
    realtime: bool = True
    episode_steps: int | None = None
    end_on_success: bool = True
    episodes_path: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.id is None:  # LeRobot prints the robot as "<id> <class>": name it rather than "None"
            self.id = "pusht_sim"
        validate_perturbation(
            self.perturbation, self.magnitude, self.direction_deg, self.resample_every, self.directions_deg
        )
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int)):
            raise ValueError(f"seed must be an integer or None, got {self.seed!r}")
        steps = self.episode_steps
        if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
            raise ValueError(f"episode_steps must be an integer >= 1 or None, got {self.episode_steps!r}")
        if not isinstance(self.end_on_success, bool):
            raise ValueError(f"end_on_success must be true or false, got {self.end_on_success!r}")
        if self.episodes_path is not None and self.episode_steps is None:
            raise ValueError("episodes_path needs episode_steps (an endless episode never finishes)")
