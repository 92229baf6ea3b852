"""``docs/FLAGS.md``: every ``--policy.<name>`` flag of ``dcdp``, rendered from the config's ``Args:``.

Each field of :class:`~lerobot_dcdp.policy.configuration_dcdp.DCDPConfig` and of the classes it inherits
fields from (the option groups of :mod:`lerobot_dcdp.policy.config_options` and LeRobot's
``PreTrainedConfig``) gets one table row: flag, type, default and the description of its ``Args:`` entry.
An entry in a subclass's docstring wins over its parent's (``DCDPConfig`` says what LeRobot's own fields
mean for a corrector). A field without any ``Args:`` entry is an error, so the page cannot fall behind the
config.

Regenerate the page from the repository root with ``python -m lerobot_dcdp.policy.flags_doc`` (``--check``:
only report whether it is current).
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import inspect
import json
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

from lerobot_dcdp.policy.config_options import OPTION_GROUPS
from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig

#: Where the page lives, relative to the repository root.
FLAGS_PATH = Path("docs") / "FLAGS.md"
_ENTRY = re.compile(r"^(\w+)(?: \([^)]*\))?:\s?(.*)$")


def parse_args_section(doc: str | None) -> dict[str, str]:
    """The entries of every ``Args:`` section of a Google-style docstring.

    An entry starts at the section's first indentation with ``name:`` (or ``name (type):``); deeper
    indented lines continue it. A section ends at the first non-blank line indented no deeper than its
    ``Args:`` line.

    Args:
        doc: A docstring (``None``: no entries).

    Returns:
        Each documented name and its description, joined into one line.
    """
    entries: dict[str, str] = {}
    lines = inspect.cleandoc(doc or "").splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        i += 1
        if line.strip() != "Args:":
            continue
        header = len(line) - len(line.lstrip())
        entry_indent: int | None = None
        name: str | None = None
        while i < len(lines):
            line = lines[i]
            indent = len(line) - len(line.lstrip())
            if line.strip() and indent <= header:
                break
            i += 1
            if not line.strip():
                continue
            entry_indent = indent if entry_indent is None else entry_indent
            match = _ENTRY.match(line.strip()) if indent == entry_indent else None
            if match:
                name = match.group(1)
                entries[name] = match.group(2).strip()
            elif name is not None:
                entries[name] = f"{entries[name]} {line.strip()}".strip()
    return entries


def field_docs(config_class: type = DCDPConfig) -> dict[str, str]:
    """The ``Args:`` description of every documented field, a subclass's entry over its parent's.

    Args:
        config_class: The config dataclass.

    Returns:
        Field name to description, from the docstrings of ``config_class`` and every class it inherits.
    """
    docs: dict[str, str] = {}
    for cls in reversed(config_class.__mro__):
        docs.update(parse_args_section(cls.__dict__.get("__doc__")))
    return docs


def undocumented_fields(config_class: type = DCDPConfig) -> list[str]:
    """The fields of ``config_class`` that no ``Args:`` entry documents (empty when the page can render)."""
    docs = field_docs(config_class)
    return [f.name for f in dataclasses.fields(config_class) if f.name not in docs]


def _owner(config_class: type, name: str) -> type:
    """The class in ``config_class``'s MRO that declares field ``name`` (the most derived one)."""
    return next(c for c in config_class.__mro__ if name in c.__dict__.get("__annotations__", {}))


def _type_text(annotation: Any) -> str:
    """An annotation as written in the source, without module paths."""
    text = annotation.__name__ if isinstance(annotation, type) else str(annotation)
    return re.sub(r"\b(?:[a-z_][\w]*\.)+(\w+)", r"\1", text.replace("typing.", ""))


def _plain(value: Any) -> Any:
    """``value`` with enums, paths and tuples turned into what JSON (a saved ``config.json``) holds."""
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _default_text(f: dataclasses.Field) -> str:
    """The field's default as a flag value: strings bare, everything else as JSON."""
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "(required)"
    value = _plain(value)
    text = value if isinstance(value, str) and value else json.dumps(value)
    return f"`{text}`"


