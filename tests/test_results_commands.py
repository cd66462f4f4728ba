"""Every command recorded beside a committed result still reads as a `clamgen` command line.

Results under `results/` keep the exact command that produced them (the JSON's "command").
A reader copies it into a shell: the quoting must survive (a row name with spaces is one
argument) and every option must still exist. Each is parsed by the subcommand's own parser,
as `clamgen` would before running it; nothing is run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import shlex
import subprocess
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


POOL_SCRIPT = RESULTS / "stage2" / "ensemble" / "rebuild_pool.sh"
REBUILT_RUNS = (  # rebuild_pool.sh's options and seeds: the committed config of each run
    ((), (1, 2, 3, 4), "stage2/ensemble/rebuilt_pool/d3-seed{}"),
    (("--least-offset",), (1, 2, 3, 4), "stage2/ensemble/least_pool/d3-least-seed{}"),
    (("--previous-action",), (1, 2, 3, 4), "stage2/ensemble/prev_pool/d3-prev-seed{}"),
    (("--two-views",), (4,), "stage2/ensemble/rebuilt_pool/d2-seed{}"),
)


def test_the_pool_script_rebuilds_the_committed_runs(tmp_path):
    """Every DAgger run behind the shipped students' pools is made again by one script; each
    command it runs gives the committed run's config (settings added since at their defaults),
    the run directory aside. Nothing is trained: a stub stands in for `clamgen`."""
    from clamgen.experiments.config import config_from_json
    from clamgen.experiments.distill import DistillSettings
    from clamgen.experiments.stage2 import Stage2Config

    stub = tmp_path / "clamgen"
    stub.write_text('#!/bin/sh\necho "$@"\n')
    stub.chmod(0o755)
    env = {**os.environ, "CLAMGEN": str(stub), "RUN_ROOT": str(tmp_path / "runs")}
    for options, seeds, committed in REBUILT_RUNS:
        printed = subprocess.run(
            ["bash", str(POOL_SCRIPT), *options, *map(str, seeds)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.splitlines()
        assert len(printed) == len(seeds)
        for seed, line in zip(seeds, printed, strict=True):
            name, *argv = shlex.split(line)
            assert name == "distill"
            config = COMMANDS[name][0](argv)
            saved = json.loads((RESULTS / committed.format(seed) / "config.json").read_text())
            student = config_from_json(json.dumps(saved["student"]), Stage2Config)
            assert config.student == dataclasses.replace(student, run_dir=config.student.run_dir)
            assert config.distill == DistillSettings(**saved["distill"])
            assert config.student.run_dir.name == Path(committed.format(seed)).name
