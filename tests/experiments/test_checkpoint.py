"""Checkpoint directories: published whole, incremental replay blocks, fallback when damaged,
one copy of the replay on resume, metrics without repeated rows after a resume."""

import csv
import dataclasses
import os
import time
import tracemalloc
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from test_train import tiny_config

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.train import Trainer
from clamgen.replay import buffer as buffer_module
from clamgen.replay.buffer import ReplayBuffer, ReplayConfig
from clamgen.replay.episode import Episode

SPEC = {
    "observation": ((4,), np.dtype(np.float32)),
    "achieved_goal": ((3,), np.dtype(np.float32)),
    "desired_goal": ((3,), np.dtype(np.float32)),
}


def reward(achieved, desired, info):
    return np.where(np.all(achieved == desired, axis=-1), 0.0, -0.01)


def episode(seed: int, num_steps: int = 9, spec=SPEC) -> Episode:
    rng = np.random.default_rng(seed)
    obs = {
        k: rng.random((num_steps + 1, *shape)).astype(dtype) for k, (shape, dtype) in spec.items()
    }
    actions = rng.uniform(-1, 1, (num_steps, 2)).astype(np.float32)
    return Episode(obs, actions, actions, np.zeros(num_steps, bool), np.zeros(num_steps, bool))


def make_buffer(capacity: int = 200, spec=SPEC) -> ReplayBuffer:
    config = ReplayConfig(capacity=capacity, reversible_her=False)
    return ReplayBuffer(config, spec, 2, reward)


def assert_same_buffer(a: ReplayBuffer, b: ReplayBuffer) -> None:
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for key in sa:
        np.testing.assert_array_equal(sa[key], sb[key], err_msg=key)


@pytest.fixture
def small_blocks(monkeypatch):
    """Blocks of a few slots, so that a small buffer has many of them."""
    slot_bytes = buffer_module.nbytes_required(ReplayConfig(capacity=2), SPEC, 2) // 2
    monkeypatch.setattr(buffer_module, "BLOCK_BYTES", 16 * slot_bytes)


def save(store: ckpt.CheckpointStore, buffer: ReplayBuffer, step: int) -> Path:
    payload = {"format": ckpt.FORMAT, "kind": ckpt.TRAINING_KIND, "stamp": step}
    path = store.save(payload, {"extra": np.arange(step)}, buffer)
    store.wait()
    return path


def copy_of(buffer: ReplayBuffer, capacity: int = 200) -> ReplayBuffer:
    copy = make_buffer(capacity)
    copy.load_state_dict({k: v.copy() for k, v in buffer.state_dict().items()})
    return copy


def slow_writes(monkeypatch, fail_on: str | None = None) -> None:
    """Writing each file takes 20 ms (and `fail_on` fails), so the loop runs meanwhile."""
    real = ckpt._write_file

    def write(path, content):
        time.sleep(0.02)
        if fail_on is not None and path.name == fail_on:
            raise OSError(28, "No space left on device")
        return real(path, content)

    monkeypatch.setattr(ckpt, "_write_file", write)
    monkeypatch.setattr(ckpt, "BACKGROUND_BYTES", 0)


def accept(payload, path):
    pass


def test_a_checkpoint_writes_only_changed_blocks_and_keeps_the_previous_one(tmp_path, small_blocks):
    buffer = make_buffer()
    assert buffer.slots_per_block == 16
    for i in range(5):  # 50 slots: blocks 0-3
        buffer.add_episode(episode(i))
    store = ckpt.CheckpointStore(tmp_path)
    first = save(store, buffer, 1)
    assert first.name == "ckpt-000001"
    assert sorted(p.name for p in (first / "replay").iterdir()) == [
        f"block-{b:06d}.npz" for b in range(4)
    ]
    buffer.add_episode(episode(5))  # slots 50-59: blocks 3 only
    second = save(store, buffer, 2)
    for block in range(3):  # unchanged: the same file, not a copy
        name = f"replay/block-{block:06d}.npz"
        assert (second / name).stat().st_ino == (first / name).stat().st_ino
    assert (second / "replay/block-000003.npz").stat().st_ino != (
        first / "replay/block-000003.npz"
    ).stat().st_ino
    buffer.add_episode(episode(6))
    third = save(store, buffer, 3)
    # The previous good checkpoint stays until the next one is published; older ones go.
    assert [p.name for p in store.published()] == [third.name, second.name]
    restored = make_buffer()
    loaded = ckpt.CheckpointStore(tmp_path).load(restored, accept)
    assert loaded.path == third and loaded.payload["stamp"] == 3
    np.testing.assert_array_equal(loaded.arrays["extra"], np.arange(3))
    assert_same_buffer(buffer, restored)


