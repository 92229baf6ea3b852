"""LeRobot's face of DCDP: config, ``DCDPPolicy``, processors, folder I/O and base loading.

Importing it registers the ``dcdp`` policy type and the processor steps saved in correctors' pre-processors.
"""

from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.processor_check_observation import CheckObservationProcessorStep  # noqa: F401
from lerobot_dcdp.policy.processor_split_state import SplitStateProcessorStep  # noqa: F401
from lerobot_dcdp.policy.processor_state_history import StateHistoryProcessorStep  # noqa: F401

__all__ = ["DCDPConfig"]
