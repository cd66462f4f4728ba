"""A learned collision head on a student's own encoding, and a policy acting through it (beyond
the paper; measured in `results/stage2/shield/README.md`, session 29).

A collision head (`make_head`: the collision-prediction loss's `CollisionHead`, 2 x 256) maps
what a vision student computes of a state (`student_features`: its visual encoding, or each
view's projection in the encoder's first dense layer, with its normalised joints and goal) and
a candidate action to the logit of that step colliding; it is regressed
on pooled DAgger states labelled in the true scene (`results/stage2/shield/learned_shield.py`)
or beside the student itself (`results/stage2/distill/offline.py --collision-labels`).
`LearnedShieldPolicy` lets the student's action through when the head's probability is under a
threshold, else takes the nearest candidate under it (`shield_candidates`), else the least
risky: a shield that needs no sensor beyond the student's own views.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from clamgen.agents.aux_losses import CollisionHead
from clamgen.experiments import checkpoint as ckpt

HIDDEN = 256
THRESHOLD = 0.5
SCALES = (0.5, 0.25)
"""`LearnedShieldPolicy`'s candidates: the action scaled by these ..."""
NUDGE = 0.5
"""... and moved by this much (of the action range) on one joint either way, clipped."""
HEAD_NAME = "head.pt"
HEAD_KIND = "collision-head"


def make_head(features: int, action_dim: int) -> CollisionHead:
    """A fresh head: (student's features (B, `features`), action (B, A)) -> the logit of the
    step colliding (B,), two hidden layers of `HIDDEN`."""
    return CollisionHead(features, action_dim, (HIDDEN, HIDDEN))


def save_head(path: Path, head: CollisionHead, features: int, reads: str) -> None:
    """Write `head` (reading `features` numbers of the student's kind `reads`, `FEATURES`)
    where `LearnedShieldPolicy` loads it."""
    ckpt.save_torch(
        path,
        {
            "format": ckpt.FORMAT,
            "kind": HEAD_KIND,
            "reads": reads,
            "features": features,
            "action_dim": head.net[0].in_features - features,
            "state": head.state_dict(),
        },
    )


def load_head(path: Path) -> tuple[CollisionHead, str]:
    """(the head `save_head` wrote, what of the student it reads)."""
    saved = ckpt.load_torch(path, kind=HEAD_KIND)
    head = make_head(saved["features"], saved["action_dim"])
    head.load_state_dict(saved["state"])
    return head, saved["reads"]


FEATURES = ("encoding", "projections")
"""What the head reads of the student beside its normalised joints and goal: its visual
encoding (`feature_dim`), or each view's projection in the encoder's first dense layer (V x
`hidden_dim`: the conv maps before the views are summed and squeezed into the encoding)."""


def student_features(
    agent, obs: dict, kind: str = "encoding"
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(features (B, D) of `kind` (`FEATURES`) with the normalised joints + goal, the low-dim
    input, the visual encoding) of a batch of observations, centre crops as when acting; the
    encoding is the one the student acts on (the same operations)."""
    encoder = agent.critic.encoder
    projections = encoder.project(encoder.conv_trunk(agent.encoder_input(obs)))
    visual = encoder.merge_projected(projections)
    state = agent.low_dim_input(obs)
    seen = visual if kind == "encoding" else projections.flatten(1)
    return torch.cat([seen, state], -1), state, visual


def shield_candidates(action: np.ndarray) -> np.ndarray:
    """(K, A): the action, scaled by `SCALES`, moved by `NUDGE` on each joint either way."""
    a = len(action)
    nudges = np.concatenate([np.eye(a), -np.eye(a)]) * NUDGE + action
    return np.clip(
        np.concatenate([action[None], np.outer(SCALES, action), nudges]), -1.0, 1.0
    ).astype(np.float32)


class LearnedShieldPolicy:
    """A student acting through its collision head (a `Policy`): its action when the head
    says it collides with probability under `threshold`, else the candidate
    (`shield_candidates`) nearest to it among those under `threshold`, else the least risky.
    Counts `num_shielded` of `num_steps`."""

    def __init__(self, agent, head_path: Path, threshold: float = THRESHOLD) -> None:
        self.agent = agent
        self.head, self.reads = load_head(head_path)
        self.threshold = threshold
        self.num_steps = self.num_shielded = 0

    def reset(self, env=None) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        self.num_steps += 1
        batch = {k: np.asarray(v)[None] for k, v in obs.items()}
        with torch.inference_mode():
            features, state, visual = student_features(self.agent, batch, self.reads)
            action = torch.tanh(self.agent.policy_mean(visual, state))[0].numpy()
            if (
                torch.sigmoid(self.head(features, torch.as_tensor(action[None])))[0]
                < self.threshold
            ):
                return action
            candidates = shield_candidates(action)
            risk = torch.sigmoid(
                self.head(features.expand(len(candidates), -1), torch.as_tensor(candidates))
            ).numpy()
        self.num_shielded += 1
        safe = np.flatnonzero(risk < self.threshold)
        if len(safe) == 0:
            return candidates[int(np.argmin(risk))]
        distance = np.linalg.norm(candidates[safe] - action, axis=1)
        return candidates[safe[int(np.argmin(distance))]]
