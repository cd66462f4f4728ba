"""Pooled distillation data, in memory and memory-mapped from a cache."""

from __future__ import annotations

import os

import numpy as np
import pytest

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.pooled import MANIFEST_NAME, ReadAhead, data_files, load_pooled


def _write_run(run, sizes, views=3, seed=0):
    rng = np.random.default_rng(seed)
    for i, n in enumerate(sizes):
        chunk = {
            "images": rng.integers(0, 256, (n, views, 4, 6, 6), dtype=np.uint8),
            "proprio": rng.normal(size=(n, 9)).astype(np.float32),
            "label": rng.normal(size=(n, 6)).astype(np.float32),
        }
        ckpt.save_npz(run / "data" / f"iteration{i}.npz", chunk)


@pytest.fixture
def runs(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    _write_run(a, [5, 7, 4], seed=1)
    _write_run(b, [6, 3], seed=2)
    return a, b


def test_data_files_in_iteration_order(tmp_path):
    _write_run(tmp_path, [1] * 11)
    names = [p.name for p in data_files(tmp_path)]
    assert names[:3] == ["iteration0.npz", "iteration1.npz", "iteration2.npz"]
    assert names[-1] == "iteration10.npz"
    assert len(data_files(tmp_path, 2)) == 2


def test_pool_concatenates_sources_and_cuts_views(runs):
    a, b = runs
    pool = load_pooled([(a, 2), (b, None)], views=2)
    assert len(pool["label"]) == 5 + 7 + 6 + 3
    assert pool["images"].shape[1:] == (2, 4, 6, 6)
    first = ckpt.load_npz(a / "data" / "iteration0.npz")
    np.testing.assert_array_equal(pool["images"][:5], first["images"][:, :2])
    last = ckpt.load_npz(b / "data" / "iteration1.npz")
    np.testing.assert_array_equal(pool["label"][-3:], last["label"])


def test_cached_pool_equals_the_pool_in_memory_and_is_reused(runs, tmp_path):
    a, b = runs
    sources = [(a, None), (b, None)]
    cache = tmp_path / "cache"
    in_memory = load_pooled(sources, views=3)
    mapped = load_pooled(sources, views=3, cache=cache)
    assert sorted(mapped) == sorted(in_memory)
    for key, array in in_memory.items():
        assert isinstance(mapped[key], np.memmap)
        np.testing.assert_array_equal(mapped[key], array)
    with pytest.raises(ValueError):
        mapped["label"][0] = 0.0  # read-only: a job never changes the shared pool
    stamp = (cache / "images.npy").stat().st_mtime_ns
    again = load_pooled(sources, views=3, cache=cache)
    assert (cache / "images.npy").stat().st_mtime_ns == stamp  # not written again
    np.testing.assert_array_equal(again["images"], in_memory["images"])


def test_cache_is_rebuilt_when_its_inputs_change(runs, tmp_path):
    a, b = runs
    cache = tmp_path / "cache"
    load_pooled([(a, None), (b, None)], views=3, cache=cache)
    two_views = load_pooled([(a, None), (b, None)], views=2, cache=cache)
    assert two_views["images"].shape[1] == 2
    fewer = load_pooled([(a, 1)], views=2, cache=cache)
    assert len(fewer["label"]) == 5
    _write_run(a, [2], seed=9)  # iteration0 rewritten: other states
    os.utime(a / "data" / "iteration0.npz", ns=(1, 1))
    rewritten = load_pooled([(a, 1)], views=2, cache=cache)
    np.testing.assert_array_equal(
        rewritten["label"], ckpt.load_npz(a / "data" / "iteration0.npz")["label"]
    )


def test_half_written_cache_is_not_trusted(runs, tmp_path):
    a, _ = runs
    cache = tmp_path / "cache"
    load_pooled([(a, None)], views=3, cache=cache)
    (cache / MANIFEST_NAME).unlink()  # as after a crash while writing
    np.save(cache / "label.npy", np.zeros((16, 6), np.float32))
    pool = load_pooled([(a, None)], views=3, cache=cache)
    np.testing.assert_array_equal(pool["label"], load_pooled([(a, None)], views=3)["label"])


def test_bad_input_is_refused(runs, tmp_path):
    a, _ = runs
    with pytest.raises(FileNotFoundError, match="no data"):
        load_pooled([(tmp_path / "empty", None)], views=3)
    with pytest.raises(ValueError, match="fewer than 4"):
        load_pooled([(a, None)], views=4)


def test_relabelled_cached_pool_equals_the_relabelled_pool_in_memory(runs, tmp_path, monkeypatch):
    a, b = runs
    monkeypatch.setattr("clamgen.experiments.pooled.RELABEL_CHUNK", 4)  # several calls per run

    def relabel(chunk):  # a label that depends on the chunk's inputs, not on its position
        return chunk["proprio"][:, :6] + chunk["images"].mean(axis=(1, 2, 3, 4))[:, None]

    sources = [(a, None), (b, None)]
    in_memory = load_pooled(sources, views=2, relabel=relabel)
    cache = tmp_path / "cache"
    mapped = load_pooled(sources, views=2, relabel=relabel, cache=cache)
    np.testing.assert_allclose(mapped["label"], in_memory["label"], rtol=1e-6)
    np.testing.assert_array_equal(mapped["images"], in_memory["images"])
    assert not np.allclose(mapped["label"], load_pooled(sources, views=2)["label"])
    # the cache keeps the teachers' labels for the next job
    np.testing.assert_array_equal(
        load_pooled(sources, views=2, cache=cache)["label"], load_pooled(sources, views=2)["label"]
    )


@pytest.mark.skipif(not hasattr(os, "posix_fadvise"), reason="read-ahead needs posix_fadvise")
def test_cached_image_rows_of_a_page_or_more_are_read_ahead_row_by_row(tmp_path, monkeypatch):
    run = tmp_path / "run"
    rng = np.random.default_rng(3)
    images = rng.integers(0, 256, (9, 3, 4, 20, 20), dtype=np.uint8)  # 4800-byte rows
    label = rng.normal(size=(9, 6)).astype(np.float32)
    ckpt.save_npz(run / "data" / "iteration0.npz", {"images": images, "label": label})
    pool = load_pooled([(run, None)], views=3, cache=tmp_path / "cache")
    assert isinstance(pool["images"], ReadAhead)
    assert isinstance(pool["label"], np.memmap)  # small rows: the map as it is

    asked = []
    monkeypatch.setattr(os, "posix_fadvise", lambda fd, start, size, advice: asked.append(start))
    index = np.array([7, 2, 7, -1])
    np.testing.assert_array_equal(pool["images"][index], images[index])
    offset = pool["images"].array.offset
    assert asked == [offset + 2 * 4800, offset + 7 * 4800, offset + 8 * 4800]  # each row once
    asked.clear()
    np.testing.assert_array_equal(pool["images"][[1, 4]], images[[1, 4]])
    assert len(asked) == 2
    asked.clear()
    np.testing.assert_array_equal(pool["images"][3:6], images[3:6])
    np.testing.assert_array_equal(pool["images"][5], images[5])
    assert asked == []  # slices and single rows read the map directly
    np.testing.assert_array_equal(np.asarray(pool["images"]), images)
    assert pool["images"].shape == images.shape and len(pool["images"]) == 9
    with pytest.raises(TypeError):
        pool["images"][0] = 0  # read-only
