"""Old path of :mod:`lerobot_dcdp.policy.processor_split_state` (named in older served folders); re-exports
it."""

from lerobot_dcdp.policy.processor_split_state import *  # noqa: F401,F403
