"""Every flag of every argparse console script (``[project.scripts]`` in pyproject.toml) has a help line.

Each script's ``main([])`` runs until it parses: ``ArgumentParser.parse_args`` / ``parse_known_args`` raise
instead, carrying the parser the command built, whose actions are then read.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]


class _Parsed(Exception):
    """Raised instead of parsing: carries the parser the command built."""

    def __init__(self, parser: argparse.ArgumentParser) -> None:
        super().__init__(parser.prog)
        self.parser = parser


def _capture(self: argparse.ArgumentParser, *args, **kwargs):
    raise _Parsed(self)


def _track_creator(monkeypatch: pytest.MonkeyPatch) -> None:
    """Record on every new parser the module that built it (``argparse.ArgumentParser(...)`` called there;
    a subclass, e.g. draccus's, records its own module)."""
    original = argparse.ArgumentParser.__init__

    def init(self, *args, **kwargs) -> None:
        self.built_in = sys._getframe(1).f_globals.get("__name__", "")
        original(self, *args, **kwargs)

    monkeypatch.setattr(argparse.ArgumentParser, "__init__", init)


@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_every_flag_has_a_help_line(script: str, monkeypatch: pytest.MonkeyPatch) -> None:
    module_name, _, function = SCRIPTS[script].partition(":")
    main = getattr(importlib.import_module(module_name), function)
    if not inspect.signature(main).parameters:
        pytest.skip(f"{script}'s main takes no argv: its flags are a LeRobot (draccus) config, not argparse")
    _track_creator(monkeypatch)
    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", _capture)
    monkeypatch.setattr(argparse.ArgumentParser, "parse_known_args", _capture)
    with pytest.raises(_Parsed) as parsed:
        main([])
    parser = parsed.value.parser
    if not parser.built_in.startswith("lerobot_dcdp"):
        pytest.skip(f"{script} parses with a parser built in {parser.built_in}, not its own argparse")
    flags = [a for a in parser._actions if not isinstance(a, argparse._HelpAction)]
    assert flags, f"{script}: its parser has no flags"
    missing = [
        a.option_strings[0] if a.option_strings else a.dest for a in flags if not (a.help or "").strip()
    ]
    assert not missing, f"{script}: flags without a help line: {missing}"