def _cell(text: str) -> str:
    """Docstring text as one Markdown table cell (RST ``code`` to Markdown, pipes escaped)."""
    return re.sub(r"``(.+?)``", r"`\1`", text).replace("|", "\\|")


def _sections(config_class: type) -> list[tuple[type, list[dataclasses.Field]]]:
    """The fields grouped by declaring class: the option groups in order, then the config's own, then the
    rest of its parents (LeRobot's)."""
    fields = dataclasses.fields(config_class)
    order = [*(g for g in OPTION_GROUPS if issubclass(config_class, g)), config_class]
    order += [c for c in config_class.__mro__ if c not in order and dataclasses.is_dataclass(c)]
    by_owner: dict[type, list[dataclasses.Field]] = {c: [] for c in order}
    for f in fields:
        by_owner.setdefault(_owner(config_class, f.name), []).append(f)
    return [(c, fs) for c, fs in by_owner.items() if fs]


def _title(cls: type, config_class: type) -> str:
    """A section's heading: the class name and its docstring's first sentence."""
    if cls is config_class:
        return f"`{cls.__name__}`: training (optimizer and scheduler presets) and normalisation"
    if cls not in OPTION_GROUPS:
        return f"`{cls.__name__}` (LeRobot's fields of every policy, as they apply to a corrector)"
    first = inspect.cleandoc(cls.__doc__ or "").split("\n\n")[0].replace("\n", " ")
    return f"`{cls.__name__}`: {first.rstrip('.')}"


def render_flags_markdown(config_class: type = DCDPConfig) -> str:
    """The Markdown page of every ``--policy.<name>`` flag of ``config_class``.

    Args:
        config_class: The config dataclass (``DCDPConfig``).

    Returns:
        The page: one table per declaring class with each field's flag, type, default and description.

    Raises:
        ValueError: A field has no ``Args:`` entry in the docstring of its class or of a subclass.
    """
    missing = undocumented_fields(config_class)
    if missing:
        raise ValueError(
            f"{config_class.__name__} fields without an Args: entry in any docstring of its classes: "
            f"{missing}; document each in the Args: of the class that declares it (or of a subclass)"
        )
    docs = field_docs(config_class)
    n = len(dataclasses.fields(config_class))
    out = [
        "# `--policy.*` flags of `dcdp`",
        "",
        "<!-- Generated by `python -m lerobot_dcdp.policy.flags_doc` from the `Args:` docstrings of "
        "`src/lerobot_dcdp/policy/configuration_dcdp.py` and `config_options.py`; do not edit by hand. -->",
        "",
        f"The {n} fields of `{config_class.__name__}`, as `lerobot-train`, `lerobot-eval` and "
        "`lerobot-rollout` take them (`--policy.<name>=<value>`) and a saved `config.json` holds them. "
        "Defaults are shown as a flag or `config.json` value (`null` is None).",
    ]
    for cls, fields in _sections(config_class):
        out += ["", f"## {_title(cls, config_class)}", ""]
        out += ["| flag | type | default | description |", "|---|---|---|---|"]
        for f in fields:
            out.append(
                f"| `--policy.{f.name}` | {_cell(f'`{_type_text(f.type)}`')} | {_cell(_default_text(f))} | "
                f"{_cell(docs[f.name])} |"
            )
    return "\n".join(out) + "\n"


def write_atomically(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` in one step (a temporary file in the same folder, then a rename); the
    file keeps its permissions (a new one gets the umask's)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        mode = path.stat().st_mode & 0o777
    else:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def main(argv: list[str] | None = None) -> int:
    """Write ``docs/FLAGS.md`` (or ``--out``); with ``--check`` only compare it. Returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, default=FLAGS_PATH, help="the page to write (default: %(default)s)"
    )
    parser.add_argument("--check", action="store_true", help="exit 1 if the page differs from the config")
    args = parser.parse_args(argv)
    text = render_flags_markdown()
    if args.check:
        current = args.out.read_text(encoding="utf-8") if args.out.is_file() else None
        if current != text:
            print(f"{args.out} is out of date: run python -m lerobot_dcdp.policy.flags_doc", file=sys.stderr)
            return 1
        return 0
    write_atomically(args.out, text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
