"""Checkpoints: resumable training state and small policy files, loaded with `weights_only`.

A training checkpoint is one directory, `checkpoints/ckpt-<generation>/`, written under a
temporary name and published by a single rename, so a kill at any instant leaves either the
whole new checkpoint or none of it (`CheckpointStore`). It holds

- `state.pt`: agent, progress, random states, config (torch, tensors only);
- `episodes.npz`: the environments' episodes in progress and the replay's counters;
- `replay/block-<b>.npz`: the replay's arrays in blocks of consecutive slots
  (`ReplayBuffer.block_arrays`). Only blocks changed since the previous checkpoint are
  written; the others are hard links to the previous checkpoint's files, so a checkpoint of a
  large image replay writes what was added since the last one, not the whole replay;
- `manifest.json`: the step, and the size and CRC-32 of every file above.

The previous checkpoint is removed only after the new one is published. A resume verifies the
newest checkpoint against its manifest and, if it is damaged, falls back to the previous one and
says so in one line.

A policy file (`export_policy`) holds what acting and stage 2 need: actor, critic, normaliser
and the config, a few hundred kB.

Nothing is pickled: `torch.load(..., weights_only=True)` and `numpy.load(allow_pickle=False)`.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import sys
import tempfile
import threading
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import torch

# Policies shipped inside the package (clamgen/checkpoints/), by name.
SHIPPED_POLICIES = {
    "base": "base.pt",
    "residual-3views": "residual-3views.pt",
    "residual-2views": "residual-2views.pt",
    "residual-1view": "residual-1view.pt",
    "image-only": "image-only.pt",
}


def resolve_policy_path(name: str | Path) -> Path:
    """A shipped policy's file, or `name` as a path."""
    if name in SHIPPED_POLICIES:
        return Path(str(files("clamgen") / "checkpoints" / SHIPPED_POLICIES[name]))
    return Path(name)


FORMAT = "clamgen"
TRAINING_KIND = "training-state"
POLICY_KIND = "sac-policy"


class CheckpointError(ValueError):
    """A checkpoint is missing, truncated, corrupt, or does not match what loads it."""


class DamagedCheckpointError(CheckpointError):
    """A checkpoint directory's files are missing, truncated or differ from its manifest."""


def atomic_write(path: Path, write) -> None:
    """Call `write(tmp_path)` then rename onto `path`, so a crash never leaves half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(Path(tmp))
        # mkstemp makes the file private (0600); give it the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def save_torch(path: Path, payload: dict[str, Any]) -> None:
    atomic_write(path, lambda tmp: torch.save(payload, tmp))


def load_torch(path: Path, kind: str | None) -> dict[str, Any]:
    """Load a clamgen torch file of `kind` (None: any kind), with errors that say what is
    wrong."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for truncated / foreign files
        raise CheckpointError(
            f"cannot read checkpoint {path} ({type(error).__name__}: {error}); the file is "
            "truncated, corrupt, or not a clamgen checkpoint"
        ) from error
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a clamgen checkpoint")
    if kind is not None and payload.get("kind") != kind:
        raise CheckpointError(f"{path} holds a {payload.get('kind')!r}, expected a {kind!r}")
    return payload


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    def write(tmp: Path) -> None:
        with tmp.open("wb") as f:
            np.savez(f, **arrays)

    atomic_write(path, write)


def load_npz(path: Path) -> dict[str, np.ndarray]:
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"replay snapshot not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except Exception as error:
        raise CheckpointError(f"cannot read replay snapshot {path}: {error}") from error


def load_agent_state(agent, state: dict[str, Any], source: Path) -> None:
    """`agent.load_state_dict(state)` with a clear error when the shapes do not match."""
    try:
        agent.load_state_dict(state)
    except (RuntimeError, KeyError, ValueError) as error:
        raise CheckpointError(
            f"{source} does not match this agent's configuration (network sizes, observation "
            f"keys or action size differ): {error}"
        ) from error


