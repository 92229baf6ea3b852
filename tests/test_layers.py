"""The package's layering holds: `lint-imports` (import-linter) with the contract in pyproject.toml."""

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_layers_contract_is_kept():
    """Each layer imports only the layers below it (benchmark > train > deploy > data > sim > policy >
    runtime > model); the command exits non-zero on a broken contract."""
    lint = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run(
        [str(lint), "--config", str(REPO / "pyproject.toml")], capture_output=True, text=True, cwd=REPO
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "1 kept, 0 broken" in proc.stdout


def test_layers_contract_catches_an_upward_import(tmp_path):
    """The contract is live: a model module importing the sim layer breaks it."""
    import shutil

    pkg = tmp_path / "lerobot_dcdp"
    shutil.copytree(REPO / "src" / "lerobot_dcdp", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    with open(pkg / "model" / "correction.py", "a") as f:
        f.write("\nimport lerobot_dcdp.sim.pusht_geometry  # noqa: E402,F401\n")
    lint = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run(
        [str(lint), "--config", str(REPO / "pyproject.toml")],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode != 0
    assert "BROKEN" in proc.stdout or "broken" in proc.stdout
