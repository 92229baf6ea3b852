"""Configuration of the scripted PushT correcting person (``--teleop.type=pusht_nudge``)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.teleoperators.config import TeleoperatorConfig


@TeleoperatorConfig.register_subclass("pusht_nudge")
@dataclass
class PushTNudgeConfig(TeleoperatorConfig):
    """A stand-in for a person who *corrects* the robot rather than drives it
    (:mod:`lerobot_dcdp.sim.teleoperators.pusht_nudge`): the leader arm follows the robot's own command, and
    once
    the person sees the world moving the block, they carry that command with the block.

    Args:
        notice_speed: The block's speed (px/step) while the agent is away from it above which the person
            judges that the world, not the robot, moves the block, and starts carrying the robot's command.
            Below it (a still scene, a block coasting after a push) the command passes unchanged.
        contact_margin: Extra distance (px) beyond the agent's radius (15 px) within which the agent counts as
            touching the block; the block's motion is measured only on steps where the agent was farther than
            this from the T at this and the previous observation.
        smoothing: Weight (0, 1] of each new free-motion measurement in the person's running estimate of the
            block's own speed (an exponential average; 1 keeps only the latest).
        id: LeRobot's teleoperator id (``--teleop.id``); default ``pusht_nudge``.
    """

    notice_speed: float = 0.3
    contact_margin: float = 10.0
    smoothing: float = 0.3

    def __post_init__(self) -> None:
        if self.id is None:
            self.id = "pusht_nudge"
        if not self.notice_speed >= 0:
            raise ValueError(f"notice_speed must be >= 0 px/step, got {self.notice_speed}")
        if not self.contact_margin >= 0:
            raise ValueError(f"contact_margin must be >= 0 px, got {self.contact_margin}")
        if not 0 < self.smoothing <= 1:
            raise ValueError(f"smoothing must be in (0, 1], got {self.smoothing}")
