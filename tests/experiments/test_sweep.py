"""`clamgen sweep`: spec checks, the plan, the message without Ray, and a two-run sweep on
local Ray that is killed mid-way and resumed without redoing finished work."""

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from clamgen.experiments import sweep as S

# A few hundred env steps of stage 1 with everything small, evaluated on 2 test tasks.
TINY = """
name = "tiny"
run_root = "{root}"
command = "train"
presets = ["base"]
seeds = [0]
flags = ["--loop.learning-starts", "100", "--env.num-envs", "2", "--loop.updates-per-step", "0.25"]
set = {{"loop.eval_every_steps" = 100, "loop.num_eval_episodes" = 2, \
"loop.checkpoint_every_steps" = 100, "loop.log_every_steps" = 100, "replay.capacity" = 20000}}

[eval]
table = 1
flags = ["--num-tasks", "2", "--speeds", "0"]

[[overrides]]
name = "short"
set = {{"loop.total_env_steps" = 300}}

[[overrides]]
name = "long"
set = {{"loop.total_env_steps" = 3000}}
"""


def write_spec(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "spec.toml"
    path.write_text(text)
    return path


def test_plan_covers_rows_presets_and_seeds(tmp_path):
    spec = S.load_spec(
        write_spec(
            tmp_path,
            f"""
run_root = "{tmp_path / "runs"}"
command = "train-residual"
presets = ["residual-cpu"]
seeds = [0, 1, 2]
flags = ["--loop.total-env-steps", "60000"]
[eval]
table = 2
flags = ["--num-tasks", "200"]
[[overrides]]
name = "CLAMGen, 3 RGBD views"
set = {{"env.num_views" = 3, "agent.encoder.num_views" = 3}}
seeds = [0, 1, 2, 3, 4]
[[overrides]]
name = "no residual (2 views)"
set = {{"agent.residual" = false}}
compare_to = "CLAMGen, 3 RGBD views"
""",
        )
    )
    runs = S.plan_runs(spec)
    assert [r.id for r in runs][:2] == ["clamgen-3-rgbd-views/seed0", "clamgen-3-rgbd-views/seed1"]
    assert len(runs) == 5 + 3
    first, ablation = runs[0], runs[5]
    assert first.train_args[:3] == ("train-residual", "--preset", "residual-cpu")
    assert "--env.num-views" in first.train_args and "--agent.encoder.num-views" in first.train_args
    assert "--agent.no-residual" in ablation.train_args
    assert first.train_args[-2:] == ("--run-dir", str(tmp_path / "runs" / first.id))
    assert ("--name", "CLAMGen, 3 RGBD views") == first.eval_args[7:9]
    assert spec.summary_path == tmp_path / "runs" / "summary.json"


def test_a_distillation_sweep_seeds_the_dagger_loop_and_waits_for_its_summary(tmp_path):
    spec = S.load_spec(
        write_spec(
            tmp_path,
            f"""
run_root = "{tmp_path / "runs"}"
command = "distill"
presets = ["residual-cpu"]
seeds = [1]
flags = ["--distill.teacher", "teacher.pt"]
set = {{"distill.lookahead_candidates" = 16, "env.num_views" = 1}}
[eval]
table = 2
[[overrides]]
name = "1 view, distilled"
""",
        )
    )
    (run,) = S.plan_runs(spec)
    args = run.train_args
    assert args[0] == "distill" and args[args.index("--distill.seed") + 1] == "1"
    assert "--loop.seed" not in args
    assert args[args.index("--distill.lookahead-candidates") + 1] == "16"
    assert args[args.index("--env.num-views") + 1] == "1"
    # Its policy file is written after each iteration: a run is trained once it has a summary.
    run.run_dir.mkdir(parents=True)
    run.policy_path.write_bytes(b"")
    (run.run_dir / "student.pt").write_bytes(b"")
    assert not run.trained and run.has_checkpoint
    (run.run_dir / "summary.json").write_text("{}")
    assert run.trained
    # Its training env, which the report's curves need, sits under the student's settings.
    config = {"student": {"env": {"env_id": "CLAMGen/ReachMixed-v0"}}, "distill": {}}
    (run.run_dir / "config.json").write_text(json.dumps(config))
    assert S._train_env(run.run_dir) == "CLAMGen/ReachMixed-v0"
    with pytest.raises(S.SpecError, match=r"distill\.seed is set by"):
        S.load_spec(
            write_spec(
                tmp_path,
                spec.text.replace('"teacher.pt"]', '"teacher.pt", "--distill.seed", "2"]'),
            )
        )
    with pytest.raises(S.SpecError, match=r"'distill\.sed' is not a field"):
        S.load_spec(write_spec(tmp_path, spec.text.replace("lookahead_candidates", "sed")))


HEAD = 'run_root = "r"\ncommand = "train"\npresets = ["base"]\n'
EVAL = "[eval]\ntable = 1\n"


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("seeds = [0]\n" + EVAL, "needs run_root"),
        (HEAD.replace('"train"', '"fit"') + "seeds = [0]\n" + EVAL, "command must be one of"),
        (HEAD + "seeds = []\n" + EVAL, "seeds must be a non-empty list"),
        (HEAD + "seeds = [1000000000]\n" + EVAL, "loop.seed must be in"),
        (HEAD.replace('"base"', '"nope"') + "seeds = [0]\n" + EVAL, "no preset 'nope'"),
        (HEAD + "seeds = [0]\n", "needs an [eval]"),
        (HEAD + "seeds = [0]\n" + EVAL.replace("1", "3"), "eval.table must be 1 or 2"),
        (HEAD + "seeds = [0]\nseed = 1\n" + EVAL, "unknown keys ['seed']"),
        (HEAD + 'seeds = [0]\nset = {"loop.sed" = 1}\n' + EVAL, "'loop.sed' is not a field"),
        (HEAD + 'seeds = [0]\nflags = ["--loop.seed", "3"]\n' + EVAL, "--loop.seed is set by"),
        (HEAD + "seeds = [0]\n" + EVAL + 'flags = ["--policy", "base"]\n', "--policy is set by"),
        (
            HEAD
            + "seeds = [0]\n"
            + EVAL
            + '[[overrides]]\nname = "a"\n[[overrides]]\nname = "a"\n',
            "appears twice",
        ),
        (
            HEAD + "seeds = [0]\n" + EVAL + '[[overrides]]\nname = "a"\ncompare_to = "b"\n',
            "is not a row of the sweep",
        ),
        (
            HEAD
            + "seeds = [0]\n"
            + EVAL
            + '[[overrides]]\nflags = []\n[[overrides]]\nname = "b"\n',
            "needs a name",
        ),
        ("run_root = \n", "not valid TOML"),
    ],
)
def test_bad_specs_are_refused_in_one_line(tmp_path, body, message):
    with pytest.raises(S.SpecError) as error:
        S.load_spec(write_spec(tmp_path, body))
    assert message in str(error.value)
    assert "\n" not in str(error.value)


