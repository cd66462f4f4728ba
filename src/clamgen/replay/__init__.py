"""Replay: episode containers, hindsight relabelling (standard and reversible HER), buffer."""

from clamgen.replay.buffer import (
    ReplayBuffer,
    ReplayConfig,
    available_memory_bytes,
    nbytes_required,
    obs_spec_from_space,
)
from clamgen.replay.episode import Batch, Episode, EpisodeRecorder, sparse_terminated
from clamgen.replay.her import (
    relabel_episode_goals,
    relabel_final,
    relabel_future,
    reversible_her,
    sample_goal_indices,
    transitions,
    with_goals,
)
from clamgen.replay.pipeline import EpisodePipeline, HindsightConfig

__all__ = [
    "Batch",
    "Episode",
    "EpisodePipeline",
    "EpisodeRecorder",
    "HindsightConfig",
    "ReplayBuffer",
    "ReplayConfig",
    "available_memory_bytes",
    "nbytes_required",
    "obs_spec_from_space",
    "relabel_episode_goals",
    "relabel_final",
    "relabel_future",
    "reversible_her",
    "sample_goal_indices",
    "sparse_terminated",
    "transitions",
    "with_goals",
]
