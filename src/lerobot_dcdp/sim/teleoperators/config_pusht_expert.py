"""Configuration of the scripted PushT expert teleoperator (``--teleop.type=pusht_expert``)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators.config import TeleoperatorConfig


@TeleoperatorConfig.register_subclass("pusht_expert")
@dataclass
class PushTExpertConfig(TeleoperatorConfig):
    """The PushT scripted expert (:mod:`lerobot_dcdp.sim.pusht_expert`) as a LeRobot teleoperator: a stand-in
    for
    a person correcting the robot, so the person-in-the-loop path runs without one.

    Args:
        replan_every: Control steps the expert executes of a plan before it plans again from the latest
            observation (a person's reaction time, in steps). 8 reaches 80 % / 60 % success at constant
            0.5 / 1.0 px/step block drift (docs/FINDINGS.md).
        max_step: Largest distance (px) between consecutive targets it sends.
        follow_block: Track a moving block as a person would. Each plan predicts the block's pose after every
            action on the expert's exact simulator copy; between plans the targets move with the block's
            deviation from that prediction (the rigid motion from the predicted to the observed pose), and at
            each plan the deviation per step is added to a drift estimate that the next plan simulates (the
            block translated that much before every step, as ``pusht_perturbed`` does). On a still scene the
            prediction holds to within a pixel in contact, so the estimate stays ~0 and the expert acts as
            without the flag. False: execute each plan as made, the block assumed still.
        seed: Seed of the expert's escape moves (when no push improves the block's pose).
        id: LeRobot's teleoperator id (``--teleop.id``); default ``pusht_expert``.
    """

    replan_every: int = 8
    max_step: float = 20.0
    follow_block: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        if self.id is None:
            self.id = "pusht_expert"
        if isinstance(self.replan_every, bool) or not isinstance(self.replan_every, int):
            raise ValueError(f"replan_every must be an integer >= 1, got {self.replan_every!r}")
        if self.replan_every < 1:
            raise ValueError(f"replan_every must be >= 1, got {self.replan_every}")
        if not isinstance(self.follow_block, bool):
            raise ValueError(f"follow_block must be true or false, got {self.follow_block!r}")
        if not self.max_step > 0:
            raise ValueError(f"max_step must be > 0 px, got {self.max_step}")
