"""Write a dataset folder so that a crash never loses both the old and the new copy.

Every writer of a LeRobotDataset here (demonstrations, recorded corrections, precomputed plans, FastUMI)
builds the new dataset in a private temporary folder beside its destination and moves it into place only when
complete: the old copy is first moved aside into that same private folder, the new one renamed into place, and
only then is the old one deleted (a failed rename puts the old one back). Each run touches its own temporary
folder only; a folder left by another run (live or killed) is never removed by this code.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def replace_dir(built: Path, out: Path, scratch: Path) -> None:
    """Move the complete folder ``built`` to ``out``; an existing ``out`` is parked in ``scratch`` (a folder
    of this run on the same filesystem) until the new one is in place, and restored if the move fails."""
    old = None
    if out.exists():
        old = scratch / "replaced"
        os.replace(out, old)
    try:
        os.replace(built, out)
    except BaseException:
        if old is not None:
            os.replace(old, out)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


@contextmanager
def staged_dir(out: str | Path) -> Iterator[Path]:
    """Yield a path (not yet existing) to build the new ``out`` in; on a clean exit it replaces ``out``
    (:func:`replace_dir`); on an exception ``out`` is left as it was. The private temporary folder, named
    ``.<name>.tmp-*`` beside ``out``, is removed either way."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        built = scratch / out.name
        yield built
        replace_dir(built, out, scratch)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
