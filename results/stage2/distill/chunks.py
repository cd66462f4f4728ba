"""Action chunks for a distilled student (beyond the paper): a test of look-ahead in one pass.

The lookahead teacher leaves a stall with a manoeuvre of several steps; a student that acts on
each state alone leaves it only if every state on the way says so. Here the student also
predicts the teacher's next `steps` labels of its episode (a chunk head on the actor's
features: the visual encoding and the joints / goal encoding), regressed on the consecutive
labels of the pooled data's episodes (`clamgen.experiments.stall.pool_episodes` and
`episode_rows`), and may act with temporal ensembling: at each step, the weighted mean of what
the steps before predicted for it and what it predicts now (weights `exp(-DECAY * age)`), so
that a way out, once begun, is carried on. `offline.py --chunk K` regresses such a student
(`ChunkDistiller`, the head's weights in `OUT/chunk_head.pt`); `ChunkEnsemblePolicy` acts with
it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.distill import Distiller, actor_features
from clamgen.experiments.stall import episode_rows

CHUNK_WEIGHT = 1.0  # of the chunk loss (mean squared error, pre-squash) beside the imitation loss
HIDDEN = 256
DECAY = 0.5  # temporal ensembling: a prediction made `age` steps ago weighs exp(-DECAY * age)
HEAD_NAME = "chunk_head.pt"


def future_labels(labels: np.ndarray, episode: np.ndarray, steps: int) -> np.ndarray:
    """(N, steps, A): for each row, the labels of the next `steps` rows of its episode (rows
    of one episode are in step order); past the episode's end its last label again."""
    out = np.empty((len(labels), steps, labels.shape[1]), labels.dtype)
    for rows in episode_rows(episode):
        position = np.arange(len(rows))
        for k in range(steps):
            out[rows, k] = labels[rows[np.minimum(position + k + 1, len(rows) - 1)]]
    return out


class ChunkHead(torch.nn.Module):
    """The actor's features -> the next `steps` pre-squash actions (steps, A)."""

    def __init__(self, in_features: int, steps: int, action_dim: int) -> None:
        super().__init__()
        self.steps, self.action_dim = steps, action_dim
        self.net = torch.nn.Sequential(
            torch.nn.Linear(in_features, HIDDEN),
            torch.nn.ReLU(),
            torch.nn.Linear(HIDDEN, steps * action_dim),
        )

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.net(features).view(-1, self.steps, self.action_dim)


class ChunkDistiller(Distiller):
    """A `Distiller` that regresses a chunk head beside the student on `future` (N, steps, A),
    the next labels of each state of its data (`future_labels`)."""

    def attach_chunks(self, future: np.ndarray) -> None:
        self.future = future
        width = self.actor_features_dim()
        self.chunk_head = self.add_head(
            "chunk_head", lambda: ChunkHead(width, future.shape[1], future.shape[2])
        )

    def extra_loss(self, index: np.ndarray, obs: dict, visual: torch.Tensor):
        target = torch.as_tensor(self.future[index])
        predicted = self.chunk_head(actor_features(self.student, obs, visual))
        return CHUNK_WEIGHT * torch.mean((predicted - target) ** 2)

    def save_head(self, out: Path) -> None:
        ckpt.save_torch(
            out / HEAD_NAME,
            {
                "format": ckpt.FORMAT,
                "kind": "chunk-head",
                "in_features": self.chunk_head.net[0].in_features,
                "steps": self.chunk_head.steps,
                "action_dim": self.chunk_head.action_dim,
                "state": self.chunk_head.state_dict(),
            },
        )


class ChunkEnsemblePolicy:
    """A chunk student acting with temporal ensembling (a `Policy`): the tanh of the weighted
    mean of its pre-squash action now and what it predicted for this step 1..steps steps ago."""

    def __init__(self, agent, head_path: Path, decay: float = DECAY) -> None:
        saved = ckpt.load_torch(head_path, kind="chunk-head")
        self.agent = agent
        self.head = ChunkHead(saved["in_features"], saved["steps"], saved["action_dim"])
        self.head.load_state_dict(saved["state"])
        self.decay = decay
        self.history: list[np.ndarray] = []

    def reset(self, env=None) -> None:
        self.history = []

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        agent = self.agent
        batch = {k: np.asarray(v)[None] for k, v in obs.items()}
        with torch.inference_mode():
            visual = agent.critic.encoder(agent.encoder_input(batch))
            state = agent.low_dim_input(batch)
            now = agent.policy_mean(visual, state)[0]
            ahead = self.head(agent.actor_features(visual, state))[0]
        self.history.append(torch.cat([now[None], ahead]).numpy())  # this step, then ahead
        self.history = self.history[-(self.head.steps + 1) :]
        values, weights = [], []
        for age, predicted in enumerate(reversed(self.history)):
            values.append(predicted[age])
            weights.append(np.exp(-self.decay * age))
        mean = np.average(values, axis=0, weights=weights)
        return np.tanh(mean).astype(np.float32)
