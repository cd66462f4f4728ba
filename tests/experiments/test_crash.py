"""kill -9 at random instants of short training runs that checkpoint at every iteration.

Each campaign runs the same training again and again in a child process, killed with SIGKILL
after a random delay, until it has been killed `num_kills` times; then lets it finish. It checks
that every restart resumes from the newest checkpoint published before the kill, that no kill
costs more than the steps since that checkpoint (the episodes in progress are in the
checkpoint), that the finished run's metrics hold each (step, metric) pair once in both
`metrics.csv` and TensorBoard, and that the final policy equals that of the same run never
killed (exact resume).

The short stage-1 campaign runs with the tests; the long ones (200 kills of stage 1, 20 of
stage 2) with `pytest -m slow tests/experiments/test_crash.py`.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import multiprocessing
import os
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch
from test_train import tiny_config

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.train import POLICY_NAME

START = "start"
DONE = "done"


def _child(trainer_path: str, config, log_path: str, stderr_path: str, background: bool) -> None:
    """One training attempt: note the step it resumed at, train to the end, note that.
    `background`: write every checkpoint's replay blocks in the background thread."""
    if background:
        ckpt.BACKGROUND_BYTES = -1
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)  # the memory line and progress output of hundreds of attempts
    os.dup2(os.open(stderr_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT), 2)
    log = os.open(log_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    module, name = trainer_path.rsplit(".", 1)
    try:
        trainer = getattr(__import__(module, fromlist=[name]), name)(config)
        trainer.start_or_resume()
        os.write(log, f"{START} {trainer.progress.env_steps}\n".encode())
        trainer.run(show_progress=False)
        os.write(log, f"{DONE}\n".encode())
    except BaseException:
        traceback.print_exc()
        sys.stderr.flush()
        os._exit(1)
    os._exit(0)


@dataclasses.dataclass
class Campaign:
    kills: int = 0
    kills_during_save: int = 0
    starts: list[int] = dataclasses.field(default_factory=list)
    max_lost_steps: int = 0
    fallbacks: int = 0


def _wait_for_start(child, log_path: Path, num_lines_before: int) -> None:
    while child.is_alive():
        if log_path.exists() and len(log_path.read_text().splitlines()) > num_lines_before:
            return
        time.sleep(0.01)


def _newest_stamp(checkpoint_dir: Path) -> int:
    published = ckpt.CheckpointStore(checkpoint_dir).published()
    if not published:
        return 0
    return json.loads((published[0] / ckpt.MANIFEST_NAME).read_text())["stamp"]


def _last_logged_step(run_dir: Path) -> int:
    path = run_dir / "metrics.csv"
    if not path.exists():
        return 0
    with path.open(newline="") as f:
        steps = [int(row[0]) for row in list(csv.reader(f))[1:] if row and row[0].isdigit()]
    return max(steps, default=0)


def run_campaign(
    trainer_path: str, config, num_kills: int, max_delay_s: float, seed: int, background: bool
) -> Campaign:
    """Kill `num_kills` attempts of the run at random instants, then let one finish."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["clamgen.experiments.train", "clamgen.experiments.stage2"])
    rng = np.random.default_rng(seed)
    run_dir = Path(config.run_dir)
    checkpoint_dir = run_dir / "checkpoints"
    log_path = run_dir.parent / f"{run_dir.name}-attempts.log"
    stderr_path = run_dir.parent / f"{run_dir.name}-stderr.log"
    # A kill while a checkpoint is written in the background loses the steps since the one
    # before it too.
    every = config.loop.checkpoint_every_steps * (2 if background else 1)
    campaign = Campaign()
    while True:
        expected_start = _newest_stamp(checkpoint_dir)
        lines_before = log_path.read_text().splitlines() if log_path.exists() else []
        child = context.Process(
            target=_child,
            args=(trainer_path, config, str(log_path), str(stderr_path), background),
        )
        child.start()
        if campaign.kills < num_kills:
            # Mostly while training, sometimes while building the trainer or resuming.
            if rng.random() < 0.8:
                _wait_for_start(child, log_path, len(lines_before))
            child.join(rng.uniform(0.0, max_delay_s))
            if child.is_alive():
                child.kill()
                campaign.kills += 1
        child.join(600)
        lines = log_path.read_text().splitlines()[len(lines_before) :] if log_path.exists() else []
        if child.exitcode not in (0, -9):
            raise AssertionError(
                f"attempt exited with {child.exitcode}: {stderr_path.read_text()[-3000:]}"
            )
        starts = [int(line.split()[1]) for line in lines if line.startswith(START)]
        for start in starts:
            assert start == expected_start, (
                f"resumed at {start}, newest checkpoint {expected_start}"
            )
            campaign.starts.append(start)
        if child.exitcode == 0:
            assert DONE in lines
            break
        if any(p.name.endswith(".tmp") for p in checkpoint_dir.glob(".*")):
            campaign.kills_during_save += 1
        lost = _last_logged_step(run_dir) - _newest_stamp(checkpoint_dir)
        campaign.max_lost_steps = max(campaign.max_lost_steps, lost)
        assert lost <= every, f"a kill lost {lost} steps, more than {every}"
    campaign.fallbacks = stderr_path.read_text().count("is damaged") if stderr_path.exists() else 0
    return campaign


def _straight(trainer_path: str, config) -> None:
    context = multiprocessing.get_context("forkserver")
    log_path = Path(config.run_dir).parent / "straight-attempts.log"
    stderr_path = Path(config.run_dir).parent / "straight-stderr.log"
    child = context.Process(
        target=_child, args=(trainer_path, config, str(log_path), str(stderr_path), False)
    )
    child.start()
    child.join(600)
    assert child.exitcode == 0, stderr_path.read_text()[-3000:]


def _assert_metrics_once(run_dir: Path, every: int, total: int) -> None:
    with (run_dir / "metrics.csv").open(newline="") as f:
        rows = [(int(row[0]), row[2]) for row in list(csv.reader(f))[1:]]
    repeated = [pair for pair, n in Counter(rows).items() if n > 1]
    assert not repeated, f"repeated metrics rows: {repeated[:5]}"
    logged = sorted(step for step, metric in rows if metric == "rollout/episodes")
    assert logged == list(range(every, total + 1, every))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run_dir / "tensorboard"), purge_orphaned_data=True)
    events.Reload()
    for tag in events.Tags()["scalars"]:
        steps = [e.step for e in events.Scalars(tag)]
        assert len(steps) == len(set(steps)), f"TensorBoard repeats steps of {tag}"
    assert [e.step for e in events.Scalars("rollout/episodes")] == logged


def _assert_same_policy(a: Path, b: Path) -> None:
    pa = torch.load(a / POLICY_NAME, weights_only=True)["agent"]
    pb = torch.load(b / POLICY_NAME, weights_only=True)["agent"]
    for part in ("actor", "critic"):
        for key, value in pa[part].items():
            torch.testing.assert_close(value, pb[part][key], rtol=0, atol=0)


def stage1_config(run_dir: Path, total: int):
    return tiny_config(
        run_dir,
        total=total,
        checkpoint_every_steps=2,  # every iteration (2 envs)
        log_every_steps=2,
        num_eval_episodes=2,
    )


def stage2_config(run_dir: Path, total: int):
    from clamgen.experiments.config import LoopConfig, load_preset
    from clamgen.experiments.stage2 import Stage2Config
    from clamgen.replay import ReplayConfig

    preset = load_preset("residual-obstacles", Stage2Config)
    return dataclasses.replace(
        preset,
        run_dir=run_dir,
        env=dataclasses.replace(preset.env, num_envs=2),
        agent=dataclasses.replace(preset.agent, batch_size=16, hidden_sizes=(32,)),
        replay=ReplayConfig(capacity=5_000),
        loop=LoopConfig(
            total_env_steps=total,
            learning_starts=40,
            updates_per_step=0.25,
            eval_every_steps=0,
            num_eval_episodes=2,
            checkpoint_every_steps=2,
            log_every_steps=2,
            seed=2,
            torch_threads=1,
        ),
    )


STAGE1 = "clamgen.experiments.train.Trainer"
STAGE2 = "clamgen.experiments.stage2.Stage2Trainer"


def crash_and_compare(
    tmp_path, trainer_path, make_config, total, num_kills, max_delay_s, background=False
):
    start = time.perf_counter()
    killed = make_config(tmp_path / "killed", total)
    campaign = run_campaign(
        trainer_path, killed, num_kills, max_delay_s, seed=num_kills, background=background
    )
    _straight(trainer_path, make_config(tmp_path / "straight", total))
    _assert_metrics_once(killed.run_dir, 2, total)
    _assert_same_policy(killed.run_dir, tmp_path / "straight")
    assert campaign.kills == num_kills
    assert campaign.fallbacks == 0  # kill -9 never damages a published checkpoint
    print(
        f"{trainer_path}{' (background writes)' if background else ''}: "
        f"{campaign.kills} kills ({campaign.kills_during_save} during a save), "
        f"{len(campaign.starts)} attempts started, at most {campaign.max_lost_steps} steps "
        f"lost per kill, {time.perf_counter() - start:.0f} s"
    )
    return campaign


def test_stage1_survives_20_kills_at_random_instants(tmp_path):
    # Long enough that 20 kills land before the run ends, even on a fast idle machine.
    crash_and_compare(tmp_path, STAGE1, stage1_config, 600, num_kills=20, max_delay_s=0.3)


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_stage1_survives_200_kills_at_random_instants(tmp_path):
    # Each attempt keeps the steps up to its last checkpoint, so a 2000-step run finished
    # after 184 kills here: 4000 steps leave room for all 200.
    campaign = crash_and_compare(
        tmp_path, STAGE1, stage1_config, 4000, num_kills=200, max_delay_s=0.4
    )
    assert campaign.kills_during_save > 0


@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("background", [False, True], ids=["synchronous", "background"])
def test_stage2_survives_20_kills_at_random_instants(tmp_path, background):
    crash_and_compare(
        tmp_path, STAGE2, stage2_config, 400, num_kills=20, max_delay_s=0.6, background=background
    )
