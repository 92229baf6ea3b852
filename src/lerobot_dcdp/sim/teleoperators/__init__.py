"""Teleoperators of the DCDP plugin: ``pusht_expert``, the scripted PushT expert that drives, and
``pusht_nudge``, a scripted person who corrects the robot's own command with the moving block."""

from lerobot_dcdp.sim.teleoperators.config_pusht_expert import PushTExpertConfig
from lerobot_dcdp.sim.teleoperators.config_pusht_nudge import PushTNudgeConfig
from lerobot_dcdp.sim.teleoperators.pusht_expert import PushTExpert
from lerobot_dcdp.sim.teleoperators.pusht_nudge import PushTNudge

__all__ = ["PushTExpert", "PushTExpertConfig", "PushTNudge", "PushTNudgeConfig"]
