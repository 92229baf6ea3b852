"""Simulated PushT: the perturbed env, the simulated robot, teleoperators, the scripted expert.

Importing it registers the ``pusht_perturbed`` env, the ``pusht_sim`` robot and the ``pusht_expert`` /
``pusht_nudge`` teleoperators with LeRobot's config registries.
"""

from lerobot_dcdp.sim.envs.pusht_perturbed import PushTPerturbedEnvConfig  # noqa: F401
from lerobot_dcdp.sim.robots.config_pusht_sim import PushTSimConfig  # noqa: F401
from lerobot_dcdp.sim.teleoperators.config_pusht_expert import PushTExpertConfig  # noqa: F401
from lerobot_dcdp.sim.teleoperators.config_pusht_nudge import PushTNudgeConfig  # noqa: F401
