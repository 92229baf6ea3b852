"""DCDP for LeRobot: registers the `dcdp` policy, the `pusht_perturbed` env, the `pusht_sim` robot, the
`pusht_expert` teleoperator and the `dcdp_split_state` processor step (saved in the correctors'
pre-processors)."""

from lerobot_dcdp.configuration_dcdp import DCDPConfig
from lerobot_dcdp.envs.pusht_perturbed import PushTPerturbedEnvConfig  # noqa: F401
from lerobot_dcdp.processor_split_state import SplitStateProcessorStep  # noqa: F401
from lerobot_dcdp.robots.config_pusht_sim import PushTSimConfig  # noqa: F401
from lerobot_dcdp.teleoperators.config_pusht_expert import PushTExpertConfig  # noqa: F401

__all__ = ["DCDPConfig"]
