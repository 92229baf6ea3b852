"""Entry point found by LeRobot's plugin discovery: importing it registers the ``dcdp`` policy, its processor
steps, the ``pusht_perturbed`` env, the ``pusht_sim`` robot and the PushT teleoperators."""

import lerobot_dcdp.policy  # noqa: F401
import lerobot_dcdp.sim  # noqa: F401