def test_wrapping_buffer_round_trips_through_incremental_checkpoints(tmp_path, small_blocks):
    buffer = make_buffer(capacity=64)
    store = ckpt.CheckpointStore(tmp_path)
    for i in range(20):  # wraps several times, dropping old episodes
        buffer.add_episode(episode(i, num_steps=3 + i % 7))
        save(store, buffer, i)
        restored = make_buffer(capacity=64)
        ckpt.CheckpointStore(tmp_path).load(restored, accept)
        assert_same_buffer(buffer, restored)
        assert len(restored) == len(buffer) and restored.num_episodes == buffer.num_episodes


def test_a_background_checkpoint_holds_the_replay_as_it_was_when_saved(
    tmp_path, small_blocks, monkeypatch
):
    buffer = make_buffer(capacity=100)
    for i in range(8):
        buffer.add_episode(episode(i))
    store = ckpt.CheckpointStore(tmp_path)
    save(store, buffer, 1)
    for i in range(8, 14):  # wraps at episode 10
        buffer.add_episode(episode(i))
    slow_writes(monkeypatch)
    snapshot = copy_of(buffer, capacity=100)
    payload = {"format": ckpt.FORMAT, "kind": ckpt.TRAINING_KIND, "stamp": 2}
    store.save(payload, {}, buffer)
    assert store._job is not None and store._job.thread.is_alive()
    for i in range(14, 20):  # changes blocks still being written: they wait for them
        buffer.add_episode(episode(i))
    store.wait()
    restored = make_buffer(capacity=100)
    assert ckpt.CheckpointStore(tmp_path).load(restored, accept).payload["stamp"] == 2
    assert_same_buffer(snapshot, restored)
    save(store, buffer, 3)  # and the changes made meanwhile go into the next one
    ckpt.CheckpointStore(tmp_path).load(restored, accept)
    assert_same_buffer(buffer, restored)


def test_a_failed_background_checkpoint_is_reported_and_the_next_one_is_whole(
    tmp_path, small_blocks, monkeypatch
):
    buffer = make_buffer()
    for i in range(4):
        buffer.add_episode(episode(i))
    store = ckpt.CheckpointStore(tmp_path)
    save(store, buffer, 1)
    buffer.add_episode(episode(4))
    with monkeypatch.context() as patch:
        slow_writes(patch, fail_on="block-000002.npz")
        with pytest.raises(ckpt.CheckpointError, match=r"No space left.*previous checkpoint is"):
            save(store, buffer, 2)
    assert [p.name for p in store.published()] == ["ckpt-000001"]
    buffer.add_episode(episode(5))
    save(store, buffer, 3)
    restored = make_buffer()
    ckpt.CheckpointStore(tmp_path).load(restored, accept)
    assert_same_buffer(buffer, restored)


