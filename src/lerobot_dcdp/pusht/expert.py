"""Old path of :mod:`lerobot_dcdp.sim.pusht_expert` (named in stored results); re-exports it."""

from lerobot_dcdp.sim.pusht_expert import *  # noqa: F401,F403
from lerobot_dcdp.sim.pusht_expert import ExpertConfig, ScriptedExpert  # noqa: F401
