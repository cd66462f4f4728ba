"""Regress a fresh student on a finished distillation's data: compare regression settings cheaply.

    python results/stage2/distill/offline.py runs/distill/d2 runs/offline/d2-scale \
        --updates 24000 --set pose_length_scale_m=0.05

A DAgger run spends most of its time collecting; its data (`RUN/data/iteration*.npz`: the
student's inputs and the teacher's labels of every visited state) can train other students
with no collection at all. This builds the run's student afresh (same config and seed, with the
`--set` changes to its distill settings), regresses it `--updates` steps on all of the run's
data, scores it on the distillation's 100 validation tasks, and writes `policy.pt` and
`student.pt` (which `pose_error.py` and `validate.py` read) to OUT. Behaviour cloning on the
DAgger data, not DAgger: use it to compare losses, not as a final student.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import config_from_json
from clamgen.experiments.distill import (
    STATE_NAME,
    DistillConfig,
    Distiller,
    DistillSettings,
)
from clamgen.experiments.stage2 import Stage2Config
from clamgen.experiments.train import POLICY_NAME


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--updates", type=int, default=24_000)
    parser.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="FIELD=VALUE",
        help="distill settings to change, e.g. pose_length_scale_m=0.05",
    )
    args = parser.parse_args()
    saved = json.loads((args.run_dir / "config.json").read_text())
    student = config_from_json(json.dumps(saved["student"]), Stage2Config)
    student = dataclasses.replace(student, run_dir=args.out)
    changes = {}
    for item in args.set:
        name, _, value = item.partition("=")
        kind = type(getattr(DistillSettings(), name))
        changes[name] = kind(value)
    # No lookahead: nothing is collected, so the teacher only has to load.
    settings = DistillSettings(**{**saved["distill"], **changes, "lookahead_candidates": 0})
    distiller = Distiller(DistillConfig(student=student, distill=settings))
    for path in sorted((args.run_dir / "data").glob("iteration*.npz")):
        distiller.data.add(ckpt.load_npz(path))
    print(f"{len(distiller.data)} samples from {args.run_dir}; {args.updates} updates ...")
    loss = distiller._regress(args.updates, "offline", show_progress=True)
    scores = distiller._validate()
    args.out.mkdir(parents=True, exist_ok=True)
    ckpt.save_torch(args.out / POLICY_NAME, distiller._payload(0))
    state = {
        "student": distiller.student.state_dict(),
        "pose_head": distiller.pose_head.state_dict(),
        "settings": dataclasses.asdict(settings),
        "source": str(args.run_dir),
        "updates": args.updates,
    }
    ckpt.save_torch(args.out / STATE_NAME, {"format": ckpt.FORMAT, "kind": "distill", **state})
    (args.out / "config.json").write_text(
        json.dumps({"student": saved["student"], "distill": dataclasses.asdict(settings)}, indent=2)
    )
    row = {"source": str(args.run_dir), "changes": changes, "updates": args.updates, "loss": loss}
    row |= {f"validation/{k}": v for k, v in scores.items()}
    print(json.dumps(row))
    with (args.out / "offline.json").open("w") as f:
        json.dump(row, f, indent=2)


if __name__ == "__main__":
    main()