def test_a_killed_save_leaves_the_previous_checkpoint_and_is_cleaned_up(tmp_path, small_blocks):
    buffer = make_buffer()
    buffer.add_episode(episode(0))
    store = ckpt.CheckpointStore(tmp_path)
    save(store, buffer, 1)
    # What a kill during the next save leaves: a temporary directory, half written.
    partial = tmp_path / ".ckpt-000002.tmp"
    (partial / "replay").mkdir(parents=True)
    (partial / "state.pt").write_bytes(b"\0" * 10)
    restored = make_buffer()
    assert ckpt.CheckpointStore(tmp_path).load(restored, accept).payload["stamp"] == 1
    save(ckpt.CheckpointStore(tmp_path), buffer, 2)
    assert not partial.exists()


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        (lambda d: (d / "replay/block-000001.npz").unlink(), "block-000001.npz is missing"),
        (lambda d: _truncate(d / "state.pt"), "state.pt has"),
        (lambda d: _flip_byte(d / "replay/block-000000.npz"), "fails its CRC-32"),
        (lambda d: (d / "manifest.json").write_text("{"), "manifest.json unreadable"),
    ],
)
def test_a_damaged_newest_checkpoint_falls_back_to_the_previous_one(
    tmp_path, small_blocks, capsys, damage, reason
):
    buffer = make_buffer()
    for i in range(3):
        buffer.add_episode(episode(i))
    store = ckpt.CheckpointStore(tmp_path)
    save(store, buffer, 1)
    expected = copy_of(buffer)
    buffer.add_episode(episode(3))
    newest = save(store, buffer, 2)
    damage(newest)
    restored = make_buffer()
    loaded = ckpt.CheckpointStore(tmp_path).load(restored, accept)
    assert loaded.payload["stamp"] == 1
    assert_same_buffer(expected, restored)
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "ckpt-000002 is damaged" in line and reason in line
    assert "resumed from ckpt-000001 (step 1)" in line
    # The next checkpoint builds on the one resumed from; the damaged one is removed.
    store = ckpt.CheckpointStore(tmp_path)
    store.load(make_buffer(), accept)
    capsys.readouterr()
    published = save(store, restored, 3)
    assert [p.name for p in store.published()] == [published.name, "ckpt-000001"]


def test_no_intact_checkpoint_is_one_error_naming_each(tmp_path):
    buffer = make_buffer()
    buffer.add_episode(episode(0))
    store = ckpt.CheckpointStore(tmp_path)
    for step in (1, 2):
        _truncate(save(store, buffer, step) / "episodes.npz")
    with pytest.raises(ckpt.CheckpointError, match="no intact checkpoint") as error:
        ckpt.CheckpointStore(tmp_path).load(make_buffer(), accept)
    assert "ckpt-000002 is damaged" in str(error.value)
    assert "ckpt-000001 is damaged" in str(error.value)
    assert "\n" not in str(error.value)


def test_a_configuration_mismatch_stops_the_resume_instead_of_falling_back(tmp_path):
    buffer = make_buffer()
    buffer.add_episode(episode(0))
    store = ckpt.CheckpointStore(tmp_path)
    save(store, buffer, 1)
    save(store, buffer, 2)

    def refuse(payload, path):
        raise ckpt.CheckpointError(f"{path} was written with a different configuration")

    with pytest.raises(ckpt.CheckpointError, match="ckpt-000002 was written with a different"):
        ckpt.CheckpointStore(tmp_path).load(make_buffer(), refuse)


def test_resume_holds_one_copy_of_the_replay(tmp_path):
    spec = SPEC | {"images": ((2, 40, 40, 4), np.dtype(np.uint8))}
    buffer = make_buffer(capacity=6_000, spec=spec)  # 77 MB of images
    for i in range(59):
        buffer.add_episode(episode(i, num_steps=99, spec=spec))
    store = ckpt.CheckpointStore(tmp_path)
    save(store, buffer, 1)
    restored = make_buffer(capacity=6_000, spec=spec)
    tracemalloc.start()
    try:
        ckpt.CheckpointStore(tmp_path).load(restored, accept)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 3 * buffer_module.BLOCK_BYTES < buffer.nbytes / 2
    assert_same_buffer(buffer, restored)


def test_the_old_two_file_checkpoint_still_resumes(tmp_path):
    buffer = make_buffer()
    buffer.add_episode(episode(0))
    payload = {"format": ckpt.FORMAT, "kind": ckpt.TRAINING_KIND, "stamp": 7}
    arrays = {f"buffer/{k}": v for k, v in buffer.state_dict().items()}
    ckpt.save_npz(tmp_path / ckpt.LEGACY_REPLAY_NAME, arrays | {"stamp": np.array(7)})
    ckpt.save_torch(tmp_path / ckpt.LEGACY_STATE_NAME, payload)
    restored = make_buffer()
    store = ckpt.CheckpointStore(tmp_path)
    assert store.exists()
    assert store.load(restored, accept).payload["stamp"] == 7
    assert_same_buffer(buffer, restored)


