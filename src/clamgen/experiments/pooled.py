"""Pooled distillation data: the states of several DAgger runs in one array per key.

A distillation run writes its (student input, teacher label) pairs as
`RUN/data/iteration*.npz`. Students regressed offline on several runs' data
(`results/stage2/distill/offline.py`, `continue_dagger.py`) hold all of it at once: four
3-view runs are 290k states, 14.4 GB of images, so two such jobs do not fit beside each other
on a 24 GB machine. With a cache directory the pool is written once as uncompressed `.npy`
files and memory-mapped read-only: every process that maps the same cache shares one copy in
the page cache, and the arrays hold the same values as the in-memory pool. A pool larger than
memory is read from disk as it is sampled; its image rows are asked for ahead of each gather
(`ReadAhead`), all of a batch's at once.
"""

from __future__ import annotations

import fcntl
import json
import os
import weakref
from collections.abc import Callable
from pathlib import Path

import numpy as np

from clamgen.experiments import checkpoint as ckpt

MANIFEST_NAME = "manifest.json"
LOCK_NAME = "lock"

RELABEL_CHUNK = 4096  # states read from a memory-mapped pool per relabelling call
READ_AHEAD_ROW_BYTES = 4096  # cached arrays with rows of at least a page are read row by row
Relabel = Callable[[dict[str, np.ndarray]], np.ndarray]


def data_files(run: Path, first: int | None = None) -> list[Path]:
    """A run's `data/iteration*.npz` in iteration order, the first `first` only if given."""
    paths = sorted(
        (Path(run) / "data").glob("iteration*.npz"),
        key=lambda p: int(p.stem[len("iteration") :]),
    )
    return paths[:first]


def _files(sources: list[tuple[Path, int | None]]) -> list[tuple[Path, list[Path]]]:
    per_run = [(Path(run), data_files(run, first)) for run, first in sources]
    if not any(paths for _, paths in per_run):
        names = ", ".join(str(run) for run, _ in sources)
        raise FileNotFoundError(f"no data/iteration*.npz under {names}")
    return per_run


def _fill(
    per_run: list[tuple[Path, list[Path]]],
    views: int,
    relabel: Relabel | None,
    allocate: Callable[[str, tuple[int, ...], np.dtype], np.ndarray],
) -> dict[str, np.ndarray]:
    """Every chunk copied into arrays allocated once from the chunks' total size: growing them
    by concatenation holds two copies at its peak (29 GB for four 3-view runs)."""
    total = 0
    for path in (path for _, paths in per_run for path in paths):
        with np.load(path, allow_pickle=False) as data:
            total += len(data["label"])
    arrays: dict[str, np.ndarray] = {}
    start = 0
    for run, paths in per_run:
        for path in paths:
            chunk = ckpt.load_npz(path)
            if "images" in chunk:  # a vision run's data; a privileged student's has none
                if chunk["images"].shape[1] < views:
                    have = chunk["images"].shape[1]
                    raise ValueError(f"{path} has {have} views, fewer than {views}")
                chunk["images"] = chunk["images"][:, :views]
            if relabel is not None:
                chunk["label"] = relabel(chunk)
            if not arrays:
                arrays = {k: allocate(k, (total, *v.shape[1:]), v.dtype) for k, v in chunk.items()}
            end = start + len(chunk["label"])
            for key, value in chunk.items():
                arrays[key][start:end] = value
            start = end
        print(f"{start} samples after {run} ({len(paths)} iterations)")
    return arrays


def load_pooled(
    sources: list[tuple[Path, int | None]],
    views: int,
    relabel: Relabel | None = None,
    cache: Path | None = None,
) -> dict[str, np.ndarray]:
    """The data of every (run, first K iterations or None for all) source in one array per
    key, images cut to the first `views` cameras, labels replaced by `relabel(chunk)` if given.

    With `cache`, the arrays are memory-mapped read-only from `cache/<key>.npy`, written there
    first unless the cache already holds exactly these files (paths, sizes, modification times)
    at this view count. Processes that start together wait on a lock while one writes it.
    The cache holds the teachers' labels: a relabelled pool maps the cache and holds its new
    labels in memory (they are small), read RELABEL_CHUNK states at a time."""
    per_run = _files(sources)
    if cache is None:
        return _fill(per_run, views, relabel, lambda _, shape, dtype: np.empty(shape, dtype))
    arrays = _mapped(per_run, views, Path(cache))
    if relabel is not None:
        arrays["label"] = _relabelled(arrays, relabel)
    return arrays


def _rows(path: Path) -> int:
    with np.load(path, allow_pickle=False) as data:
        return len(data["label"])


def file_lengths(sources: list[tuple[Path, int | None]]) -> list[int]:
    """The rows of each data file of `sources` (as `load_pooled`), in pool order."""
    return [_rows(path) for _, paths in _files(sources) for path in paths]


def cache_files(cache: Path) -> list[tuple[Path, int]]:
    """The data files a pool cache was written from, in pool order, with their rows."""
    manifest = json.loads((Path(cache) / MANIFEST_NAME).read_text())
    return [(Path(path), _rows(Path(path))) for path, *_ in manifest["inputs"]["files"]]


class Rows:
    """The rows `index` of an array (memory-mapped or not) without copying them: indexing
    picks from the array's own rows (`subset`)."""

    def __init__(self, array: np.ndarray, index: np.ndarray) -> None:
        self.array = array
        self.index = np.asarray(index, np.int64)
        self.shape = (len(self.index), *array.shape[1:])
        self.dtype = array.dtype

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, item) -> np.ndarray:
        return self.array[self.index[item]]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self.array[self.index]
        return out if dtype is None else out.astype(dtype)


