"""`clamgen sweep SPEC.toml`: a grid of training runs (rows x presets x seeds) and then their
evaluations, on Ray, resumable, with one summary file that `clamgen report` reads.

Design: every run is a Ray task (one CPU) that starts the `clamgen` CLI as a subprocess:
`clamgen train|train-residual ... --run-dir RUN --loop.seed S --loop.torch-threads 1`, then
`clamgen eval --policy RUN/policy.pt --out RUN/eval ...`. A subprocess rather than training in
the Ray worker, because
- it is kill-safe: the trainers already checkpoint so that a kill at any instant loses only the
  steps since the last checkpoint, and a killed sweep (or a lost Ray node) leaves nothing
  half-held in a worker; the subprocess dies with its worker (`PR_SET_PDEATHSIG` on Linux), and
  a lock file held by it keeps a second sweep off a run that is still going;
- each run gets a fresh interpreter with one torch/OpenMP thread, whatever the worker imported;
- what runs is exactly the command written into the summary, so any run can be repeated by hand;
- resuming is the trainers' own: running the same training command on a run directory that has
  a checkpoint continues from it.
A run is finished when its policy file and its evaluation result exist; running the same sweep
again skips finished runs, evaluates trained ones, resumes interrupted ones and retries failed
ones. A run finished on another machine (its directory absent here) whose record in the
committed summary is done, with test scores, under exactly the commands the spec gives now, is
kept from that record instead of trained again. Locally (default) Ray gets as many CPUs as the
machine has, or `--max-concurrent`; with `--address` the same runs go to an existing cluster
(run directories must then be on a file system every node sees).

The spec (TOML; paths relative to the current directory):

    name = "table2"                          # default: the file's stem
    run_root = "runs/sweeps/table2"          # RUN = run_root/<row>/seed<S>
    summary = "results/sweeps/table2.json"   # default: run_root/summary.json
    command = "train-residual"               # or "train", "distill"; rows may override
    presets = ["residual-cpu"]               # names or .toml paths; rows may override
    seeds = [0, 1, 2]                        # training loop seeds; rows may override
    flags = ["--loop.total-env-steps", "60000"]   # CLI flags for every run
    set = {"loop.eval_every_steps" = 5000}        # the same as a dict of config fields

    [eval]                                   # the evaluation after training
    table = 2                                # `clamgen eval --table N`
    flags = ["--num-tasks", "200"]

    [[overrides]]                            # one table row each (default: one, unchanged)
    name = "no residual (2 views)"           # the row's name in tables and figures
    flags = ["--agent.no-residual"]          # and/or: set = {"agent.residual" = false}
    compare_to = "CLAMGen, 2 RGBD views"     # report P(that row > this row)
    seeds = [0, 1, 2, 3, 4]                  # optional per-row command/presets/seeds/eval too
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import datetime
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
import tomllib
import typing
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

INSTALL_HINT = "Ray is not installed: pip install 'clamgen[sweep]' (or: pip install ray)"
COMMANDS = ("train", "train-residual", "distill")
# The flag that sets a run's training seed, per command (distillation has its own loop).
SEED_FLAGS = {"train": "--loop.seed", "train-residual": "--loop.seed", "distill": "--distill.seed"}
# What a finished distillation leaves (its policy file is written after every iteration).
DISTILL_SUMMARY = "summary.json"
POLICY_FILE = "policy.pt"
EVAL_STEM = "eval"
LOCK_FILE = ".sweep.lock"
VALIDATION_METRIC = "eval/success_rate"
# Flags the sweep sets itself for every run; a spec may not set them.
RESERVED_TRAIN_FLAGS = (
    "--run-dir",
    "--loop.seed",
    "--distill.seed",
    "--preset",
    "--loop.torch-threads",
)
RESERVED_EVAL_FLAGS = ("--policy", "--out", "--name", "--table")
SPEC_KEYS = {"name", "run_root", "summary", "command", "presets", "seeds", "flags", "set"}
SPEC_KEYS |= {"eval", "overrides"}
ROW_KEYS = {"name", "command", "presets", "seeds", "flags", "set", "eval", "compare_to"}
EVAL_KEYS = {"table", "flags"}
# On Ctrl-C a run's trainer gets SIGINT (it writes a checkpoint at once) and this long to exit.
INTERRUPT_GRACE_S = 120.0


class SpecError(ValueError):
    """A sweep spec that cannot be run; the message is one line."""


@dataclass(frozen=True)
class SweepConfig:
    """Run a grid of training runs and their evaluations on Ray (resumable)."""

    spec: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="SPEC.toml")]
    """The sweep spec (TOML): command, presets, overrides, seeds, run root, evaluation."""
    address: str | None = None
    """Address of an existing Ray cluster (`ray start --head` prints it; `auto` finds a local
    one). Default: start Ray on this machine for the sweep's duration."""
    max_concurrent: int | None = None
    """Runs at once (default: every CPU Ray has, each run on one torch thread)."""
    progress_every_s: float = 30.0
    """Seconds between progress lines (runs done / running / failed, validation success)."""
    dry_run: bool = False
    """Print the plan and every command without running anything."""
    keep_checkpoints: bool = False
    """Keep a finished run's training checkpoints (its replay buffer: over 1 GB for an image
    run). By default they are deleted once the run is trained and evaluated: a sweep of a
    few dozen image runs would otherwise fill the disk, and a finished run is never resumed
    (its policy, config, metrics and evaluation stay)."""


