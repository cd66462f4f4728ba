"""Binned actions for a distilled student (beyond the paper): a choice instead of a mean.

In new tasks' stalls the students command small steps where their teacher leaves with one
saturated manoeuvre (`../ensemble/README.md`, session 28): what a regression to the mean gives
where the labels of similar states point different ways. Here the student also learns the
labels as a choice among `bins` k-means centres of the pooled labels (pre-squash), with an
offset from the chosen centre (as behaviour transformers discretise actions: Shafiullah et al.
2022): a bin head on the actor's features gives each bin's logit and offset, trained by the
cross-entropy of the label's bin and the squared error of that bin's offset, beside the
student's own regression (`BinDistiller`, `offline.py --bins K`; the head in
`OUT/bin_head.pt`). `BinPolicy` acts with the most likely bin's centre plus its offset: a
decisive choice where the mean would average.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.distill import Distiller, actor_features

BIN_WEIGHT = 1.0  # of the bin loss (cross-entropy + offset error) beside the imitation loss
HIDDEN = 256
KMEANS_ROWS = 50_000  # labels the centres are fitted on (a random subset)
KMEANS_ITERATIONS = 30
HEAD_NAME = "bin_head.pt"


def kmeans(points: np.ndarray, k: int, seed: int) -> np.ndarray:
    """(k, D) centres of `points` (N, D): Lloyd's iterations from k-means++ seeds, fitted on at
    most `KMEANS_ROWS` of them."""
    rng = np.random.default_rng(seed)
    points = np.asarray(points, np.float64)
    if len(points) > KMEANS_ROWS:
        points = points[rng.choice(len(points), KMEANS_ROWS, replace=False)]
    centres = [points[rng.integers(len(points))]]
    for _ in range(1, k):
        d2 = np.min(((points[:, None] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
        centres.append(points[rng.choice(len(points), p=d2 / d2.sum())])
    centres = np.array(centres)
    for _ in range(KMEANS_ITERATIONS):
        assign = nearest(points, centres)
        for j in range(k):
            members = points[assign == j]
            if len(members):
                centres[j] = members.mean(0)
    return centres.astype(np.float32)


def nearest(points: np.ndarray, centres: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """(N,) the index of each point's nearest centre."""
    out = np.empty(len(points), np.int64)
    for start in range(0, len(points), chunk):
        block = np.asarray(points[start : start + chunk], np.float64)
        out[start : start + chunk] = ((block[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
    return out


class BinHead(torch.nn.Module):
    """The actor's features -> each bin's logit (B, K) and offset from its centre (B, K, A)."""

    def __init__(self, in_features: int, centres: np.ndarray) -> None:
        super().__init__()
        self.register_buffer("centres", torch.as_tensor(centres, dtype=torch.float32))
        self.bins, self.action_dim = self.centres.shape
        self.net = torch.nn.Sequential(
            torch.nn.Linear(in_features, HIDDEN),
            torch.nn.ReLU(),
            torch.nn.Linear(HIDDEN, self.bins * (1 + self.action_dim)),
        )

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(features)
        return out[:, : self.bins], out[:, self.bins :].view(-1, self.bins, self.action_dim)

    def action(self, features: torch.Tensor) -> torch.Tensor:
        """The pre-squash action of the most likely bin (B, A)."""
        logits, offsets = self(features)
        best = logits.argmax(-1)
        rows = torch.arange(len(best))
        return self.centres[best] + offsets[rows, best]


class BinDistiller(Distiller):
    """A `Distiller` that regresses a bin head beside the student on its data's labels."""

    def attach_bins(self, bins: int) -> None:
        labels = np.asarray(self.data.arrays["label"])
        centres = kmeans(labels, bins, self.config.distill.seed)
        self.assignment = torch.as_tensor(nearest(labels, centres))
        width = self.actor_features_dim()
        self.bin_head = self.add_head("bin_head", lambda: BinHead(width, centres))

    def extra_loss(self, index: np.ndarray, obs: dict, visual: torch.Tensor):
        rows = torch.as_tensor(index)
        target = self.assignment[rows]
        labels = torch.as_tensor(np.asarray(self.data.arrays["label"][index]))
        logits, offsets = self.bin_head(actor_features(self.student, obs, visual))
        chosen = offsets[torch.arange(len(rows)), target]
        offset_error = torch.mean((chosen - (labels - self.bin_head.centres[target])) ** 2)
        return BIN_WEIGHT * (torch.nn.functional.cross_entropy(logits, target) + offset_error)

    def save_head(self, out: Path) -> None:
        ckpt.save_torch(
            out / HEAD_NAME,
            {
                "format": ckpt.FORMAT,
                "kind": "bin-head",
                "in_features": self.bin_head.net[0].in_features,
                "centres": self.bin_head.centres.clone(),
                "state": self.bin_head.state_dict(),
            },
        )


class BinPolicy:
    """A bin student acting with its bin head (a `Policy`): the tanh of the most likely bin's
    centre plus its offset."""

    def __init__(self, agent, head_path: Path) -> None:
        saved = ckpt.load_torch(head_path, kind="bin-head")
        self.agent = agent
        self.head = BinHead(saved["in_features"], saved["centres"])
        self.head.load_state_dict(saved["state"])

    def reset(self, env=None) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        agent = self.agent
        batch = {k: np.asarray(v)[None] for k, v in obs.items()}
        with torch.inference_mode():
            visual = agent.critic.encoder(agent.encoder_input(batch))
            pre_squash = self.head.action(actor_features(agent, batch, visual))
        return np.tanh(pre_squash[0].numpy()).astype(np.float32)