def test_a_missing_spec_is_one_line(tmp_path):
    with pytest.raises(S.SpecError, match="cannot read sweep spec"):
        S.load_spec(tmp_path / "none.toml")


def test_without_ray_the_command_says_what_to_install(tmp_path, monkeypatch, capsys):
    from clamgen import cli

    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now raises ImportError
    spec = write_spec(tmp_path, TINY.format(root=tmp_path / "runs"))
    with pytest.raises(SystemExit) as error:
        cli.main(["sweep", str(spec)])
    assert str(error.value) == f"clamgen sweep: {S.INSTALL_HINT}"
    assert "pip install 'clamgen[sweep]'" in S.INSTALL_HINT and "\n" not in S.INSTALL_HINT


def test_dry_run_prints_the_commands_and_runs_nothing(tmp_path, capsys):
    spec = write_spec(tmp_path, TINY.format(root=tmp_path / "runs"))
    summary = S.run_sweep(S.SweepConfig(spec=spec, dry_run=True))
    out = capsys.readouterr().out
    assert "2 runs" in out and "clamgen train --preset base" in out
    assert "--loop.total-env-steps 300" in out and "clamgen eval --table 1" in out
    assert summary["counts"] == {"done": 0, "running": 0, "failed": 0, "queued": 2}
    assert not (tmp_path / "runs").exists()  # no run directory, no summary file


def test_runs_finished_on_another_machine_are_kept_from_the_committed_summary(tmp_path, capsys):
    spec_path = write_spec(tmp_path, TINY.format(root=tmp_path / "runs"))
    spec = S.load_spec(spec_path)
    short, long = S.plan_runs(spec)
    record = {
        "id": short.id,
        "row": short.row,
        "seed": 0,
        "train_command": "clamgen " + " ".join(short.train_args),
        "eval_command": "clamgen " + " ".join(short.eval_args),
        "status": "done",
        "validation": {"steps": [100, 200], "success_rate": [0.5, 1.0]},
        "test": {"table": 1, "observation": "joints", "scores": {"0": 1.0}},
    }
    stale = {**record, "id": long.id, "train_command": "clamgen train --preset base"}
    spec.summary_path.parent.mkdir(parents=True)
    spec.summary_path.write_text(json.dumps({"runs": [record, stale]}))
    summary = S.run_sweep(S.SweepConfig(spec=spec_path, dry_run=True))
    out = capsys.readouterr().out
    assert "1 finished (skipped; 1 of them recorded in" in out
    assert short.id not in out.split("new")[1] and long.id in out  # only `long` would train
    assert summary["runs"][0] == record and summary["runs"][1]["status"] == "queued"
    # A run directory here (say, a run in progress) wins over the record.
    short.run_dir.mkdir(parents=True)
    assert S.recorded_runs(spec, [short, long]) == {}