# ------------------------------------------------------------------------------ spec
@dataclass(frozen=True)
class RowSpec:
    """One row of the grid: a named set of overrides, trained on every preset x seed."""

    name: str
    command: str
    presets: tuple[str, ...]
    seeds: tuple[int, ...]
    flags: tuple[str, ...]
    """Training CLI flags (the spec's common flags, then the row's)."""
    eval_table: int
    eval_flags: tuple[str, ...]
    compare_to: str | None = None


@dataclass(frozen=True)
class SweepSpec:
    name: str
    path: Path
    run_root: Path
    summary_path: Path
    rows: tuple[RowSpec, ...]
    text: str


@dataclass(frozen=True)
class Run:
    """One training run and its evaluation."""

    id: str
    row: str
    preset: str
    seed: int
    command: str
    run_dir: Path
    train_args: tuple[str, ...]
    """Arguments after `clamgen`."""
    eval_args: tuple[str, ...]
    table: int

    @property
    def policy_path(self) -> Path:
        return self.run_dir / POLICY_FILE

    @property
    def eval_json(self) -> Path:
        return self.run_dir / f"{EVAL_STEM}.json"

    @property
    def trained(self) -> bool:
        if self.command == "distill":  # its policy file exists after the first iteration
            return (self.run_dir / DISTILL_SUMMARY).is_file() and self.policy_path.is_file()
        return self.policy_path.is_file()

    @property
    def finished(self) -> bool:
        return self.trained and self.eval_json.is_file()

    @property
    def has_checkpoint(self) -> bool:
        checkpoints = self.run_dir / "checkpoints"
        if self.command == "distill":
            from clamgen.experiments.distill import STATE_NAME

            return (self.run_dir / STATE_NAME).is_file()
        return checkpoints.is_dir() and any(checkpoints.iterdir())


def _fail(where: str, message: str) -> typing.NoReturn:
    raise SpecError(f"{where}: {message}")


