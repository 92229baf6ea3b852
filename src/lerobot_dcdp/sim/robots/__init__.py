"""Robots of the DCDP plugin: ``pusht_sim``, a simulated PushT for ``lerobot-rollout``."""

from lerobot_dcdp.sim.robots.config_pusht_sim import PushTSimConfig
from lerobot_dcdp.sim.robots.pusht_sim import PushTSim

__all__ = ["PushTSim", "PushTSimConfig"]
