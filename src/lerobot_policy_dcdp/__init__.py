"""Entry point found by LeRobot's plugin discovery: importing it registers the `dcdp` policy and env types."""

import lerobot_dcdp  # noqa: F401