class JoinedViews:
    """Two image arrays of the same rows, (N, V1, ...) and (N, V2, ...), side by side along the
    views axis without copying them: indexing gives their concatenation (N', V1 + V2, ...)."""

    def __init__(self, first, second) -> None:
        if len(first) != len(second) or first.shape[2:] != second.shape[2:]:
            raise ValueError(f"cannot join views of shapes {first.shape} and {second.shape}")
        self.first, self.second = first, second
        self.shape = (len(first), first.shape[1] + second.shape[1], *first.shape[2:])
        self.dtype = first.dtype

    def __len__(self) -> int:
        return len(self.first)

    def __getitem__(self, item) -> np.ndarray:
        return np.concatenate([self.first[item], self.second[item]], axis=1)


def subset(arrays: dict[str, np.ndarray], index: np.ndarray) -> dict[str, Rows]:
    """The pool's rows `index`, every key alike, without copying the images."""
    return {key: Rows(value, index) for key, value in arrays.items()}


def _relabelled(arrays: dict[str, np.ndarray], relabel: Relabel) -> np.ndarray:
    labels = np.empty(arrays["label"].shape, arrays["label"].dtype)
    for start in range(0, len(labels), RELABEL_CHUNK):
        chunk = {k: np.array(v[start : start + RELABEL_CHUNK]) for k, v in arrays.items()}
        labels[start : start + RELABEL_CHUNK] = relabel(chunk)
    print(f"{len(labels)} samples relabelled")
    return labels


def _inputs(per_run: list[tuple[Path, list[Path]]], views: int) -> dict:
    files = []
    for path in (path for _, paths in per_run for path in paths):
        stat = path.stat()
        files.append([str(path.resolve()), stat.st_size, stat.st_mtime_ns])
    return {"views": views, "files": files}


def _mapped(per_run: list[tuple[Path, list[Path]]], views: int, cache: Path) -> dict:
    cache.mkdir(parents=True, exist_ok=True)
    inputs = _inputs(per_run, views)
    manifest_path = cache / MANIFEST_NAME
    with (cache / LOCK_NAME).open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
        if manifest.get("inputs") != inputs:
            manifest_path.unlink(missing_ok=True)  # a half-written cache is never trusted

            def allocate(key: str, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
                return np.lib.format.open_memmap(cache / f"{key}.npy", "w+", dtype, shape)

            arrays = _fill(per_run, views, None, allocate)
            for array in arrays.values():
                array.flush()
            manifest = {"inputs": inputs, "keys": sorted(arrays)}
            del arrays
            text = json.dumps(manifest, indent=1)
            ckpt.atomic_write(manifest_path, lambda tmp: tmp.write_text(text))
            print(f"pool cached in {cache}")
        return {key: _open_mapped(cache / f"{key}.npy") for key in manifest["keys"]}


def _open_mapped(path: Path) -> np.ndarray | ReadAhead:
    array = np.load(path, mmap_mode="r")
    large = array[:1].nbytes >= READ_AHEAD_ROW_BYTES
    return ReadAhead(path, array) if large and hasattr(os, "posix_fadvise") else array  # Linux


class ReadAhead:
    """A memory-mapped array (rows of a page or more) whose gathers first ask the kernel for
    exactly the rows they read, all of them at once (`posix_fadvise(WILLNEED)`), then copy.

    Gathering rows of a pool larger than memory by page faults alone reads them one fault at a
    time, each with the kernel's read-around of the pages beside it: an eight-run 3-view pool
    (28 GB of 48 KB image rows on a 24 GB machine) regressed at 12.7 updates a second reading
    450 MB/s, most of it rows no batch asked for. Indexing with an integer array reads ahead;
    anything else (slices, single rows) reads the map as it is. Read-only, like the map."""

    def __init__(self, path: Path, array: np.memmap) -> None:
        self.array = array
        self.shape, self.dtype, self.ndim = array.shape, array.dtype, array.ndim
        self._row_bytes = array[:1].nbytes
        self._fd = os.open(path, os.O_RDONLY)
        weakref.finalize(self, os.close, self._fd)

    def __len__(self) -> int:
        return len(self.array)

    def __getitem__(self, item) -> np.ndarray:
        rows = np.asarray(item) if isinstance(item, np.ndarray | list) else None
        if rows is not None and rows.dtype.kind in "iu":
            for row in np.unique(rows % len(self.array)):
                start = self.array.offset + int(row) * self._row_bytes
                os.posix_fadvise(self._fd, start, self._row_bytes, os.POSIX_FADV_WILLNEED)
        return self.array[item]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return np.asarray(self.array, dtype)


def apply_row(scene, observation: np.ndarray, goal: np.ndarray, poses: np.ndarray) -> None:
    """Put `scene` (a `clamgen.sim.scene.Scene`) in the state one pooled row records: the arm's
    joints (the first 6 of `observation`), the target (`desired_goal`) and the obstacles' poses
    (a row of `obstacles`, `Obstacles.as_array`). The views
    rendered from it are the row's cached views (checked bit for bit on cached rows)."""
    from clamgen.sim.scene import Obstacles

    scene.set_obstacles(Obstacles.from_array(poses))
    scene.data.mocap_pos[scene.target_mocap] = goal
    scene.set_joints(np.asarray(observation[:6], np.float64))
