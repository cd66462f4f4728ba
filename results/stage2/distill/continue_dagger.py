"""Continue DAgger from a regressed student: it drives, the teacher labels its states, it learns.

    python results/stage2/distill/continue_dagger.py runs/offline/d3-pool4-48k \
        runs/offline/d3-pool4-48k-dagger --iterations 2 --updates 6000 --new-share 0.2 \
        --seed 5 --torch-threads 2

A student regressed on pooled DAgger data (`offline.py`) learned from states that *other*
students visited; its own mistakes (where it stalls or presses into an obstacle) are in that
data only as far as those students made the same ones. This is DAgger's next step for it:
each iteration the student drives `episodes-per-iteration` episodes of the source run's task
mix (fresh training seeds: `--seed` picks the block, see `DISTILL_SEED_BASE`), the source
run's teacher labels every state it visits (with the same lookahead), and the student is
regressed further `--updates` steps, starting from its weights, on all data: the pool it was
regressed on plus the states collected here. A share `--new-share` of each batch comes from
the new states (0.2 gives them about as many passes as the pool had in a 48000-step
regression), the rest uniformly from the pool; the learning rate decays to zero along a cosine
in each iteration's regression. After each iteration it scores the student on the
distillation's 100 validation tasks and writes `policy_iteration<k>.pt` (and `policy.pt`: the
last iteration's, chosen by no score), its data and the state it resumes from.

The pool is held once (one preallocated array per key, as `offline.py` loads it, or
memory-mapped with `--pool-cache DIR` so that jobs on the same pool share it); the new states
are kept apart so that adding them never copies it (four 3-view runs are 14 GB).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from offline import add_settings_option, settings_changes  # (this directory)

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import config_from_json
from clamgen.experiments.distill import STATE_NAME, DistillConfig, Distiller, DistillSettings
from clamgen.experiments.pooled import data_files, load_pooled
from clamgen.experiments.stage2 import Stage2Config
from clamgen.experiments.train import POLICY_NAME

CONTINUE_STATE = "continue.pt"
"""The state a rerun resumes from (STATE_NAME holds the source student's, as offline.py writes)."""


class PoolAndNew:
    """The pooled states (read-only arrays) and the states collected since, apart: indices
    below `len(pool)` are the pool's, the rest the new states' in collection order."""

    def __init__(self, pool: dict[str, np.ndarray], keys: tuple[str, ...]) -> None:
        self.pool = pool
        self.keys = keys
        self.new: dict[str, np.ndarray] = {}

    @property
    def pool_size(self) -> int:
        return len(self.pool["label"])

    @property
    def new_size(self) -> int:
        return len(self.new.get("label", ()))

    def add(self, chunk: dict[str, np.ndarray]) -> None:
        self.new = (
            {k: np.concatenate([self.new[k], chunk[k]]) for k in chunk} if self.new else chunk
        )

    def __len__(self) -> int:
        return self.pool_size + self.new_size

    def column(self, key: str) -> np.ndarray:
        """Every state's `key` (a small one: it is copied), pool first."""
        return np.concatenate([self.pool[key], *([self.new[key]] if self.new_size else [])])

    def _gather(self, key: str, index: np.ndarray) -> np.ndarray:
        # Pool rows first, then new rows: every key of one batch in the same order.
        old = index < self.pool_size
        parts = [self.pool[key][np.sort(index[old])]]
        if self.new_size:
            parts.append(self.new[key][index[~old] - self.pool_size])
        return np.concatenate(parts)

    def batch(self, index: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        return {k: self._gather(k, index) for k in self.keys}, self._gather("label", index)

    def poses(self, index: np.ndarray) -> np.ndarray:
        return self._gather("obstacles", index)


class Continuation(Distiller):
    """A Distiller whose batches take `new_share` of their states from the new data."""

    new_share = 0.0

    def batch_index(self, batch_size: int) -> np.ndarray:
        data = self.data
        fresh = round(self.new_share * batch_size) if data.new_size else 0
        old = self.draw(0, data.pool_size, batch_size - fresh)
        new = self.draw(data.pool_size, len(data), fresh) if fresh else np.zeros(0, int)
        return np.concatenate([old, new])


FLAG_WORDS = (
    "set by --seed, --episodes or --driver-noise, or taken from the source run (the "
    "lookahead); give each once"
)


def flag_changes(args: argparse.Namespace) -> dict:
    """The distill settings this script's own flags set: the seed always, the episodes per
    iteration and the driver's noise where given (`--set` may not name them again)."""
    changes = {"seed": args.seed}
    if args.episodes:
        changes["episodes_per_iteration"] = args.episodes
    if args.driver_noise is not None:
        changes["driver_noise"] = args.driver_noise
    return changes


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help="a student written by offline.py")
    parser.add_argument("out", type=Path)
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--updates", type=int, default=6000, help="regression steps per iteration")
    parser.add_argument("--new-share", type=float, default=0.2, help="of each batch, new states")
    parser.add_argument("--episodes", type=int, default=None, help="per iteration (default: run's)")
    parser.add_argument("--seed", type=int, required=True, help="a distill seed no run used")
    parser.add_argument("--torch-threads", type=int, default=None, help="not saved")
    parser.add_argument(
        "--driver-noise",
        type=float,
        default=None,
        metavar="SD",
        help="Gaussian noise on the student's actions while it drives (distill.driver_noise; "
        "DART; default: the source's setting, 0)",
    )
    parser.add_argument(
        "--pool-cache", type=Path, default=None, metavar="DIR", help="as offline.py's"
    )
    add_settings_option(
        parser,
        "e.g. near_tip_weight=3 (the seed, the teacher's lookahead and the options above are "
        "set by their own flags)",
    )
    args = parser.parse_args(argv)
    if not 0.0 <= args.new_share < 1.0:
        raise SystemExit(f"--new-share must be in [0, 1), got {args.new_share}")
    changes = settings_changes(parser, args)
    given = flag_changes(args)
    twice = sorted(set(changes) & (set(given) | {"lookahead_candidates"}))
    if twice:
        parser.error(f"--set {', '.join(twice)}: {FLAG_WORDS}")
    changes.update(given)
    for name in ("offline.json", "config.json"):
        if not (args.source / name).is_file():
            parser.error(f"{args.source} has no {name}: not a student written by offline.py")
    record = json.loads((args.source / "offline.json").read_text())
    if record["relabel"]:
        raise SystemExit(f"{args.source} was regressed on relabelled data: not continued here")
    saved = json.loads((args.source / "config.json").read_text())
    run = Path(record["source"])
    lookahead = json.loads((run / "config.json").read_text())["distill"]["lookahead_candidates"]
    changes["lookahead_candidates"] = lookahead
    try:
        settings = DistillSettings(**{**saved["distill"], **changes})
    except ValueError as error:
        raise SystemExit(str(error)) from None
    student = config_from_json(json.dumps(saved["student"]), Stage2Config)
    student = dataclasses.replace(student, run_dir=args.out)
    distiller = Continuation(DistillConfig(student=student, distill=settings))
    distiller.new_share = args.new_share
    sources = [(run, record["iterations"]), *((Path(p), None) for p in record["pool"])]
    try:
        pool = load_pooled(sources, student.env.num_views, cache=args.pool_cache)
    except (FileNotFoundError, ValueError) as error:
        raise SystemExit(str(error)) from None
    distiller.data = PoolAndNew(pool, distiller.keys)
    args.out.mkdir(parents=True, exist_ok=True)
    start = 0
    resume = args.out / CONTINUE_STATE
    if resume.exists():
        distiller.load_resume_state(ckpt.load_torch(resume, "distill"))
        start = len(distiller.history)
        for path in data_files(args.out, start):
            distiller.data.add(ckpt.load_npz(path))
        print(f"resumed after iteration {start - 1} ({distiller.data.new_size} new states)")
    else:  # the source student's weights; a fresh optimizer and random streams
        state = ckpt.load_torch(args.source / STATE_NAME, "distill")
        distiller.student.load_state_dict(state["student"])
        distiller.pose_head.load_state_dict(state["pose_head"])
    if args.torch_threads:
        torch.set_num_threads(args.torch_threads)
    (args.out / "config.json").write_text(
        json.dumps({"student": saved["student"], "distill": dataclasses.asdict(settings)}, indent=2)
    )
    for iteration in range(start, args.iterations):
        tic = time.perf_counter()
        chunk, stats = distiller.collect_iteration(0.0, iteration, show_progress=True)
        ckpt.save_npz(args.out / "data" / f"iteration{iteration}.npz", chunk)
        distiller.data.add(chunk)
        loss, loss_mean, _ = distiller.regress(
            args.updates, iteration, show_progress=True, decay_over=(0, args.updates)
        )
        scores = distiller.validate()
        row = {
            "iteration": iteration,
            "new_states": distiller.data.new_size,
            "pool_states": distiller.data.pool_size,
            **stats,
            "loss": loss,
            "loss_mean": loss_mean,
            **{f"validation/{k}": v for k, v in scores.items()},
            "seconds": round(time.perf_counter() - tic, 1),
        }
        distiller.history.append(row)
        print(json.dumps(row), flush=True)
        payload = distiller.policy_payload(iteration)
        payload["continued"] = {
            "source": str(args.source),
            "iteration": iteration,
            "updates": args.updates,
            "new_share": args.new_share,
            "seed": args.seed,
        }
        ckpt.save_torch(args.out / f"policy_iteration{iteration}.pt", payload)
        ckpt.save_torch(args.out / POLICY_NAME, payload)
        ckpt.save_torch(resume, distiller.resume_state())
    summary = {
        "source": str(args.source),
        "iterations": args.iterations,
        "updates": args.updates,
        "new_share": args.new_share,
        "seed": args.seed,
        "driver_noise": settings.driver_noise,
        "set": args.set,
        "torch_threads": args.torch_threads or student.loop.torch_threads,
        "history": distiller.history,
    }
    (args.out / "continue.json").write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
