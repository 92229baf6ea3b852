"""Old path of :mod:`lerobot_dcdp.policy.processor_state_history` (named in older served folders); re-exports
it."""

from lerobot_dcdp.policy.processor_state_history import *  # noqa: F401,F403
