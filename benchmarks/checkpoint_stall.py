"""How long a checkpoint of a large image replay stalls the training loop, and what resuming
holds in memory: the two-file format (one `.npz` of the whole replay, loaded whole) against
checkpoint directories (only the replay blocks changed since the previous checkpoint are
written, by a background thread once they exceed 64 MiB; loaded a block at a time), measured
in the same run on the same buffer. The stall of the new save is the time `save` blocks plus
how much slower the loop's next episodes go into the replay while the blocks are written. The
old save is measured without `fsync`, as it was; the new one syncs every file it writes.

The buffer is shaped like `--preset residual-cpu`'s (2 RGBD views of 64 px, 32 KiB a slot)
and filled to `--replay-gib` with random images. Between two checkpoints the loop adds
`--new-slots` slots: 5000 env steps are 50 episodes of 101 slots, and with re-rendered HER
each failed one brings two more (15150 slots when all fail, the worst case).

    python benchmarks/checkpoint_stall.py               # 2.3 GiB, as in the measured stall
    python benchmarks/checkpoint_stall.py --replay-gib 0.5 --repeats 1   # quick look

Writes results/benchmarks/checkpoint_stall.csv.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
from common import write_csv

from clamgen.experiments import checkpoint as ckpt
from clamgen.replay.buffer import ReplayBuffer, ReplayConfig
from clamgen.replay.episode import Episode

SPEC = {
    "achieved_goal": ((3,), np.dtype(np.float32)),
    "desired_goal": ((3,), np.dtype(np.float32)),
    "images": ((2, 4, 64, 64), np.dtype(np.uint8)),
    "observation": ((6,), np.dtype(np.float32)),
}
EPISODE_STEPS = 100


def reward(achieved, desired, info):
    return np.where(np.linalg.norm(achieved - desired, axis=-1) < 0.02, 0.0, -0.01)


def random_episode(rng: np.random.Generator) -> Episode:
    n = EPISODE_STEPS
    obs = {
        key: (
            rng.integers(0, 256, (n + 1, *shape), np.uint8)
            if dtype == np.uint8
            else rng.random((n + 1, *shape)).astype(dtype)
        )
        for key, (shape, dtype) in SPEC.items()
    }
    actions = rng.uniform(-1, 1, (n, 6)).astype(np.float32)
    return Episode(obs, actions, actions, np.zeros(n, bool), np.zeros(n, bool))


def fill(buffer: ReplayBuffer, num_slots: int, rng: np.random.Generator) -> None:
    # A few distinct episodes, stored over and over: filling 2 GiB with fresh random bytes
    # would take longer than the measurement.
    episodes = [random_episode(rng) for _ in range(8)]
    for i in range(num_slots // (EPISODE_STEPS + 1)):
        buffer.add_episode(episodes[i % len(episodes)])


def old_save(directory: Path, buffer: ReplayBuffer) -> None:
    """The two-file format's replay half: the whole replay as one `.npz`."""
    arrays = {f"buffer/{k}": v for k, v in buffer.state_dict().items()}
    ckpt.save_npz(directory / ckpt.LEGACY_REPLAY_NAME, arrays | {"stamp": np.array(0)})


def old_load(directory: Path, buffer: ReplayBuffer) -> None:
    arrays = ckpt.load_npz(directory / ckpt.LEGACY_REPLAY_NAME)
    buffer.load_state_dict({k[7:]: v for k, v in arrays.items() if k.startswith("buffer/")})


def _timed_hook(buffer: ReplayBuffer) -> list[float]:
    """Wrap `buffer.before_change` (set by a background save) to add up the time it blocks."""
    total = [0.0]
    hook = buffer.before_change
    if hook is not None:

        def timed_hook(first: int, last: int) -> None:
            start = time.perf_counter()
            hook(first, last)
            total[0] += time.perf_counter() - start

        buffer.before_change = timed_hook
    return total


