"""Environments of lerobot-dcdp: the ``pusht_perturbed`` LeRobot env type and its gymnasium wrapper."""

from lerobot_dcdp.sim.envs.pusht_perturbed import (
    DEFAULT_DIRECTIONS_DEG,
    GYM_ID,
    PERTURBATION_MODES,
    BlockPerturbation,
    PushTPerturbedEnvConfig,
    make_perturbed_env,
)

__all__ = [
    "DEFAULT_DIRECTIONS_DEG",
    "GYM_ID",
    "PERTURBATION_MODES",
    "BlockPerturbation",
    "PushTPerturbedEnvConfig",
    "make_perturbed_env",
]
