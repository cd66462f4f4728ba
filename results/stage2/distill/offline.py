"""Regress a fresh student on a finished distillation's data: compare regression settings cheaply.

    python results/stage2/distill/offline.py runs/distill/d2 runs/offline/d2-scale \
        --updates 24000 --set pose_length_scale_m=0.05

A DAgger run spends most of its time collecting; its data (`RUN/data/iteration*.npz`: the
student's inputs and the teacher's labels of every visited state) can train other students
with no collection at all. This builds the run's student afresh (same config and seed, with the
`--set` changes to its distill settings), regresses it `--updates` steps on all of the run's
data, scores it on the distillation's 100 validation tasks, and writes `policy.pt` and
`student.pt` (which `pose_error.py` and `validate.py` read) to OUT. Behaviour cloning on the
DAgger data, not DAgger: use it to compare losses and data, not as a final student.

`--iterations K` uses the run's first K iterations only (how success grows with data);
`--pool RUN ...` adds the data of other runs of the same teacher, their views cut to the
student's (a 3-view run's data holds the first two cameras a 2-view student sees);
`--relabel POLICY ...` replaces the teacher's labels by the mean of those policies' pre-squash
means on each state (distilling an ensemble of students into one, `results/stage2/ensemble/`);
`--pool-cache DIR` memory-maps the pooled data from uncompressed copies in DIR (written by the
first job), so that two jobs on the same pool share one copy in memory
(`clamgen.experiments.pooled`; the same values, the same regression; relabelled labels are
held in memory beside the mapped images).

The regression saves its progress to `OUT/offline_progress.pt` every CHECKPOINT_UPDATES
updates (weights, optimizer, random streams): the same command run again after a kill goes on
from there (and refuses a progress file of other options); the file is removed once OUT is
complete. `offline.json` holds the last batch's loss (`loss`) and its mean over the last
chunk's updates (`loss_mean`, over `loss_mean_updates`: the steadier reading), and the
regression's wall time (`regression_seconds`, summed over the processes that ran it).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from bins import BinDistiller
from chunks import ChunkDistiller, future_labels  # (this directory: the script's own)
from collisions import CollisionDistiller, load_labels
from tqdm import tqdm

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import config_from_json, config_to_json, parse_assignments
from clamgen.experiments.distill import (
    STATE_NAME,
    DistillConfig,
    Distiller,
    DistillSettings,
    RegressionLoss,
)
from clamgen.experiments.pooled import JoinedViews, Rows, file_lengths, load_pooled, subset
from clamgen.experiments.stage2 import Stage2Config
from clamgen.experiments.stall import pool_episodes, pool_stall_counts
from clamgen.experiments.train import POLICY_NAME

RELABEL_BATCH = 256
PROGRESS_NAME = "offline_progress.pt"
CHECKPOINT_UPDATES = 1000  # about a minute of regression on one core


def mean_labels(agents: list, chunk: dict[str, np.ndarray]) -> np.ndarray:
    """(N, A) the mean over `agents` of their pre-squash means (`ResidualAgent.mean_action`:
    what a student regresses) on the states of a data chunk, in batches of RELABEL_BATCH."""
    out = np.empty_like(chunk["label"])
    for start in range(0, len(out), RELABEL_BATCH):
        obs = {k: v[start : start + RELABEL_BATCH] for k, v in chunk.items() if k != "label"}
        out[start : start + RELABEL_BATCH] = np.mean([a.mean_action(obs) for a in agents], axis=0)
    return out


def with_defaults(job: dict) -> dict:
    """`job` with every student and distill setting it lacks at its default: a regression
    saved before a setting existed ran with that setting's default, so it is the same job as
    one that names the default (and resumes)."""
    student = config_from_json(json.dumps(job["student"]), Stage2Config)
    return {
        **job,
        "student": json.loads(config_to_json(student)),
        "distill": dataclasses.asdict(DistillSettings(**job["distill"])),
    }


def regress_resumably(
    distiller: Distiller, updates: int, out: Path, job: dict, cosine: bool = False
) -> tuple[RegressionLoss, float]:
    """`distiller.regress(updates)` in chunks of CHECKPOINT_UPDATES, its state saved to
    `out/PROGRESS_NAME` after each: run again, it goes on after the last saved chunk (the same
    batches and weights as one uninterrupted run). With `cosine` the learning rate falls from
    the distill `lr` to 0 along one cosine over all `updates`. `job` (JSON values) names the
    regression; a progress file of another job is refused. Returns the last chunk's
    `RegressionLoss` (its mean over that chunk's updates) and the regression's wall time in
    seconds, summed over the processes that ran it."""
    path = out / PROGRESS_NAME
    done, loss, seconds = 0, RegressionLoss(None, None), 0.0
    if path.exists():
        state = ckpt.load_torch(path, kind="offline-progress")
        if with_defaults(state["job"]) != with_defaults(job):
            raise SystemExit(
                f"{path} is the progress of a regression with other options: "
                "run the same command, or remove it to start again"
            )
        distiller.load_regression_state(state)
        # (progress saved before the chunk's mean was kept has its last batch's loss alone)
        done, seconds = state["done"], state.get("seconds", 0.0)
        loss = RegressionLoss(state["loss"], state.get("loss_mean"), state.get("loss_batches", 0))
        print(f"resumed after {done} of {updates} updates")
    out.mkdir(parents=True, exist_ok=True)
    with tqdm(total=updates, initial=done, desc="offline regression", unit="update") as bar:
        while done < updates:
            steps = min(CHECKPOINT_UPDATES, updates - done)
            decay_over = (done, updates) if cosine else None
            tic = time.perf_counter()
            loss = distiller.regress(steps, "offline", show_progress=False, decay_over=decay_over)
            done, seconds = done + steps, seconds + time.perf_counter() - tic
            state = {
                "format": ckpt.FORMAT,
                "kind": "offline-progress",
                "job": job,
                "done": done,
                "loss": loss.last,
                "loss_mean": loss.mean,
                "loss_batches": loss.batches,
                "seconds": seconds,
                **distiller.regression_state(),
            }
            ckpt.save_torch(path, state)
            bar.update(steps)
            bar.set_postfix(loss=f"{loss.mean:.4f}")
    return loss, seconds


def add_settings_option(parser: argparse.ArgumentParser, example: str) -> None:
    """`--set FIELD=VALUE ...`: distill settings to change (`settings_changes` reads them)."""
    parser.add_argument(
        "--set",
        nargs="+",
        action="extend",
        default=[],
        metavar="FIELD=VALUE",
        help=f"distill settings to change, {example} (repeatable)",
    )


def settings_changes(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    """The `--set` items as typed distill settings; a bad one ends the command in one line."""
    try:
        return parse_assignments(DistillSettings, args.set)
    except ValueError as error:
        parser.error(f"--set: {error}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--updates", type=int, default=24_000, help="regression steps (>= 1)")
    parser.add_argument("--iterations", type=int, default=None, help="the run's first K only")
    parser.add_argument("--pool", type=Path, nargs="*", default=[], help="other runs' data too")
    parser.add_argument(
        "--hidden-sizes",
        type=int,
        nargs="+",
        default=None,
        help="the student's actor and critic hidden layers (default: the run's)",
    )
    parser.add_argument(
        "--actor-components",
        type=int,
        default=None,
        help="the student's mixture components (agent.actor_components; default: the run's)",
    )
    parser.add_argument(
        "--view-dropout",
        type=float,
        default=None,
        help="the student's view dropout in the regression (agent.view_dropout; default: the "
        "run's)",
    )
    parser.add_argument(
        "--center-crops",
        action="store_true",
        help="the regression takes the centre crop of every view, as acting does, instead of "
        "random crops (agent.train_crops center; beyond the paper)",
    )
    parser.add_argument(
        "--shift-padding",
        type=int,
        default=None,
        metavar="K",
        help="widen the regression's random crops by K pixels of repeated edge on every side "
        "(agent.train_shift_padding; DrQ's random shift; beyond the paper)",
    )
    parser.add_argument(
        "--goal-offset",
        action="store_true",
        help="the student also reads the tip's offset to the goal (agent.goal_offset; beyond "
        "the paper)",
    )
    parser.add_argument(
        "--encoder-channels",
        type=int,
        default=None,
        help="channels of the student's convolutions (agent.encoder.num_channels; default: "
        "the run's)",
    )
    parser.add_argument(
        "--spatial-softmax",
        action="store_true",
        help="end each view's convolutions in a spatial softmax: 2 keypoint coordinates per "
        "channel instead of the flattened map (agent.encoder.spatial_softmax)",
    )
    parser.add_argument(
        "--encoder-strides",
        type=int,
        nargs="+",
        default=None,
        metavar="S",
        help="stride of each of the student's conv layers (agent.encoder.strides; default: "
        "the run's)",
    )
    parser.add_argument(
        "--num-views",
        type=int,
        default=None,
        help="a student that sees fewer views than the run's (its first N cameras)",
    )
    parser.add_argument(
        "--data-views",
        type=int,
        default=None,
        help="views the pooled data keeps (default: the student's); a privileged student, "
        "which reads none, on a vision pool's --pool-cache passes that cache's count",
    )
    parser.add_argument(
        "--zoom",
        action="store_true",
        help="a student that also sees each view's zoomed view (env.zoom_views, beyond the "
        "paper): regresses on the --pool-cache states whose zoomed views zoom_pool.py rendered",
    )
    parser.add_argument(
        "--rows",
        type=int,
        default=None,
        metavar="N",
        help="regress on the pool's first N states only (with --zoom: those zoom_pool.py "
        "rendered, by default)",
    )
    parser.add_argument(
        "--chunk",
        type=int,
        default=None,
        metavar="K",
        help="also regress a chunk head on each state's next K labels (chunks.py; beyond the "
        "paper), saved as OUT/chunk_head.pt",
    )
    parser.add_argument(
        "--bins",
        type=int,
        default=None,
        metavar="K",
        help="also regress a bin head: the labels as a choice among K k-means centres with an "
        "offset (bins.py; beyond the paper), saved as OUT/bin_head.pt",
    )
    parser.add_argument(
        "--collision-labels",
        type=Path,
        default=None,
        metavar="DIR",
        help="also regress a collision head on these states' labelled actions (collisions.py; "
        "a learned_shield.py prepare output for the same first states; beyond the paper), "
        "saved as OUT/head.pt",
    )
    parser.add_argument(
        "--stalled-only",
        type=int,
        default=None,
        metavar="K",
        help="regress on the states whose episode's tip has not come nearer its target for K "
        "steps or more only (an escape student, clamgen.experiments.stall)",
    )
    parser.add_argument(
        "--relabel",
        nargs="*",
        default=[],
        metavar="POLICY",
        help="label every state with the mean of these policies' actions instead of the teacher's",
    )
    parser.add_argument(
        "--cosine",
        action="store_true",
        help="decay the learning rate from the distill lr to 0 along a cosine over the "
        "regression (default: constant, as every earlier regression)",
    )
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=None,
        help="threads for the regression (default: the run's loop.torch_threads); not saved",
    )
    parser.add_argument(
        "--pool-cache",
        type=Path,
        default=None,
        metavar="DIR",
        help="memory-map the pooled data from DIR (written there first): jobs on the same "
        "pool share one copy in memory",
    )
    add_settings_option(parser, "e.g. pose_length_scale_m=0.05")
    args = parser.parse_args()
    if args.updates < 1:
        parser.error(f"--updates must be at least 1, got {args.updates}")
    changes = settings_changes(parser, args)
    if not (args.run_dir / "config.json").is_file():
        parser.error(f"{args.run_dir} has no config.json: not a `clamgen distill` run")
    saved = json.loads((args.run_dir / "config.json").read_text())
    student = config_from_json(json.dumps(saved["student"]), Stage2Config)
    student = dataclasses.replace(student, run_dir=args.out)
    agent_changes = {}
    if args.hidden_sizes:
        agent_changes["hidden_sizes"] = tuple(args.hidden_sizes)
    if args.actor_components:
        agent_changes["actor_components"] = args.actor_components
    if args.view_dropout is not None:
        agent_changes["view_dropout"] = args.view_dropout
    if args.goal_offset:
        agent_changes["goal_offset"] = True
    if args.center_crops:
        agent_changes["train_crops"] = "center"
    if args.shift_padding is not None:
        agent_changes["train_shift_padding"] = args.shift_padding
    env = student.env
    if args.encoder_channels:
        agent_changes["encoder"] = dataclasses.replace(
            student.agent.encoder, num_channels=args.encoder_channels
        )
    if args.spatial_softmax or args.encoder_strides:
        encoder = agent_changes.get("encoder", student.agent.encoder)
        strides = tuple(args.encoder_strides) if args.encoder_strides else encoder.strides
        agent_changes["encoder"] = dataclasses.replace(
            encoder,
            spatial_softmax=args.spatial_softmax or encoder.spatial_softmax,
            strides=strides,
        )
    if args.num_views:
        encoder = agent_changes.get("encoder", student.agent.encoder)
        agent_changes["encoder"] = dataclasses.replace(encoder, num_views=args.num_views)
        env = dataclasses.replace(env, num_views=args.num_views)
    if args.zoom:
        if args.pool_cache is None:
            raise SystemExit("--zoom reads the zoomed views beside a --pool-cache")
        encoder = agent_changes.get("encoder", student.agent.encoder)
        agent_changes["encoder"] = dataclasses.replace(encoder, num_views=2 * encoder.num_views)
        env = dataclasses.replace(env, zoom_views=True)
    if agent_changes:
        agent = dataclasses.replace(student.agent, **agent_changes)
        student = dataclasses.replace(student, agent=agent, env=env)
        saved["student"] = json.loads(config_to_json(student))
    # No lookahead: nothing is collected, so the teacher only has to load.
    settings = DistillSettings(**{**saved["distill"], **changes, "lookahead_candidates": 0})
    heads = {  # options that regress another head beside the student, and their distillers
        "--chunk": (args.chunk, ChunkDistiller),
        "--bins": (args.bins, BinDistiller),
        "--collision-labels": (args.collision_labels, CollisionDistiller),
    }
    chosen = [name for name, (value, _) in heads.items() if value]
    if len(chosen) > 1:
        raise SystemExit(f"{' and '.join(chosen)} each add a head: one at a time")
    make = heads[chosen[0]][1] if chosen else Distiller
    distiller = make(DistillConfig(student=student, distill=settings))
    views = student.env.num_views if args.data_views is None else args.data_views
    relabellers = []
    if args.relabel:
        from clamgen.experiments.policies import load_policy

        torch.set_num_threads(student.loop.torch_threads)
        relabellers = [load_policy(name)[0].agent for name in args.relabel]
    sources = [(args.run_dir, args.iterations), *((run, None) for run in args.pool)]
    relabel = (lambda chunk: mean_labels(relabellers, chunk)) if relabellers else None
    try:
        distiller.data.arrays = load_pooled(sources, views, relabel, args.pool_cache)
    except (FileNotFoundError, ValueError) as error:
        raise SystemExit(str(error)) from None
    episode = None  # the pool's episode numbers, for --chunk
    if args.chunk:
        if args.stalled_only is not None:
            raise SystemExit("--chunk takes each state's episode: not with --stalled-only")
        episode = pool_episodes(distiller.data.arrays["obstacles"], file_lengths(sources))
    rows = args.rows
    if rows is not None and args.stalled_only is not None:
        raise SystemExit("--stalled-only counts stalls over the whole pool: not with --rows")
    if args.zoom:
        zoom = np.load(args.pool_cache / "zoom.npy", mmap_mode="r")
        rows = len(zoom) if rows is None else rows
        if rows > len(zoom):
            raise SystemExit(f"--rows {rows}: zoom_pool.py rendered {len(zoom)} states")
    if rows is not None:
        if not 0 < rows <= len(distiller.data):
            raise SystemExit(f"--rows must be in 1..{len(distiller.data)}, got {rows}")
        distiller.data.arrays = subset(distiller.data.arrays, np.arange(rows))
        if args.zoom:
            images = distiller.data.arrays["images"]
            distiller.data.arrays["images"] = JoinedViews(images, Rows(zoom, np.arange(rows)))
        print(f"regressing on the first {rows} states" + (" with their zoomed views" * args.zoom))
    if args.chunk:
        episode = episode[: len(distiller.data)]  # (the first rows hold whole data files)
        labels = np.asarray(distiller.data.arrays["label"])
        distiller.attach_chunks(future_labels(labels, episode, args.chunk))
        print(f"chunk head on the next {args.chunk} labels of {len(np.unique(episode))} episodes")
    if args.bins:
        if args.stalled_only is not None:
            raise SystemExit(
                "--bins fits its centres on the regression's states: not with --stalled-only"
            )
        distiller.attach_bins(args.bins)
        print(f"bin head on {args.bins} k-means centres of the labels")
    if args.collision_labels:
        if args.stalled_only is not None:
            raise SystemExit("--collision-labels label the first states: not with --stalled-only")
        distiller.attach_collisions(*load_labels(args.collision_labels, len(distiller.data)))
        print(f"collision head on {args.collision_labels}'s labelled actions")
    if args.stalled_only is not None:
        arrays = distiller.data.arrays
        counts = pool_stall_counts(
            arrays["achieved_goal"],
            arrays["desired_goal"],
            arrays["obstacles"],
            file_lengths(sources),
        )
        stalled = np.flatnonzero(counts >= args.stalled_only)
        print(f"{len(stalled)} of {len(counts)} states stalled {args.stalled_only} steps or more")
        distiller.data.arrays = subset(arrays, stalled)
    if args.torch_threads:
        torch.set_num_threads(args.torch_threads)
    job = {
        "student": saved["student"],
        "distill": dataclasses.asdict(settings),
        "sources": [[str(run), iterations] for run, iterations in sources],
        "relabel": [str(name) for name in args.relabel],
        "updates": args.updates,
        **({"stalled_only": args.stalled_only} if args.stalled_only is not None else {}),
        **({"rows": rows} if rows is not None else {}),
        **({"zoom": True} if args.zoom else {}),
        **({"chunk": args.chunk} if args.chunk else {}),
        **({"collision_labels": str(args.collision_labels)} if args.collision_labels else {}),
        **({"bins": args.bins} if args.bins else {}),
        **({"cosine": True} if args.cosine else {}),
    }
    loss, seconds = regress_resumably(distiller, args.updates, args.out, job, args.cosine)
    scores = distiller.validate()
    payload = distiller.policy_payload("offline")
    payload["offline"] = {
        "source": str(args.run_dir),
        "iterations": args.iterations,
        "pool": [str(run) for run in args.pool],
        "relabel": [str(name) for name in args.relabel],
        "samples": len(distiller.data),
        "updates": args.updates,
    }
    ckpt.save_torch(args.out / POLICY_NAME, payload)
    if chosen:
        distiller.save_head(args.out)
    state = {
        "student": distiller.student.state_dict(),
        "pose_head": distiller.pose_head.state_dict(),
        "settings": dataclasses.asdict(settings),
        "source": str(args.run_dir),
        "pool": [str(run) for run in args.pool],
        "updates": args.updates,
    }
    ckpt.save_torch(args.out / STATE_NAME, {"format": ckpt.FORMAT, "kind": "distill", **state})
    (args.out / "config.json").write_text(
        json.dumps({"student": saved["student"], "distill": dataclasses.asdict(settings)}, indent=2)
    )
    row = {
        "source": str(args.run_dir),
        "iterations": args.iterations,
        "pool": [str(run) for run in args.pool],
        "relabel": [str(name) for name in args.relabel],
        "samples": len(distiller.data),
        "stalled_only": args.stalled_only,
        "rows": rows,
        "zoom": args.zoom,
        "chunk": args.chunk,
        "collision_labels": str(args.collision_labels) if args.collision_labels else None,
        "bins": args.bins,
        "changes": changes,
        "updates": args.updates,
        "torch_threads": args.torch_threads or student.loop.torch_threads,
        "hidden_sizes": list(student.agent.hidden_sizes),
        "encoder_channels": student.agent.encoder.num_channels,
        "encoder_strides": list(student.agent.encoder.strides),
        "spatial_softmax": student.agent.encoder.spatial_softmax,
        "view_dropout": student.agent.view_dropout,
        "actor_components": student.agent.actor_components,
        "goal_offset": student.agent.goal_offset,
        "train_crops": student.agent.train_crops,
        "train_shift_padding": student.agent.train_shift_padding,
        "cosine": args.cosine,
        "loss": loss.last,
        "loss_mean": loss.mean,
        "loss_mean_updates": loss.batches,
        "regression_seconds": round(seconds, 1),
    }
    row |= {f"validation/{k}": v for k, v in scores.items()}
    print(json.dumps(row))
    with (args.out / "offline.json").open("w") as f:
        json.dump(row, f, indent=2)
    (args.out / PROGRESS_NAME).unlink()


if __name__ == "__main__":
    main()
