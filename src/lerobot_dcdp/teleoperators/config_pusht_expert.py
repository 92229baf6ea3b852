"""Configuration of the scripted PushT expert teleoperator (``--teleop.type=pusht_expert``)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators.config import TeleoperatorConfig


@TeleoperatorConfig.register_subclass("pusht_expert")
@dataclass
class PushTExpertConfig(TeleoperatorConfig):
    """The PushT scripted expert (:mod:`lerobot_dcdp.pusht.expert`) as a LeRobot teleoperator: a stand-in for
    a person correcting the robot, so the person-in-the-loop path runs without one.

    Args:
        replan_every: Control steps the expert executes of a plan before it plans again from the latest
            observation (a person's reaction time, in steps). 8 reaches 80 % / 60 % success at constant
            0.5 / 1.0 px/step block drift (docs/ANALYSIS.md).
        max_step: Largest distance (px) between consecutive targets it sends.
        seed: Seed of the expert's escape moves (when no push improves the block's pose).
        id: LeRobot's teleoperator id (``--teleop.id``); default ``pusht_expert``.
    """

    replan_every: int = 8
    max_step: float = 20.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.id is None:
            self.id = "pusht_expert"
        if isinstance(self.replan_every, bool) or not isinstance(self.replan_every, int):
            raise ValueError(f"replan_every must be an integer >= 1, got {self.replan_every!r}")
        if self.replan_every < 1:
            raise ValueError(f"replan_every must be >= 1, got {self.replan_every}")
        if not self.max_step > 0:
            raise ValueError(f"max_step must be > 0 px, got {self.max_step}")