# ------------------------------------------------------------------ training checkpoints
CHECKPOINT_PREFIX = "ckpt-"
MANIFEST_NAME = "manifest.json"
STATE_NAME = "state.pt"
EPISODES_NAME = "episodes.npz"
REPLAY_DIR = "replay"
REPLAY_COUNTERS = "replay/counters"
# The two-file format written before checkpoint directories; still resumed from.
LEGACY_STATE_NAME = "latest.pt"
LEGACY_REPLAY_NAME = "latest_replay.npz"
_READ_CHUNK = 16 * 2**20
BACKGROUND_BYTES = 64 * 2**20
"""A checkpoint with more replay bytes to write than this is written in a background thread."""


@dataclass
class LoadedCheckpoint:
    """What `CheckpointStore.load` read besides the replay (which it loads in place)."""

    path: Path
    """The checkpoint directory (or, for the legacy format, its `latest.pt`)."""
    payload: dict[str, Any]
    """The contents of `state.pt`."""
    arrays: dict[str, np.ndarray]
    """The contents of `episodes.npz` without the replay's counters."""


class CheckpointStore:
    """The checkpoints of one run directory: `save` publishes a new one, `load` resumes from the
    newest good one. The replay is any object with the block interface of
    `clamgen.replay.ReplayBuffer` (`num_blocks`, `block_arrays`, `changed_blocks`, ...)."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self._previous: Path | None = None  # the last good checkpoint, kept by the next save
        # Manifest whose replay blocks equal the replay's unchanged blocks (hard-link source).
        self._link_source: tuple[Path, dict[str, Any]] | None = None
        self._job: _SaveJob | None = None  # a checkpoint being written in the background

    def published(self) -> list[Path]:
        """Published checkpoint directories, newest first."""
        if not self.directory.is_dir():
            return []
        found = [
            p
            for p in self.directory.iterdir()
            if p.name.startswith(CHECKPOINT_PREFIX) and _generation(p) is not None
        ]
        return sorted(found, key=_generation, reverse=True)

    def exists(self) -> bool:
        """Whether there is anything to resume from (in either format)."""
        return bool(self.published()) or (self.directory / LEGACY_STATE_NAME).exists()

    # ----------------------------------------------------------------------- save
    def save(self, payload: dict[str, Any], arrays: dict[str, np.ndarray], replay) -> Path:
        """Checkpoint `payload` (must hold `stamp`, the env-step count), `arrays` (small numpy
        arrays) and `replay` as they are now, publish it, then remove older checkpoints but
        the last good one. Returns the directory it is (or will be) published as.

        When the replay blocks to write exceed `BACKGROUND_BYTES`, they are written by a
        background thread and `save` returns after a snapshot of everything else: the loop
        goes on while the replay changes elsewhere (`replay.before_change` makes it wait only
        before changing a block not yet written, and the block being filled is copied up
        front). The next `save`, `wait` or `load` waits for it to be published."""
        self.wait()
        self.directory.mkdir(parents=True, exist_ok=True)
        self._remove_debris()
        existing = self.published()
        generation = 1 + (_generation(existing[0]) if existing else 0)
        final = self.directory / f"{CHECKPOINT_PREFIX}{generation:06d}"
        state = io.BytesIO()
        torch.save(payload, state)  # the agent's tensors change with the next update
        arrays = arrays | {REPLAY_COUNTERS: replay.counters()}
        source = self._link_source
        if source is not None and source[1]["slots_per_block"] != replay.slots_per_block:
            source = None
        # What the replay holds now: views of its blocks (changed ones), file names (others).
        changed = set(replay.changed_blocks())
        blocks: dict[int, dict[str, np.ndarray] | Path] = {}
        for block in range(replay.num_blocks):
            name = _block_name(block)
            if block not in changed and source is not None and name in source[1]["files"]:
                blocks[block] = source[0] / name
            else:
                changed.add(block)
                blocks[block] = replay.block_arrays(block)
        replay.mark_saved()
        job = _SaveJob(
            final,
            generation,
            int(payload["stamp"]),
            replay.slots_per_block,
            state.getvalue(),
            arrays,
            blocks,
            None if source is None else source[1],
        )
        self._link_source = None  # until this checkpoint is published
        changed_bytes = sum(_nbytes(blocks[b]) for b in changed)
        if changed_bytes <= BACKGROUND_BYTES:
            self._finish(job, job.run())
            return final
        cursor_block = int(replay.counters()[0]) // replay.slots_per_block
        if isinstance(blocks.get(cursor_block), dict):  # the loop writes there next: a copy
            blocks[cursor_block] = {k: v.copy() for k, v in blocks[cursor_block].items()}
        job.pending = {b for b in changed if b != cursor_block}
        job.replay = replay
        replay.before_change = job.wait_for_blocks
        self._job = job
        job.thread = threading.Thread(target=job.run, name="checkpoint", daemon=True)
        job.thread.start()
        return final

    def wait(self) -> None:
        """Wait for a checkpoint being written in the background to be published; raises
        `CheckpointError` if writing it failed."""
        job, self._job = self._job, None
        if job is not None:
            job.thread.join()
            self._finish(job, job.error)

    def _finish(self, job: _SaveJob, error: BaseException | None) -> None:
        if job.replay is not None:
            job.replay.before_change = None
        if error is not None:
            # The replay counts its blocks as saved: link nothing, write all blocks next time.
            raise CheckpointError(
                f"checkpoint {job.final} could not be written ({type(error).__name__}: "
                f"{error}); the previous checkpoint is intact"
            ) from error
        keep = {job.final, self._previous}
        self._previous, self._link_source = job.final, (job.final, job.manifest)
        for old in self.published():
            if old not in keep:
                _remove_dir(old)

    # ----------------------------------------------------------------------- load
    def load(self, replay, check: Callable[[dict[str, Any], Path], None]) -> LoadedCheckpoint:
        """Resume from the newest checkpoint that is intact: verify it against its manifest,
        call `check(payload, path)` (which raises `CheckpointError` when the checkpoint does not
        belong to this run; that is not damage and stops the resume), load the replay in place
        a block at a time (never a second copy of it) and return the rest. A damaged checkpoint
        is skipped for the one before it, with a one-line note on stderr."""
        self.wait()
        candidates = self.published()
        if not candidates:
            return self._load_legacy(replay, check)
        damaged: list[str] = []
        for path in candidates:
            try:
                loaded = self._load_dir(path, replay, check)
            except DamagedCheckpointError as error:
                damaged.append(f"{path.name} is damaged ({error})")
                continue
            if damaged:
                print(
                    f"checkpoint {'; '.join(damaged)}: resumed from {path.name} "
                    f"(step {loaded.payload['stamp']}) instead",
                    file=sys.stderr,
                )
            return loaded
        raise CheckpointError(
            f"no intact checkpoint in {self.directory}: {'; '.join(damaged)}; move the directory "
            "away to start the run again"
        )

    def _load_dir(self, path: Path, replay, check) -> LoadedCheckpoint:
        manifest = _verified_manifest(path)
        payload = _damage_if_unreadable(lambda: load_torch(path / STATE_NAME, TRAINING_KIND))
        if payload.get("stamp") != manifest["stamp"]:
            raise DamagedCheckpointError(
                f"{STATE_NAME} is of step {payload.get('stamp')}, the manifest of step "
                f"{manifest['stamp']}"
            )
        check(payload, path)
        arrays = _damage_if_unreadable(lambda: load_npz(path / EPISODES_NAME))
        counters = arrays.pop(REPLAY_COUNTERS)
        slots_per_block = manifest["slots_per_block"]
        try:
            for block in range(manifest["replay_blocks"]):
                blocks = _damage_if_unreadable(lambda b=block: load_npz(path / _block_name(b)))
                replay.load_slots(block * slots_per_block, blocks)
                del blocks
            replay.set_counters(counters)
        except ValueError as error:
            raise CheckpointError(f"{path} does not fit this run's replay: {error}") from error
        if slots_per_block == replay.slots_per_block:
            replay.mark_saved()
            self._link_source = (path, manifest)
        self._previous = path
        return LoadedCheckpoint(path, payload, arrays)

    def _load_legacy(self, replay, check) -> LoadedCheckpoint:
        path = self.directory / LEGACY_STATE_NAME
        if not path.exists():
            raise CheckpointError(f"no checkpoint in {self.directory}")
        payload = load_torch(path, TRAINING_KIND)
        check(payload, path)
        arrays = load_npz(self.directory / LEGACY_REPLAY_NAME)
        if int(arrays.pop("stamp")) != payload["stamp"]:
            raise CheckpointError(
                f"{LEGACY_REPLAY_NAME} and {LEGACY_STATE_NAME} in {self.directory} are of "
                "different steps; this old-format checkpoint cannot be resumed"
            )
        prefix = "buffer/"
        state = {k[len(prefix) :]: arrays.pop(k) for k in list(arrays) if k.startswith(prefix)}
        try:
            replay.load_state_dict(state)
        except (KeyError, ValueError) as error:
            raise CheckpointError(f"{path} does not fit this run's replay: {error}") from error
        return LoadedCheckpoint(path, payload, arrays)

    def _remove_debris(self) -> None:
        """Temporary directories of saves that were killed, and half-removed old checkpoints."""
        for path in self.directory.iterdir():
            if path.name.startswith(".") and path.name.endswith((".tmp", ".trash")):
                if path.is_dir():
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    path.unlink(missing_ok=True)


class _SaveJob:
    """Writing one checkpoint directory from a snapshot (`CheckpointStore.save`)."""

    def __init__(
        self,
        final: Path,
        generation: int,
        stamp: int,
        slots_per_block: int,
        state: bytes,
        arrays: dict[str, np.ndarray],
        blocks: dict[int, dict[str, np.ndarray] | Path],
        source: dict[str, Any] | None,
    ) -> None:
        self.final, self.generation, self.stamp = final, generation, stamp
        self.slots_per_block, self.state, self.arrays = slots_per_block, state, arrays
        self.blocks, self.source = blocks, source
        self.manifest: dict[str, Any] = {}
        self.error: BaseException | None = None
        self.replay = None
        self.thread: threading.Thread | None = None
        self.pending: set[int] = set()  # blocks the replay must not change yet
        self._written = threading.Condition()

    def wait_for_blocks(self, first: int, last: int) -> None:
        """`replay.before_change`: block until blocks first..last are written."""
        with self._written:
            while any(first <= b <= last for b in self.pending):
                self._written.wait()

    def run(self) -> BaseException | None:
        try:
            self._write()
        except BaseException as error:  # reported by `CheckpointStore.wait`
            self.error = error
        finally:
            with self._written:
                self.pending.clear()
                self._written.notify_all()
        return self.error

    def _write(self) -> None:
        tmp = self.final.with_name(f".{self.final.name}.tmp")
        (tmp / REPLAY_DIR).mkdir(parents=True)
        files = {
            STATE_NAME: _write_file(tmp / STATE_NAME, lambda f: f.write(self.state)),
            EPISODES_NAME: _write_file(tmp / EPISODES_NAME, lambda f: np.savez(f, **self.arrays)),
        }
        for block, content in self.blocks.items():
            name = _block_name(block)
            if isinstance(content, Path):
                _link_or_copy(content, tmp / name)
                files[name] = self.source["files"][name]
                continue
            files[name] = _write_file(tmp / name, lambda f, a=content: np.savez(f, **a))
            with self._written:
                self.pending.discard(block)
                self._written.notify_all()
        self.manifest = {
            "format": FORMAT,
            "kind": TRAINING_KIND,
            "generation": self.generation,
            "stamp": self.stamp,
            "slots_per_block": int(self.slots_per_block),
            "replay_blocks": len(self.blocks),
            "files": files,
        }
        manifest = json.dumps(self.manifest).encode()
        _write_file(tmp / MANIFEST_NAME, lambda f: f.write(manifest))
        _fsync_dir(tmp / REPLAY_DIR)
        _fsync_dir(tmp)
        os.rename(tmp, self.final)  # the single step that publishes the checkpoint
        _fsync_dir(self.final.parent)


def _nbytes(content: dict[str, np.ndarray] | Path) -> int:
    return 0 if isinstance(content, Path) else sum(a.nbytes for a in content.values())


def latest_state_path(directory: Path) -> Path:
    """`state.pt` of the newest checkpoint in a run's checkpoint directory (for reading the
    agent without resuming; not verified)."""
    directory = Path(directory)
    published = CheckpointStore(directory).published()
    if published:
        return published[0] / STATE_NAME
    if (directory / LEGACY_STATE_NAME).exists():
        return directory / LEGACY_STATE_NAME
    raise CheckpointError(f"no checkpoint in {directory}")


def _generation(path: Path) -> int | None:
    suffix = path.name[len(CHECKPOINT_PREFIX) :]
    return int(suffix) if suffix.isdigit() else None


def _block_name(block: int) -> str:
    return f"{REPLAY_DIR}/block-{block:06d}.npz"


def _write_file(path: Path, write: Callable[[BinaryIO], Any]) -> dict[str, int]:
    """Write, flush to disk, and return the file's size and CRC-32 (read back)."""
    with path.open("wb") as f:
        write(f)
        f.flush()
        os.fsync(f.fileno())
    return {"bytes": path.stat().st_size, "crc32": _crc32(path)}


