"""``docs/FLAGS.md`` is the config's ``Args:`` docstrings rendered, and every config field has an entry."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.flags_doc import (
    field_docs,
    main,
    parse_args_section,
    render_flags_markdown,
    undocumented_fields,
)

ROOT = Path(__file__).resolve().parents[1]


def test_every_config_field_has_an_args_entry() -> None:
    docs = field_docs()
    assert undocumented_fields() == []
    for f in dataclasses.fields(DCDPConfig):
        assert docs[f.name].strip(), f.name


def test_flags_md_is_the_rendered_page() -> None:
    """Regenerate with ``python -m lerobot_dcdp.policy.flags_doc`` after changing an option or its Args:."""
    page = render_flags_markdown()
    assert (ROOT / "docs" / "FLAGS.md").read_text(encoding="utf-8") == page
    for f in dataclasses.fields(DCDPConfig):  # one row per field, with its default
        rows = [line for line in page.splitlines() if line.startswith(f"| `--policy.{f.name}` |")]
        assert len(rows) == 1, f.name
    assert "| `--policy.execution` | `str` | `dcdp` | `dcdp` (corrected chunks)" in page
    assert "| `--policy.planner_cpus` | `list[int] \\| None` | `null` |" in page


def test_a_field_without_an_args_entry_is_an_error() -> None:
    @dataclasses.dataclass
    class Extended(DCDPConfig):
        """A config with one field more.

        Args:
            documented: An option with its entry.
        """

        documented: int = 0
        forgotten: int = 0

    assert undocumented_fields(Extended) == ["forgotten"]
    with pytest.raises(ValueError, match=r"without an Args: entry .*\['forgotten'\]"):
        render_flags_markdown(Extended)


def test_args_sections_are_parsed_as_google_docstrings() -> None:
    doc = """Summary.

    Args:
        first: One line.
        second (int): Two
            lines.

    Returns:
        not_an_arg: ignored.

    Args:
        third: A second Args: section.
    """
    assert parse_args_section(doc) == {
        "first": "One line.",
        "second": "Two lines.",
        "third": "A second Args: section.",
    }


def test_check_and_write(tmp_path: Path) -> None:
    out = tmp_path / "FLAGS.md"
    assert main(["--out", str(out), "--check"]) == 1  # missing
    assert main(["--out", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == render_flags_markdown()
    assert main(["--out", str(out), "--check"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["FLAGS.md"]  # no temporary file left
