"""Checkpoints: resumable training state and small policy files, loaded with `weights_only`.

A training checkpoint is two files written atomically (temporary file, then rename):
`latest.pt` (agent, progress, random states, config) and `latest_replay.npz` (the replay
buffer and the environments' episodes in progress), both stamped with the same env-step count.
A policy file (`export_policy`) holds what acting and stage 2 need: actor, critic, normaliser
and the config, a few hundred kB.

Nothing is pickled: `torch.load(..., weights_only=True)` and `numpy.load(allow_pickle=False)`.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

FORMAT = "clamgen"
TRAINING_KIND = "training-state"
POLICY_KIND = "sac-policy"


class CheckpointError(ValueError):
    """A checkpoint is missing, truncated, corrupt, or does not match what loads it."""


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
