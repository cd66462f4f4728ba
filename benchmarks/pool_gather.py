"""How fast a regression batch is gathered from a pool cache that is not in memory: the cache's
image rows read by page faults alone (the memory map as `np.load` gives it) against
`clamgen.experiments.pooled.ReadAhead` (the batch's rows asked for first, all at once), in the
same run on the same file, interleaved.

A cache larger than memory is mostly read from disk as it is sampled (the eight-run 3-view
pool: 28 GB on a 24 GB machine). Here the file is small, and it is dropped from the page cache
before every gather (`posix_fadvise(DONTNEED)`), so that every row comes from disk, as the
misses of a larger pool do. The rows are shaped like the 3-view pool's (3 RGBD views of 64 px,
48 KiB); a batch is `residual-cpu`'s 128 rows.

    python benchmarks/pool_gather.py                  # 1 GiB file, 30 gathers each
    python benchmarks/pool_gather.py --gib 0.25 --gathers 10   # quick look

Writes results/benchmarks/pool_gather.csv.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from common import write_csv

from clamgen.experiments.pooled import ReadAhead

ROW_SHAPE = (3, 4, 64, 64)  # a 3-view pool's image row, uint8
BATCH = 128


def write_cache(path: Path, rows: int, rng: np.random.Generator) -> None:
    """An `images.npy` of `rows` rows: a few random blocks repeated (fresh random bytes for a
    whole GiB would take longer than the measurement)."""
    array = np.lib.format.open_memmap(path, "w+", np.uint8, (rows, *ROW_SHAPE))
    blocks = rng.integers(0, 256, (64, *ROW_SHAPE), dtype=np.uint8)
    for start in range(0, rows, len(blocks)):
        end = min(start + len(blocks), rows)
        array[start:end] = blocks[: end - start]
    array.flush()
    del array


def evict(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gib", type=float, default=1.0, help="the cache file's size")
    parser.add_argument("--gathers", type=int, default=30, help="gathers timed for each way")
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: /tmp)")
    args = parser.parse_args()
    if args.gib <= 0 or args.gathers < 1:
        parser.error("--gib must be > 0 and --gathers >= 1")
    rng = np.random.default_rng(0)
    rows = max(BATCH, int(args.gib * 2**30 // np.prod(ROW_SHAPE)))
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        path = Path(tmp) / "images.npy"
        write_cache(path, rows, rng)
        ways = {
            "page faults": np.load(path, mmap_mode="r"),
            "ReadAhead": ReadAhead(path, np.load(path, mmap_mode="r")),
        }
        seconds = {name: [] for name in ways}
        for _ in range(args.gathers):
            for name, array in ways.items():
                index = rng.integers(0, rows, BATCH)
                evict(path)
                start = time.perf_counter()
                array[index]
                seconds[name].append(time.perf_counter() - start)
    median_ms = {name: float(np.median(times)) * 1000 for name, times in seconds.items()}
    ratio = median_ms["page faults"] / median_ms["ReadAhead"]
    gib = rows * np.prod(ROW_SHAPE) / 2**30
    print(f"cache {rows} rows ({gib:.2f} GiB), evicted each time")
    for name, ms in median_ms.items():
        print(f"{name:12s} {ms:7.1f} ms per {BATCH}-row gather (median of {args.gathers})")
    print(f"ReadAhead {ratio:.1f}x faster")
    row = {
        "cache_gib": round(gib, 2),
        "batch_rows": BATCH,
        "gathers": args.gathers,
        "page_faults_ms": round(median_ms["page faults"], 2),
        "read_ahead_ms": round(median_ms["ReadAhead"], 2),
        "ratio": round(ratio, 2),
    }
    print(f"wrote {write_csv('pool_gather', [row])}")


if __name__ == "__main__":
    main()
