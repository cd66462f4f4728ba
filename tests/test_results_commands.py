"""Every command recorded beside a committed result still reads as a `clamgen` command line.

Results under `results/` keep the exact command that produced them (the JSON's "command").
A reader copies it into a shell: the quoting must survive (a row name with spaces is one
argument) and every option must still exist. Each is parsed by the subcommand's own parser,
as `clamgen` would before running it; nothing is run.
"""

from __future__ import annotations

import contextlib
import io
import json
import shlex
from pathlib import Path

import pytest

from clamgen.cli import COMMANDS

RESULTS = Path(__file__).resolve().parent.parent / "results"


def recorded_commands() -> list[tuple[str, str]]:
    """(file relative to results/, command) of every JSON object there with a "command" that
    runs `clamgen`."""
    found = []
    for path in sorted(RESULTS.rglob("*.json")):
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue
        command = data.get("command") if isinstance(data, dict) else None
        if isinstance(command, str) and command.startswith("clamgen "):
            found.append((str(path.relative_to(RESULTS)), command))
    return found


def test_there_are_recorded_commands():
    assert len(recorded_commands()) > 100


def test_every_recorded_command_parses():
    unreadable = []
    for where, command in recorded_commands():
        try:
            name, *rest = shlex.split(command)[1:]
        except ValueError as error:  # e.g. an unclosed quote
            unreadable.append(f"{where}: {error}")
            continue
        if name not in COMMANDS:
            unreadable.append(f"{where}: no subcommand {name!r}")
            continue
        output = io.StringIO()
        try:
            with contextlib.redirect_stdout(output), contextlib.redirect_stderr(output):
                COMMANDS[name][0](rest)
        except SystemExit as stop:  # tyro's usage errors, the CLI's own checks
            unreadable.append(f"{where}: exit {stop.code}: {output.getvalue()[-300:]}")
        except ValueError as error:  # a config class's own check of a value
            unreadable.append(f"{where}: {error}")
    assert not unreadable, "\n".join(unreadable)


def test_an_unquoted_row_name_is_caught():
    # How 36 commands had been recorded: the row name's words as separate arguments.
    name, *rest = shlex.split("clamgen eval --table 2 --policy ik --name two words")[1:]
    with contextlib.redirect_stderr(io.StringIO()), pytest.raises(SystemExit):
        COMMANDS[name][0](rest)
