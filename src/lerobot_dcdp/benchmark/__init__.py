"""The paper's PushT experiment: rollouts of every execution mode, latency, tables, plots, videos."""

from pathlib import Path

#: Where the shipped correctors and bases are: ``$DCDP_MODELS``, else the ``models/`` folder of the source
#: checkout this package runs from (an editable install), else ``models/`` under the working directory.
MODELS_ENV = "DCDP_MODELS"


def shipped_model(name: str) -> str:
    """Path of the shipped checkpoint ``name`` (see :data:`MODELS_ENV`), so the defaults of the benchmark
    commands work from any working directory of a source checkout."""
    import os

    if os.environ.get(MODELS_ENV):
        return str(Path(os.environ[MODELS_ENV]) / name)
    checkout = Path(__file__).resolve().parents[3] / "models"
    return str(checkout / name) if checkout.is_dir() else str(Path("models") / name)
