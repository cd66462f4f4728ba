"""A collision loss for a distilled student (beyond the paper): does learning to tell a
colliding step shape an encoding that collides less?

A collision head on a frozen student's encoding (`clamgen.experiments.learned_shield`) flags
most colliding steps on the pooled states it was fitted on and few on new tasks
(`../shield/README.md`, session 29): the encoding, shaped by imitation alone, does not carry
the contact geometry the head would need. Here the head is regressed beside the student
(`CollisionDistiller`, `offline.py --collision-labels DIR`), on the same labels (each pooled
state's candidate actions and whether each collides in the true scene: `learned_shield.py
prepare`, whose first states must be the regression's), its binary cross-entropy weighted by
`WEIGHT` beside the imitation loss, the gradient reaching the encoder through the encoding the
imitation loss computed (random crops, view dropout). The head is saved as `OUT/head.pt`, so
the student can also act through it (`LearnedShieldPolicy`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from clamgen.experiments.distill import Distiller
from clamgen.experiments.learned_shield import HEAD_NAME, make_head, save_head

WEIGHT = 1.0
"""Of the collision loss beside the imitation loss (0.6 at the end of a regression; the
collision loss of a fitted head is about 0.05)."""


def load_labels(directory: Path, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """(actions (rows, K, A), collided (rows, K)) from a `learned_shield.py prepare` output,
    which must hold exactly the regression's `rows` states."""
    actions = np.load(directory / "actions.npy")
    collided = np.load(directory / "collided.npy")
    if len(actions) != rows:
        raise SystemExit(f"{directory} labels {len(actions)} states, the regression has {rows}")
    return actions, collided


class CollisionDistiller(Distiller):
    """A `Distiller` that regresses a collision head beside the student on `actions` (N, K, A)
    and `collided` (N, K) of its data's states."""

    def attach_collisions(self, actions: np.ndarray, collided: np.ndarray) -> None:
        self.actions = torch.as_tensor(actions)
        self.collided = torch.as_tensor(collided).float()
        self.features = self.student.feature_dim + self.student.config.encoder.low_dim_input
        self.collision_head = self.add_head(
            "collision_head", lambda: make_head(self.features, actions.shape[2])
        )

    def extra_loss(self, index: np.ndarray, obs: dict, visual: torch.Tensor):
        rows = torch.as_tensor(index)
        actions, collided = self.actions[rows], self.collided[rows]  # (B, K, A), (B, K)
        k = actions.shape[1]
        features = torch.cat([visual, self.student.low_dim_input(obs)], -1)
        logits = self.collision_head(
            features.repeat_interleave(k, 0), actions.reshape(-1, actions.shape[2])
        )
        loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, collided.reshape(-1))
        return WEIGHT * loss

    def save_head(self, out: Path) -> None:
        save_head(out / HEAD_NAME, self.collision_head, self.features, "encoding")