# --------------------------------------------------------------------- the trainer
def metric_rows(run_dir: Path) -> list[tuple[int, str]]:
    with (run_dir / "metrics.csv").open(newline="") as f:
        return [(int(row[0]), row[2]) for row in list(csv.reader(f))[1:]]


def tensorboard_steps(run_dir: Path) -> dict[str, list[int]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run_dir / "tensorboard"), purge_orphaned_data=True)
    events.Reload()
    return {tag: [e.step for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


class Died(Exception):
    """Stands for a kill -9: the process stops without saving anything more."""


def test_resume_logs_every_step_and_metric_once(tmp_path):
    config = tiny_config(tmp_path / "run", total=240, checkpoint_every_steps=80, log_every_steps=20)
    config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, eval_every_steps=60))
    dying = Trainer(config)
    real_collect = dying._collect_step

    def collect():
        real_collect()
        if dying.progress.env_steps == 150:  # 70 steps of rows after the checkpoint at 80
            raise Died

    dying._collect_step = collect
    with pytest.raises(Died):
        dying.run(show_progress=False)
    assert max(step for step, _ in metric_rows(config.run_dir)) == 140
    Trainer(config).run(show_progress=False)
    rows = metric_rows(config.run_dir)
    assert not [pair for pair, n in Counter(rows).items() if n > 1]
    assert sorted({step for step, metric in rows if metric == "rollout/episodes"}) == list(
        range(20, 241, 20)
    )
    for tag, steps in tensorboard_steps(config.run_dir).items():
        assert len(steps) == len(set(steps)), tag
    assert tensorboard_steps(config.run_dir)["rollout/episodes"] == list(range(20, 241, 20))
    # Run again once finished: nothing is evaluated or logged twice.
    before = metric_rows(config.run_dir)
    Trainer(config).run(show_progress=False)
    assert metric_rows(config.run_dir) == before


def test_a_run_that_died_before_its_first_checkpoint_starts_its_metrics_again(tmp_path):
    config = tiny_config(tmp_path / "run", total=120, checkpoint_every_steps=100)
    dying = Trainer(config)
    real_collect = dying._collect_step

    def collect():
        real_collect()
        if dying.progress.env_steps == 90:
            raise Died

    dying._collect_step = collect
    with pytest.raises(Died):
        dying.run(show_progress=False)
    assert metric_rows(config.run_dir)
    Trainer(config).run(show_progress=False)
    rows = metric_rows(config.run_dir)
    assert len(rows) == len(set(rows))
    for tag, steps in tensorboard_steps(config.run_dir).items():
        assert len(steps) == len(set(steps)), tag


def test_trainer_prints_its_memory_need_and_refuses_what_does_not_fit(tmp_path, capsys):
    Trainer(tiny_config(tmp_path / "run"))
    line = capsys.readouterr().out
    assert line.startswith("memory: ") and "checkpoint save/resume" in line
    assert "GiB available" in line
    config = tiny_config(tmp_path / "big")
    replay = ReplayConfig(capacity=100_000)
    replay_bytes = buffer_module.nbytes_required(replay, obs_spec_of(config), 6)
    # The replay alone fits into the allowed fraction; with a checkpoint's peak on top it does not.
    fraction = (replay_bytes + 1000) / buffer_module.available_memory_bytes()
    big = dataclasses.replace(
        config, replay=dataclasses.replace(replay, max_memory_fraction=fraction)
    )
    with pytest.raises(ValueError, match=r"needs .* GiB at peak .*lower replay.capacity"):
        Trainer(big)


def obs_spec_of(config):
    from clamgen.experiments.train import make_env
    from clamgen.replay import obs_spec_from_space

    env = make_env(config.env)
    try:
        return obs_spec_from_space(env.observation_space)
    finally:
        env.close()


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _flip_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    os.remove(path)  # a new file: the previous checkpoint's hard link keeps the good bytes
    path.write_bytes(bytes(data))
