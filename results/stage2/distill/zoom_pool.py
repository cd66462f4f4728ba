"""Render the zoomed views of a pooled distillation cache's states (beyond the paper).

    python results/stage2/distill/zoom_pool.py runs/pool-cache/d3-pool4-48k --runs 2

A pool cache (`offline.py --pool-cache`, `clamgen.experiments.pooled`) holds each state's
views as the DAgger runs rendered them, and what determines the scene: the arm's joints
(`observation`), the target (`desired_goal`) and the obstacles' poses. This renders, for the
states of the cache's first `--runs` runs, the zoomed view of each of the views' cameras
(`ReachEnv(zoom_views=True)`: the camera's position, turned to the target, `ZOOM_FOVY_DEG`) at
the views' size, into `CACHE/zoom.npy` (rows, V, 4, H, W) uint8, in `--workers` processes,
and writes `CACHE/zoom.json` (rows, views, the field of view, the cache's inputs). A student
regressed with `offline.py ... --zoom-cache` reads the cached views and these together, as
an env with `zoom_views` renders them.
"""

from __future__ import annotations

import argparse
import itertools
import json
import multiprocessing as mp
from pathlib import Path

import numpy as np
from tqdm import tqdm

from clamgen.experiments.pooled import apply_row, cache_files

ZOOM_NAME = "zoom.npy"
RECORD_NAME = "zoom.json"
CHUNK = 500  # rows per progress update and per flush


def _rows_of_runs(cache: Path, runs: int) -> int:
    """Rows of the cache's first `runs` runs (its files are in run order, each run's in
    iteration order under RUN/data/)."""
    files = cache_files(cache)
    first = list(dict.fromkeys(path.parent.parent for path, _ in files))[:runs]
    return sum(rows for path, rows in files if path.parent.parent in first)


def _render(cache: Path, start: int, stop: int, views: int, size: int, queue) -> None:
    import mujoco

    from clamgen.sim.render import MultiViewRenderer
    from clamgen.sim.scene import Scene
    from clamgen.sim.state import images_from_render

    joints = np.load(cache / "observation.npy", mmap_mode="r")
    goals = np.load(cache / "desired_goal.npy", mmap_mode="r")
    obstacles = np.load(cache / "obstacles.npy", mmap_mode="r")
    out = np.load(cache / ZOOM_NAME, mmap_mode="r+")
    scene = Scene()
    renderer = MultiViewRenderer(scene.model, scene.zoom_camera_ids[:views], size, size)
    for first in range(start, stop, CHUNK):
        last = min(first + CHUNK, stop)
        for row in range(first, last):
            apply_row(scene, joints[row], goals[row], obstacles[row])
            mujoco.mj_camlight(scene.model, scene.data)
            out[row] = images_from_render(*renderer.render(scene.data))
        out.flush()
        queue.put(last - first)
    renderer.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cache", type=Path, help="a pool cache directory (offline.py --pool-cache)")
    parser.add_argument("--runs", type=int, default=2, help="the cache's first RUNS runs' states")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    manifest = json.loads((args.cache / "manifest.json").read_text())
    images = np.load(args.cache / "images.npy", mmap_mode="r")
    views, size = images.shape[1], images.shape[-1]
    rows = _rows_of_runs(args.cache, args.runs)
    from clamgen.sim import constants as C

    record = {
        "rows": rows,
        "runs": args.runs,
        "views": views,
        "size": size,
        "fovy_deg": C.ZOOM_FOVY_DEG,
        "inputs": manifest["inputs"],
    }
    record_path = args.cache / RECORD_NAME
    if record_path.exists() and json.loads(record_path.read_text()) == record:
        print(f"{args.cache / ZOOM_NAME} is complete ({rows} rows)")
        return
    record_path.unlink(missing_ok=True)  # a half-written file is never trusted
    np.lib.format.open_memmap(
        args.cache / ZOOM_NAME, mode="w+", dtype=np.uint8, shape=(rows, views, 4, size, size)
    ).flush()
    bounds = np.linspace(0, rows, args.workers + 1).astype(int)
    queue = mp.get_context("spawn").Queue()
    workers = [
        mp.get_context("spawn").Process(
            target=_render, args=(args.cache, lo, hi, views, size, queue)
        )
        for lo, hi in itertools.pairwise(bounds)
    ]
    for worker in workers:
        worker.start()
    with tqdm(total=rows, desc="zoomed views", unit="state") as bar:
        done = 0
        while done < rows:
            count = queue.get()
            done += count
            bar.update(count)
    for worker in workers:
        worker.join()
        if worker.exitcode:
            raise SystemExit(f"a rendering worker failed (exit code {worker.exitcode})")
    record_path.write_text(json.dumps(record, indent=1))
    print(f"wrote {args.cache / ZOOM_NAME} ({rows} rows)")


if __name__ == "__main__":
    main()
