"""Teleoperators of the DCDP plugin: ``pusht_expert``, the scripted PushT expert as a LeRobot teleoperator."""

from lerobot_dcdp.teleoperators.config_pusht_expert import PushTExpertConfig
from lerobot_dcdp.teleoperators.pusht_expert import PushTExpert

__all__ = ["PushTExpert", "PushTExpertConfig"]