def _crc32(path: Path) -> int:
    crc = 0
    with path.open("rb") as f:
        while chunk := f.read(_READ_CHUNK):
            crc = zlib.crc32(chunk, crc)
    return crc


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _link_or_copy(source: Path, target: Path) -> None:
    """A hard link (no data copied); a copy on file systems without hard links."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)
        with target.open("rb") as f:
            os.fsync(f.fileno())


def _remove_dir(path: Path) -> None:
    """Rename away first, so that a kill during the removal leaves no half checkpoint under a
    published name."""
    trash = path.with_name(f".{path.name}.trash")
    os.rename(path, trash)
    shutil.rmtree(trash, ignore_errors=True)


def _verified_manifest(path: Path) -> dict[str, Any]:
    try:
        manifest = json.loads((path / MANIFEST_NAME).read_text())
        files = manifest["files"]
        int(manifest["stamp"]), int(manifest["slots_per_block"]), int(manifest["replay_blocks"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise DamagedCheckpointError(f"{MANIFEST_NAME} unreadable: {error}") from error
    if manifest.get("format") != FORMAT or manifest.get("kind") != TRAINING_KIND:
        raise DamagedCheckpointError(f"{MANIFEST_NAME} is not a clamgen training checkpoint's")
    for name, expected in files.items():
        file = path / name
        if not file.is_file():
            raise DamagedCheckpointError(f"{name} is missing")
        size = file.stat().st_size
        if size != expected["bytes"]:
            raise DamagedCheckpointError(f"{name} has {size} bytes, expected {expected['bytes']}")
        if _crc32(file) != expected["crc32"]:
            raise DamagedCheckpointError(f"{name} fails its CRC-32 check")
    missing = {STATE_NAME, EPISODES_NAME} | {
        _block_name(b) for b in range(manifest["replay_blocks"])
    }
    if missing - set(files):
        raise DamagedCheckpointError(f"the manifest lacks {sorted(missing - set(files))[0]}")
    return manifest


def _damage_if_unreadable(read: Callable[[], Any]) -> Any:
    """A file that passed its CRC but still cannot be read counts as damage too."""
    try:
        return read()
    except CheckpointError as error:
        raise DamagedCheckpointError(str(error)) from error
