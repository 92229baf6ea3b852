"""What the benchmark's results record about what they ran: the machine, the git commit and a model
folder's scene lead (part of the identity its DCDP and gated cells are reused by)."""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path
from typing import Any

#: a folder's scene lead in its identity, with the value a cell recorded without it ran with (a cell without
#: a tolerance ran the median motion of the first scene lead; one without a noise, none)
LEAD_IDENTITY = {
    "lead_steps": 0,
    "lead_window": 0,
    "lead_state_feature": "observation.state",
    "lead_tolerance": None,
    "lead_repeats": None,
    "lead_noise": 0.0,
}


def machine() -> dict:
    """The CPU model, core count, torch threads and the Python, torch and platform versions."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import torch

    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "platform": platform.platform(),
    }


def git_commit() -> str:
    """``HEAD`` of the git checkout in the working directory, or ``unknown`` outside one."""
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def lead_identity(config: Any) -> dict:
    """A folder's scene lead as its cells record it (its DCDP and gated rows run with it; pure): every
    ``LEAD_IDENTITY`` key from ``config``, or nothing where it does not lead."""
    return {key: getattr(config, key) for key in LEAD_IDENTITY} if config.lead_steps else {}
