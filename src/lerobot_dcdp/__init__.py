"""DCDP for LeRobot: registers the ``dcdp`` policy type and the ``pusht_perturbed`` env type."""

from lerobot_dcdp.configuration_dcdp import DCDPConfig
from lerobot_dcdp.envs.pusht_perturbed import PushTPerturbedEnvConfig  # noqa: F401

__all__ = ["DCDPConfig"]
