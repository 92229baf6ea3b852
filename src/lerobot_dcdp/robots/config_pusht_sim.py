"""Configuration of the simulated PushT robot (``--robot.type=pusht_sim``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.robots import RobotConfig

from lerobot_dcdp.envs.pusht_perturbed import DEFAULT_DIRECTIONS_DEG, validate_perturbation


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
            unseeded.
        id: LeRobot's robot id (``--robot.id``); default ``pusht_sim``.
        realtime: ``True``: simulated time follows the wall clock from the first action on: an action
            that arrives more than one control step (0.1 s) after the previous one first lets the world
            run the missed steps under the previous target, as a real robot would. ``False``: lock-step,
            every ``send_action`` advances the simulation by exactly one control step.
    """

    perturbation: str = "none"
    magnitude: float = 1.0
    direction_deg: float = 45.0
    resample_every: int = 50
    directions_deg: list[float] = field(default_factory=lambda: list(DEFAULT_DIRECTIONS_DEG))
    seed: int | None = 0
    realtime: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.id is None:  # LeRobot prints the robot as "<id> <class>": name it rather than "None"
            self.id = "pusht_sim"
        validate_perturbation(
            self.perturbation, self.magnitude, self.direction_deg, self.resample_every, self.directions_deg
        )
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int)):
            raise ValueError(f"seed must be an integer or None, got {self.seed!r}")
