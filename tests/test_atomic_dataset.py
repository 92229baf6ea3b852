"""The shared atomic writer: the new folder is in place before the old one goes; others' temp folders stay."""

from __future__ import annotations

from pathlib import Path

import pytest

from lerobot_dcdp.data.atomic_dataset import staged_dir


def test_a_failed_build_leaves_the_old_copy_and_no_temp(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(RuntimeError, match="crash"), staged_dir(out) as built:
        built.mkdir()
        (built / "new.txt").write_text("half")
        raise RuntimeError("crash")
    assert (out / "old.txt").read_text() == "old" and not (out / "new.txt").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_a_complete_build_replaces_the_old_copy(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with staged_dir(out) as built:
        built.mkdir()
        (built / "new.txt").write_text("new")
        assert (out / "old.txt").exists()  # the old copy stays while the new one is built
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_another_runs_temp_folder_is_never_touched(tmp_path: Path) -> None:
    other = tmp_path / ".ds.tmp-live"  # a concurrent (or killed) run's private folder
    other.mkdir()
    (other / "work.txt").write_text("theirs")
    with staged_dir(tmp_path / "ds") as built:
        built.mkdir()
    assert (other / "work.txt").read_text() == "theirs"
    assert (tmp_path / "ds").is_dir()