def payload() -> dict:
    return {"format": ckpt.FORMAT, "kind": ckpt.TRAINING_KIND, "stamp": 0}


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def traced_peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replay-gib", type=float, default=2.3)
    parser.add_argument("--new-slots", type=int, default=15_150)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: /tmp)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    slot_bytes = sum(np.prod(s) * d.itemsize for s, d in SPEC.values())
    filled = int(args.replay_gib * 2**30 / slot_bytes)
    capacity = filled + 2 * args.new_slots * args.repeats + EPISODE_STEPS + 1
    config = ReplayConfig(capacity=capacity, her_ratio=0.0, reversible_her=False)
    buffer = ReplayBuffer(config, SPEC, 6, reward)
    fill(buffer, filled, rng)
    print(f"replay: {len(buffer)} transitions, {filled * slot_bytes / 2**30:.2f} GiB of slots")
    root = Path(tempfile.mkdtemp(prefix="checkpoint-stall-", dir=args.dir))
    rows = []
    try:
        store = ckpt.CheckpointStore(root / "new")
        first_s = timed(lambda: store.save(payload(), {}, buffer))  # every block
        store.wait()
        (root / "old").mkdir()
        for repeat in range(args.repeats):
            fill_alone_s = timed(lambda: fill(buffer, args.new_slots, rng))
            old_s = timed(lambda: old_save(root / "old", buffer))
            call_s = timed(lambda: store.save(payload(), {}, buffer))
            # The loop goes on while the blocks are written (the next interval's episodes); it
            # is blocked only where it would change a block not yet written.
            blocked = _timed_hook(buffer)
            fill_during_s = timed(lambda: fill(buffer, args.new_slots, rng))
            wait_s = timed(store.wait)
            new_s = call_s + blocked[0]
            rows.append(
                {
                    "repeat": repeat,
                    "replay_gib": round(filled * slot_bytes / 2**30, 3),
                    "new_slots": args.new_slots,
                    "old_save_s": round(old_s, 3),
                    "new_save_call_s": round(call_s, 3),
                    "new_blocked_in_loop_s": round(blocked[0], 3),
                    "new_fill_slowdown_s": round(fill_during_s - fill_alone_s, 3),
                    "new_stall_s": round(new_s, 3),
                    "new_background_left_s": round(wait_s, 3),
                    "first_new_save_s": round(first_s, 3),
                    "stall_ratio_old_over_new": round(old_s / new_s, 1),
                }
            )
            print(
                f"checkpoint after {args.new_slots} new slots: whole .npz stalls {old_s:6.2f} s"
                f"   changed blocks stall {new_s:6.3f} s (save {call_s:.3f} s + blocked in the "
                f"loop {blocked[0]:.3f} s; adding the next {args.new_slots} slots meanwhile took "
                f"{fill_during_s - fill_alone_s:+.2f} s longer, written {wait_s:.2f} s after)"
                f"   ratio {old_s / new_s:6.0f}x"
            )
        print(f"first checkpoint of the run (every block, in the background): {first_s:.3f} s")
        # Resume: peak memory besides the replay itself (numpy allocations, tracemalloc).
        target = ReplayBuffer(config, SPEC, 6, reward)
        old_peak = traced_peak(lambda: old_load(root / "old", target))
        target = ReplayBuffer(config, SPEC, 6, reward)
        new_peak = traced_peak(
            lambda: ckpt.CheckpointStore(root / "new").load(target, lambda p, path: None)
        )
        for row in rows:
            row |= {
                "old_resume_extra_gib": round(old_peak / 2**30, 3),
                "new_resume_extra_gib": round(new_peak / 2**30, 3),
            }
        print(
            f"resume, memory held besides the replay: whole .npz {old_peak / 2**30:.2f} GiB   "
            f"blocks {new_peak / 2**30:.3f} GiB"
        )
    finally:
        shutil.rmtree(root, ignore_errors=True)
    print(f"wrote {write_csv('checkpoint_stall', rows)}")


if __name__ == "__main__":
    main()
