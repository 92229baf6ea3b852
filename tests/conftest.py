"""Shared, session-scoped tiny fixtures (all offline): recorded PushT datasets, random-init bases, and one
corrector trained by ``lerobot-train``. Session fixtures are shared by every test: copy a folder before
changing anything in it."""

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
    from lerobot_dcdp.data.pusht_demos import record_demonstrations

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


@pytest.fixture(scope="session")
def trained_corrector(
    diffusion_base: Path, demo_root: Path, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """The ``pretrained_model`` folder of a tiny corrector around ``diffusion_base``, trained once per session
    by a real 6-step ``lerobot-train`` run (the default residual recipe on synthesised block motion, with
    ``anchor_feature``): what the end-to-end tests evaluate, load and inspect. Read-only."""
    from helpers import train_corrector

    return train_corrector(diffusion_base, demo_root, tmp_path_factory.mktemp("trained_corrector") / "train")


@pytest.fixture(scope="session")
def image_demo_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One expert episode of image-only PushT demonstrations (``observation.image`` + agent position, no
    keypoints), ``local/img``, recorded once per session. Read-only."""
    from lerobot_dcdp.data.pusht_demos import record_demonstrations

    root = tmp_path_factory.mktemp("image_demos") / "img"
    record_demonstrations(root, "local/img", episodes=1, seed=3, images=True, keypoints=False, progress=False)
    return root
