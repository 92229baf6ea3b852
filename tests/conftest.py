"""Shared, session-scoped tiny fixtures: a recorded PushT dataset and random-init bases (all offline)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
os.environ.setdefault("HF_HUB_OFFLINE", "1")

BIN = Path(sys.executable).parent


@pytest.fixture(scope="session")
def demo_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two expert episodes (state + keypoints), recorded in-process by the project's recorder."""
    from lerobot_dcdp.pusht.demos import record_demonstrations

    root = tmp_path_factory.mktemp("demos") / "pusht"
    record_demonstrations(root, "local/test", episodes=2, seed=0, workers=1, progress=False)
    return root


@pytest.fixture(scope="session")
def diffusion_base(demo_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from helpers import make_tiny_base

    return make_tiny_base("diffusion", tmp_path_factory.mktemp("bases") / "diffusion", demo_root)


@pytest.fixture(scope="session")
def act_base(demo_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from helpers import make_tiny_base

    return make_tiny_base("act", tmp_path_factory.mktemp("bases") / "act", demo_root)