def test_overrides_become_cli_flags():
    flags = S.overrides_to_flags(
        {"env.num_views": 3, "agent.residual": False, "replay.her_ratio": 0.5}, "train-residual", ""
    )
    assert flags == ("--env.num-views", "3", "--agent.no-residual", "--replay.her-ratio", "0.5")


def test_validation_curve_skips_other_metrics_and_a_torn_line(tmp_path):
    (tmp_path / "metrics.csv").write_text(
        "step,wall_time_s,metric,value\n"
        "100,1.0,train/critic_loss,3\n100,1.0,eval/success_rate,0.5\n"
        "200,2.0,eval/success_rate,0.75\n300,3.0,eval/success_ra"
    )
    assert S.read_validation(tmp_path) == ([100, 200], [0.5, 0.75])


def _sweep_process(spec: Path, log: Path) -> subprocess.Popen:
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    with log.open("a") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "clamgen.cli", "sweep", str(spec), "--max-concurrent", "1",
             "--progress-every-s", "2"],
            stdout=out, stderr=subprocess.STDOUT, env=env,
        )  # fmt: skip


def _wait_for(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.5)


def _lock_free(run_dir: Path) -> bool:
    with (run_dir / S.LOCK_FILE).open("w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        fcntl.flock(lock, fcntl.LOCK_UN)
        return True


@pytest.mark.timeout(900)
def test_sweep_on_local_ray_is_killed_and_resumes_without_redoing_finished_work(tmp_path):
    pytest.importorskip("ray")
    root = tmp_path / "runs"
    spec = write_spec(tmp_path, TINY.format(root=root))
    short, long = root / "short" / "seed0", root / "long" / "seed0"
    log = tmp_path / "sweep.log"

    # One run at a time: `short` finishes, then `long` trains; kill the sweep (SIGKILL, no
    # chance to clean up) once `long` has written a checkpoint and before it has a policy.
    first = _sweep_process(spec, log)
    try:
        _wait_for(
            lambda: (long / "checkpoints").is_dir() and any((long / "checkpoints").iterdir()),
            600,
            f"a checkpoint of the long run ({log.read_text()[-2000:]})",
        )
        assert (short / "policy.pt").is_file() and (short / "eval.json").is_file()
        assert not (short / "checkpoints").exists()  # a finished run's are deleted
        assert not (long / "policy.pt").exists()
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait()
    # The trainer of `long` dies with its Ray worker: its lock is released.
    _wait_for(lambda: _lock_free(long), 120, "the killed run's trainer to exit")
    assert not (long / "policy.pt").exists()
    short_files = {p.name: p.stat().st_mtime_ns for p in short.iterdir() if p.is_file()}

    second = _sweep_process(spec, log)
    assert second.wait(timeout=600) == 0, log.read_text()[-3000:]
    text = log.read_text()
    assert "1 finished (skipped; 0 of them recorded in" in text
    assert "summary.json), 1 to resume from checkpoints" in text
    assert "done long/seed0 (resumed from its checkpoint)" in text
    # Nothing of the finished run was touched, and it was trained and evaluated once.
    assert {p.name: p.stat().st_mtime_ns for p in short.iterdir() if p.is_file()} == short_files
    assert (short / "train.log").read_text().count("$ clamgen train") == 1
    # The interrupted run was started twice and continued the second time.
    train_log = (long / "train.log").read_text()
    assert train_log.count("$ clamgen train") == 2
    assert "resumed" in train_log.split("$ clamgen train")[-1]
    steps, _ = S.read_validation(long)
    assert steps[-1] == 3000 and len(steps) == len(set(steps))

    assert not (long / "checkpoints").exists()
    summary = json.loads((root / "summary.json").read_text())
    assert summary["counts"]["done"] == 2
    by_id = {r["id"]: r for r in summary["runs"]}
    assert by_id["long/seed0"]["validation"]["steps"][-1] == 3000
    assert set(by_id["short/seed0"]["test"]["scores"]) == {"0"}
    assert by_id["short/seed0"]["train_command"].startswith("clamgen train --preset base")

    # A third run finds nothing to do.
    third = subprocess.run(
        [sys.executable, "-m", "clamgen.cli", "sweep", str(spec)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "2 finished (skipped; 0 of them recorded in" in third.stdout
    assert "nothing to do" in third.stdout