def _str_list(value: Any, where: str, key: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = shlex.split(value)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        _fail(where, f"{key} must be a list of strings (CLI flags), got {value!r}")
    return tuple(value)


def _seeds(value: Any, where: str) -> tuple[int, ...]:
    from clamgen.experiments.config import check_training_seed

    if not isinstance(value, list) or not value:
        _fail(where, f"seeds must be a non-empty list of integers, got {value!r}")
    for seed in value:
        if isinstance(seed, bool) or not isinstance(seed, int):
            _fail(where, f"seeds must be integers, got {seed!r}")
        try:
            check_training_seed(seed)
        except ValueError as error:
            _fail(where, str(error))
    if len(set(value)) != len(value):
        _fail(where, f"seeds repeat: {value}")
    return tuple(value)


def _config_class(command: str) -> type:
    if command == "train":
        from clamgen.experiments.config import TrainConfig

        return TrainConfig
    from clamgen.experiments.stage2 import Stage2Config

    return Stage2Config


def _field_type(cls: type, dotted: str, where: str, shown: str | None = None) -> Any:
    """The type of config field `dotted` (e.g. `agent.encoder.num_views`) of `cls`; errors
    name it `shown` (default: `dotted`)."""
    shown = shown or dotted
    hint: Any = cls
    for part in dotted.split("."):
        if not dataclasses.is_dataclass(hint):
            _fail(where, f"{shown!r} is not a field of {cls.__name__} ({part!r} has no fields)")
        fields = {f.name for f in dataclasses.fields(hint)}
        name = part.replace("-", "_")
        if name not in fields:
            _fail(
                where,
                f"{shown!r} is not a field of {cls.__name__}: {hint.__name__} has "
                f"{', '.join(sorted(fields))}",
            )
        hint = typing.get_type_hints(hint)[name]
    return hint


def overrides_to_flags(overrides: Any, command: str, where: str) -> tuple[str, ...]:
    """CLI flags for a dict of config fields: `{"env.num_views": 3}` -> `--env.num-views 3`,
    booleans as `--agent.residual` / `--agent.no-residual`, lists as several values."""
    if not isinstance(overrides, dict):
        _fail(where, f"set must be a table of config fields, got {overrides!r}")
    flags: list[str] = []
    for key, value in overrides.items():
        if command == "distill" and key.startswith("distill."):
            from clamgen.experiments.distill import DistillSettings

            hint = _field_type(DistillSettings, key.removeprefix("distill."), where, key)
        else:
            hint = _field_type(_config_class(command), key, where)
        *parents, last = key.replace("_", "-").split(".")
        prefix = "--" + "".join(p + "." for p in parents)
        if prefix + last in RESERVED_TRAIN_FLAGS:
            _fail(where, f"{key!r} is set by the sweep itself")
        if dataclasses.is_dataclass(hint) or isinstance(value, dict):
            _fail(where, f"{key!r} takes a nested value; set its fields one by one, or use flags")
        if isinstance(value, bool):
            flags.append(prefix + ("" if value else "no-") + last)
        elif isinstance(value, list):
            flags += [prefix + last, *map(str, value)]
        else:
            flags += [prefix + last, str(value)]
    return tuple(flags)


def _check_flags(flags: Iterable[str], reserved: tuple[str, ...], where: str) -> None:
    for flag in flags:
        if flag.split("=")[0] in reserved:
            _fail(where, f"{flag.split('=')[0]} is set by the sweep itself; remove it")


def _eval_section(value: Any, where: str, default: tuple[int, tuple[str, ...]] | None):
    if value is None:
        if default is None:
            _fail(where, "needs an [eval] table with `table = 1` or `table = 2`")
        return default
    if not isinstance(value, dict):
        _fail(where, f"eval must be a table, got {value!r}")
    unknown = set(value) - EVAL_KEYS
    if unknown:
        _fail(where, f"unknown eval keys {sorted(unknown)}; known: {sorted(EVAL_KEYS)}")
    table = value.get("table", default[0] if default else None)
    if table not in (1, 2):
        _fail(where, f"eval.table must be 1 or 2, got {table!r}")
    flags = _str_list(value.get("flags", []), where, "eval.flags")
    _check_flags(flags, RESERVED_EVAL_FLAGS, where)
    return table, flags


def load_spec(path: Path) -> SweepSpec:
    """Parse and check a sweep spec; a `SpecError` with a one-line message if it is bad."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise SpecError(f"cannot read sweep spec {path}: {error.strerror}") from error
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise SpecError(f"{path}: not valid TOML: {error}") from error
    where = str(path)
    unknown = set(data) - SPEC_KEYS
    if unknown:
        _fail(where, f"unknown keys {sorted(unknown)}; known: {sorted(SPEC_KEYS)}")
    name = data.get("name", path.stem)
    if "run_root" not in data:
        _fail(where, "needs run_root (the directory the runs go in)")
    run_root = Path(data["run_root"])
    summary_path = Path(data.get("summary", run_root / "summary.json"))
    common_flags = _str_list(data.get("flags", []), where, "flags")
    overrides = data.get("overrides", [{}])
    if not isinstance(overrides, list) or not overrides:
        _fail(where, "overrides must be a non-empty array of tables ([[overrides]])")
    default_eval = _eval_section(data.get("eval"), where, None) if "eval" in data else None
    rows = []
    for i, row in enumerate(overrides):
        row_where = f"{where} overrides[{i}]"
        if not isinstance(row, dict):
            _fail(row_where, f"must be a table, got {row!r}")
        unknown = set(row) - ROW_KEYS
        if unknown:
            _fail(row_where, f"unknown keys {sorted(unknown)}; known: {sorted(ROW_KEYS)}")
        command = row.get("command", data.get("command"))
        if command not in COMMANDS:
            _fail(row_where, f"command must be one of {COMMANDS}, got {command!r}")
        presets = row.get("presets", data.get("presets"))
        if isinstance(presets, str):
            presets = [presets]
        if (
            not isinstance(presets, list)
            or not presets
            or not all(isinstance(p, str) for p in presets)
        ):
            _fail(row_where, f"presets must be a non-empty list of names, got {presets!r}")
        from clamgen.experiments.config import resolve_preset

        for preset in presets:
            try:
                resolve_preset(preset)
            except FileNotFoundError as error:
                _fail(row_where, str(error))
        seeds = _seeds(row.get("seeds", data.get("seeds")), row_where)
        flags = common_flags + overrides_to_flags(data.get("set", {}), command, where)
        flags += _str_list(row.get("flags", []), row_where, "flags")
        flags += overrides_to_flags(row.get("set", {}), command, row_where)
        _check_flags(flags, RESERVED_TRAIN_FLAGS, row_where)
        table, eval_flags = _eval_section(row.get("eval"), row_where, default_eval)
        row_name = row.get("name", presets[0] if len(overrides) == 1 else None)
        if not isinstance(row_name, str) or not row_name.strip():
            _fail(row_where, "needs a name (the row's name in tables and figures)")
        compare_to = row.get("compare_to")
        rows.append(
            RowSpec(row_name, command, tuple(presets), seeds, flags, table, eval_flags, compare_to)
        )
    names = [r.name for r in rows]
    for row in rows:
        if names.count(row.name) > 1:
            _fail(where, f"row name {row.name!r} appears twice")
        if row.compare_to is not None and row.compare_to not in names:
            _fail(where, f"{row.name!r}: compare_to {row.compare_to!r} is not a row of the sweep")
    return SweepSpec(name, path, run_root, summary_path, tuple(rows), text)


def slug(name: str) -> str:
    """A directory name for a row name: `CLAMGen, 2 RGBD views` -> `clamgen-2-rgbd-views`."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "row"


def plan_runs(spec: SweepSpec) -> list[Run]:
    """Every run of the spec, rows x presets x seeds, in that order."""
    runs = []
    for row in spec.rows:
        for preset in row.presets:
            label = row.name if len(row.presets) == 1 else f"{row.name} ({Path(preset).stem})"
            for seed in row.seeds:
                run_id = f"{slug(label)}/seed{seed}"
                run_dir = spec.run_root / run_id
                train_args = (
                    row.command,
                    "--preset",
                    preset,
                    *row.flags,
                    SEED_FLAGS[row.command],
                    str(seed),
                    "--loop.torch-threads",
                    "1",
                    "--run-dir",
                    str(run_dir),
                )
                eval_args = (
                    "eval",
                    "--table",
                    str(row.eval_table),
                    "--policy",
                    str(run_dir / POLICY_FILE),
                    "--out",
                    str(run_dir / EVAL_STEM),
                    *(("--name", label) if row.eval_table == 2 else ()),
                    *row.eval_flags,
                )
                runs.append(
                    Run(run_id, label, preset, seed, row.command, run_dir, train_args,
                        eval_args, row.eval_table)
                )  # fmt: skip
    ids = [r.id for r in runs]
    if len(set(ids)) != len(ids):
        duplicate = next(i for i in ids if ids.count(i) > 1)
        raise SpecError(f"{spec.path}: two rows share the run directory {duplicate!r}; rename one")
    return runs


# ---------------------------------------------------------------------- run results
def read_validation(run_dir: Path) -> tuple[list[int], list[float]]:
    """The run's validation success against env steps, from `metrics.csv` (empty if none yet;
    a half-written last line of a running run is skipped)."""
    path = Path(run_dir) / "metrics.csv"
    steps: list[int] = []
    values: list[float] = []
    if not path.is_file():
        return steps, values
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            if row.get("metric") != VALIDATION_METRIC:
                continue
            try:
                step, value = int(row["step"]), float(row["value"])
            except (TypeError, ValueError):
                continue
            if steps and step <= steps[-1]:  # a resumed run logs each step once; be safe
                continue
            steps.append(step)
            values.append(value)
    return steps, values


def eval_scores(eval_json: Path) -> dict[str, Any]:
    """Test-task success of an evaluation result: `{"table", "observation", "scores"}` with one
    success rate per condition (Table 1: target speed label; Table 2: task family)."""
    data = json.loads(Path(eval_json).read_text())
    rows = data["rows"]
    if rows and "speed" in rows[0]:
        scores = {_speed_label(r["speed"]): r["success_rate"] for r in rows}
        return {"table": 1, "observation": data.get("observation", "joints"), "scores": scores}
    return {
        "table": 2,
        "observation": "images",
        "scores": {r.get("family", "obstacles"): r["success_rate"] for r in rows},
    }


def _speed_label(speed: Any) -> str:
    return "variable" if speed == "variable" else f"{float(speed):g}"


# ------------------------------------------------------------------------ execution
def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Ask Linux to SIGKILL this process when the Ray worker that started it dies."""
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


def _run_cli(args: tuple[str, ...], log: Path, lock_fd: int) -> int:
    """Run `clamgen ARGS` with one thread, output appended to `log`; the subprocess holds the
    run's lock too. Ctrl-C / `ray.cancel` sends it SIGINT (the trainers checkpoint on it)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    env.setdefault("MUJOCO_GL", "egl")
    with log.open("a") as out:
        out.write(f"\n$ clamgen {shlex.join(args)}  # {datetime.datetime.now():%F %T}\n")
        out.flush()
        child = subprocess.Popen(
            [sys.executable, "-m", "clamgen.cli", *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            pass_fds=(lock_fd,),
            preexec_fn=_die_with_parent if sys.platform == "linux" else None,
        )
        try:
            return child.wait()
        except BaseException:
            child.send_signal(signal.SIGINT)
            try:
                child.wait(INTERRUPT_GRACE_S)
            except subprocess.TimeoutExpired:
                child.kill()
            raise


def _last_line(log: Path) -> str:
    lines = [line.strip() for line in log.read_text(errors="replace").splitlines() if line.strip()]
    return lines[-1][-300:] if lines else "(no output)"


def execute_run(run: Run, keep_checkpoints: bool = False) -> dict[str, Any]:
    """Train (or resume) and evaluate one run, each as a `clamgen` subprocess; returns the
    run's status. Unless `keep_checkpoints`, a run that is done loses its training
    checkpoints. Runs inside a Ray task, or directly."""
    import fcntl

    run.run_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with (run.run_dir / LOCK_FILE).open("w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return {"status": "failed", "error": "another process is running this run"}
        resumed = run.has_checkpoint and not run.trained
        if not run.trained:
            log = run.run_dir / "train.log"
            if _run_cli(run.train_args, log, lock.fileno()) != 0 or not run.trained:
                return {"status": "failed", "error": f"training: {_last_line(log)}"}
        if not run.eval_json.is_file():
            log = run.run_dir / "eval.log"
            if _run_cli(run.eval_args, log, lock.fileno()) != 0 or not run.eval_json.is_file():
                return {"status": "failed", "error": f"evaluation: {_last_line(log)}"}
        if not keep_checkpoints:
            shutil.rmtree(run.run_dir / "checkpoints", ignore_errors=True)
    return {"status": "done", "resumed": resumed, "seconds": time.perf_counter() - start}


def _import_ray():
    try:
        import ray
    except ImportError as error:
        raise SystemExit(INSTALL_HINT) from error
    return ray


# -------------------------------------------------------------------------- summary
def run_record(run: Run, status: str, error: str | None = None) -> dict[str, Any]:
    """What the summary keeps of a run: commands, status, validation curve, test scores."""
    steps, values = read_validation(run.run_dir)
    record: dict[str, Any] = {
        "id": run.id,
        "row": run.row,
        "preset": run.preset,
        "seed": run.seed,
        "run_dir": str(run.run_dir),
        "train_command": "clamgen " + shlex.join(run.train_args),
        "eval_command": "clamgen " + shlex.join(run.eval_args),
        "status": status,
        "train_env": _train_env(run.run_dir),
        "validation": {"steps": steps, "success_rate": values},
        "test": None,
    }
    if error:
        record["error"] = error
    if run.eval_json.is_file():
        record["eval_json"] = str(run.eval_json)
        record["test"] = eval_scores(run.eval_json)
    return record


def _train_env(run_dir: Path) -> str | None:
    """The env id the run trains (and validates) on, from its `config.json` (a distillation's
    under its student's settings)."""
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        config = json.loads((Path(run_dir) / "config.json").read_text())
        return config.get("student", config)["env"]["env_id"]
    return None


def recorded_runs(spec: SweepSpec, runs: list[Run]) -> dict[str, dict[str, Any]]:
    """Runs finished elsewhere, by id: the records of the spec's existing summary that are done
    with test scores, whose run directory does not exist here, and whose training and
    evaluation commands are exactly those the spec gives now (a changed spec trains again)."""
    try:
        previous = json.loads(spec.summary_path.read_text())
    except (OSError, ValueError):
        return {}
    by_id = {r.get("id"): r for r in previous.get("runs", []) if isinstance(r, dict)}
    kept = {}
    for run in runs:
        record = by_id.get(run.id)
        if (
            record is not None
            and record.get("status") == "done"
            and record.get("test")
            and not run.run_dir.exists()
            and record.get("train_command") == "clamgen " + shlex.join(run.train_args)
            and record.get("eval_command") == "clamgen " + shlex.join(run.eval_args)
        ):
            kept[run.id] = record
    return kept


def write_summary(
    spec: SweepSpec,
    runs: list[Run],
    statuses: dict[str, dict],
    write: bool = True,
    kept: dict[str, dict[str, Any]] | None = None,
) -> dict:
    """The sweep's summary, with the `kept` records of runs finished elsewhere as they were;
    written (atomically) to `spec.summary_path` unless `write` is False."""
    kept = kept or {}
    records = [kept.get(r.id) or run_record(r, **statuses[r.id]) for r in runs]
    counts = {s: sum(r["status"] == s for r in records) for s in ("done", "running", "failed")}
    counts["queued"] = len(records) - sum(counts.values())
    summary = {
        "kind": "clamgen-sweep",
        "name": spec.name,
        "spec": str(spec.path),
        "spec_text": spec.text,
        "command": f"clamgen sweep {spec.path}",
        "updated": datetime.datetime.now().isoformat(timespec="seconds"),
        "counts": counts,
        "rows": [
            {
                "name": row.name,
                "command": row.command,
                "presets": list(row.presets),
                "seeds": list(row.seeds),
                "table": row.eval_table,
                "compare_to": row.compare_to,
            }
            for row in spec.rows
        ],
        "runs": records,
    }
    if not write:
        return summary
    spec.summary_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = spec.summary_path.with_name(spec.summary_path.name + ".tmp")
    tmp.write_text(json.dumps(summary, indent=1))
    tmp.replace(spec.summary_path)
    return summary


def _latest(run: Run) -> str:
    steps, values = read_validation(run.run_dir)
    return (
        f"step {steps[-1]}, validation success {values[-1]:.2f}" if steps else "no evaluation yet"
    )


def _progress(spec: SweepSpec, runs: list[Run], statuses: dict, running: list[Run]) -> None:
    counts = {s: sum(v["status"] == s for v in statuses.values()) for s in ("done", "failed")}
    queued = len(runs) - counts["done"] - counts["failed"] - len(running)
    print(
        f"[{datetime.datetime.now():%H:%M:%S}] sweep {spec.name}: {counts['done']}/{len(runs)} "
        f"done, {len(running)} running, {counts['failed']} failed, {queued} queued",
        flush=True,
    )
    for run in running:
        print(f"  running {run.id}: {_latest(run)}", flush=True)


# ------------------------------------------------------------------------------ main
def run_sweep(config: SweepConfig) -> dict:
    """Run every unfinished run of the spec and write the summary; returns it."""
    spec = load_spec(config.spec)
    if config.max_concurrent is not None and config.max_concurrent < 1:
        raise SpecError(f"--max-concurrent must be >= 1, got {config.max_concurrent}")
    runs = plan_runs(spec)
    kept = recorded_runs(spec, runs)
    statuses: dict[str, dict] = {r.id: {"status": "queued"} for r in runs}
    todo = []
    for run in runs:
        if run.finished or run.id in kept:
            statuses[run.id] = {"status": "done"}
        else:
            todo.append(run)
    resuming = sum(r.has_checkpoint and not r.trained for r in todo)
    to_evaluate = sum(r.trained for r in todo)
    print(
        f"sweep {spec.name}: {len(runs)} runs in {spec.run_root}; {len(runs) - len(todo)} "
        f"finished (skipped; {len(kept)} of them recorded in {spec.summary_path}), {resuming} "
        f"to resume from checkpoints, {to_evaluate} to evaluate only, "
        f"{len(todo) - resuming - to_evaluate} new"
    )
    if config.dry_run:
        for run in todo:
            print(f"{run.id}:\n  clamgen {shlex.join(run.train_args)}")
            print(f"  clamgen {shlex.join(run.eval_args)}")
        return write_summary(spec, runs, statuses, write=False, kept=kept)
    if not todo:
        summary = write_summary(spec, runs, statuses, kept=kept)
        print(f"nothing to do; summary: {spec.summary_path}")
        return summary
    ray = _import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        try:
            _init_ray(ray, config)
        except Exception as error:  # Ray raises plain Exceptions for startup failures
            where = f"the Ray cluster at {config.address}" if config.address else "local Ray"
            first_line = str(error).strip().splitlines()[0] if str(error).strip() else ""
            raise SystemExit(
                f"could not start {where}: {type(error).__name__}: {first_line} "
                "(on a heavily loaded machine Ray's 30 s startup can time out; run again)"
            ) from error
    limit = config.max_concurrent or max(1, int(ray.cluster_resources().get("CPU", 1)))
    # One CPU per run; a lost worker is retried, which resumes from the checkpoint.
    remote = ray.remote(num_cpus=1, max_retries=2)(execute_run)
    pending: dict[Any, Run] = {}
    last_progress = 0.0
    try:
        while todo or pending:
            while todo and len(pending) < limit:
                run = todo.pop(0)
                pending[remote.remote(run, config.keep_checkpoints)] = run
                statuses[run.id] = {"status": "running"}
            write_summary(spec, runs, statuses, kept=kept)
            if time.monotonic() - last_progress >= config.progress_every_s:
                _progress(spec, runs, statuses, list(pending.values()))
                last_progress = time.monotonic()
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=config.progress_every_s)
            for ref in ready:
                run = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as error:  # a Ray failure: worker lost, task error
                    result = {"status": "failed", "error": f"{type(error).__name__}: {error}"}
                statuses[run.id] = {"status": result["status"], "error": result.get("error")}
                how = " (resumed from its checkpoint)" if result.get("resumed") else ""
                detail = result.get("error") or _latest(run)
                print(f"  {result['status']} {run.id}{how}: {detail}", flush=True)
    except KeyboardInterrupt:
        print(f"\ninterrupted: stopping {len(pending)} runs (each writes a checkpoint) ...")
        for ref in pending:
            ray.cancel(ref)
        ray.wait(list(pending), num_returns=len(pending), timeout=INTERRUPT_GRACE_S)
        for run in pending.values():
            statuses[run.id] = {"status": "queued"}
        write_summary(spec, runs, statuses, kept=kept)
        raise SystemExit(
            f"sweep interrupted; run `clamgen sweep {spec.path}` again to resume"
        ) from None
    finally:
        if started_here:
            ray.shutdown()
    summary = write_summary(spec, runs, statuses, kept=kept)
    _progress(spec, runs, statuses, [])
    print(f"summary: {spec.summary_path}")
    return summary


def _init_ray(ray, config: SweepConfig) -> None:
    import logging

    if config.address:
        ray.init(address=config.address, logging_level=logging.WARNING, log_to_driver=False)
        return
    ray.init(
        num_cpus=config.max_concurrent or os.cpu_count() or 1,
        include_dashboard=False,
        logging_level=logging.WARNING,
        log_to_driver=False,
        # The runs pass no large objects through Ray; keep its shared memory small.
        object_store_memory=100 * 2**20,
    )
