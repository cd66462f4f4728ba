"""A learned collision head on a student's own encoding (beyond the paper): a shield without
extra sensors.

The depth shield (`clamgen.experiments.depth_shield`) keeps the students' blocked collision
rates under the aim, reading each view's depth at 128 pixels. Can the students' own 64-pixel
encoding tell a colliding step instead? A small head on a frozen student's visual encoding,
its joints and goal, and a candidate action predicts whether that step collides
(`clamgen.experiments.learned_shield.make_head`); acting (`LearnedShieldPolicy` there),
the student's action goes through when the head's probability is under a threshold, else the
nearest safe candidate (the action scaled down, or moved on one joint) or, when none is safe,
the least risky one.

    python results/stage2/shield/learned_shield.py prepare POLICY CACHE OUT --rows N
    python results/stage2/shield/learned_shield.py fit OUT

`prepare` reads the first N states of a pool cache (`offline.py --pool-cache`): the student's
visual encoding, normalised joints and goal, and its own action for each (`features.npy`,
`student_action.npy`), and whether each of `CANDIDATES` actions collides from there in the
true scene (`pooled.apply_row`, the env's own step: `Scene.move_along`; `actions.npy`,
`collided.npy`). `fit` regresses the head (binary cross-entropy) on the states of all but the
cache's last data file of that range, and reports on the held-out file (other tasks) the
collision rate of each candidate kind, the area under the ROC curve, and precision and recall
at thresholds (`OUT/head.json`); the head goes to `OUT/head.pt`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from clamgen.experiments.learned_shield import (
    FEATURES,
    HEAD_NAME,
    make_head,
    save_head,
    student_features,
)
from clamgen.experiments.pooled import apply_row, cache_files

CANDIDATES = ("student", "student+0.3", "label", "label+0.3", "label+0.6", "uniform")
"""Actions labelled per state: the student's own, the teacher's (the tanh of the cache's
pre-squash label), each with Gaussian noise (std 0.3, 0.6 for the teacher's; clipped), and one
uniform in the action box."""
EPOCHS = 8
BATCH = 1024
LR = 1e-3
SEED = 0


# ------------------------------------------------------------------------------- prepare
def _actions(student: np.ndarray, teacher: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    n, a = teacher.shape
    out = np.empty((n, len(CANDIDATES), a), np.float32)
    for k, kind in enumerate(CANDIDATES):
        source, _, noise = kind.partition("+")
        if source in ("student", "label"):
            out[:, k] = student if source == "student" else teacher
            if noise:
                out[:, k] += rng.normal(0.0, float(noise), (n, a))
        else:
            out[:, k] = rng.uniform(-1.0, 1.0, (n, a))
    return np.clip(out, -1.0, 1.0)


def prepare(
    policy: str, cache: Path, out: Path, rows: int, kind: str = "encoding", batch: int = 512
) -> None:
    from clamgen.envs.reach_env import COLLISION_CHECK_RESOLUTION_RAD, step_target
    from clamgen.experiments.policies import load_policy
    from clamgen.sim.scene import Scene

    agent = load_policy(policy)[0].agent
    views = agent.config.encoder.num_views
    arrays = {
        key: np.load(cache / f"{key}.npy", mmap_mode="r")
        for key in ("images", "observation", "desired_goal", "achieved_goal", "obstacles", "label")
    }
    rows = min(rows, len(arrays["label"]))
    out.mkdir(parents=True, exist_ok=True)
    features, student = None, np.empty((rows, 6), np.float32)
    with torch.inference_mode():
        for first in tqdm(range(0, rows, batch), desc="encoding", unit="batch"):
            index = slice(first, min(first + batch, rows))
            obs = {k: np.asarray(arrays[k][index]) for k in ("observation", "desired_goal")}
            obs["achieved_goal"] = np.asarray(arrays["achieved_goal"][index])
            obs["images"] = np.asarray(arrays["images"][index][:, :views])
            feats, state, visual = student_features(agent, obs, kind)
            if features is None:
                features = np.empty((rows, feats.shape[1]), np.float32)
            features[index] = feats.numpy()
            student[index] = torch.tanh(agent.policy_mean(visual, state)).numpy()
    teacher = np.tanh(np.asarray(arrays["label"][:rows]))  # labels are pre-squash means
    actions = _actions(student, teacher, np.random.default_rng(SEED))
    collided = np.zeros(actions.shape[:2], bool)
    scene = Scene()
    for row in tqdm(range(rows), desc="collisions", unit="state", mininterval=5):
        apply_row(
            scene, arrays["observation"][row], arrays["desired_goal"][row], arrays["obstacles"][row]
        )
        joints = scene.data.qpos[:6].copy()
        for k, action in enumerate(actions[row]):
            wanted = step_target(joints, action)
            collided[row, k] = scene.move_along(joints, wanted, COLLISION_CHECK_RESOLUTION_RAD)[1]
            scene.set_joints(joints)
    for name, value in (
        ("features", features),
        ("student_action", student),
        ("actions", actions),
        ("collided", collided),
    ):
        np.save(out / f"{name}.npy", value)
    record = {
        "policy": str(policy),
        "cache": str(cache),
        "rows": rows,
        "features": kind,
        "candidates": CANDIDATES,
    }
    (out / "prepare.json").write_text(json.dumps(record, indent=1))
    print(f"wrote {out}: {rows} states; collision rate per candidate", collided.mean(0).round(3))


# ----------------------------------------------------------------------------------- fit
def _held_out_start(cache: Path, rows: int) -> int:
    """First row of the last data file that starts within the first `rows` rows."""
    start = 0
    for _, length in cache_files(cache):
        if start + length >= rows:
            return start
        start += length
    return start


def roc_auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve (the probability that a positive outscores a negative)."""
    from scipy.stats import rankdata

    ranks = rankdata(scores)
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def fit(out: Path, epochs: int = EPOCHS, name: str = HEAD_NAME) -> None:
    record = json.loads((out / "prepare.json").read_text())
    features = torch.as_tensor(np.load(out / "features.npy"))
    actions = torch.as_tensor(np.load(out / "actions.npy"))
    collided = torch.as_tensor(np.load(out / "collided.npy")).float()
    rows, kinds = collided.shape
    split = _held_out_start(Path(record["cache"]), rows)
    if split == 0:
        raise SystemExit(f"the first {rows} states are one data file: prepare more rows")
    torch.manual_seed(SEED)
    head = make_head(features.shape[1], actions.shape[2])
    optimizer = torch.optim.Adam(head.parameters(), lr=LR)
    pairs = split * kinds
    started = time.time()
    for epoch in range(epochs):
        order = torch.randperm(pairs)
        total = 0.0
        for first in range(0, pairs, BATCH):
            pick = order[first : first + BATCH]
            row, kind = pick // kinds, pick % kinds
            logit = head(features[row], actions[row, kind])
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logit, collided[row, kind])
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * len(pick)
        print(f"epoch {epoch + 1}: loss {total / pairs:.4f}", flush=True)
    with torch.inference_mode():
        held = slice(split, rows)
        n = rows - split
        probability = torch.sigmoid(
            head(features[held].repeat_interleave(kinds, 0), actions[held].reshape(n * kinds, -1))
        ).view(n, kinds)
    truth = collided[held].numpy().astype(bool)
    p = probability.numpy()
    report = {
        **record,
        "train_rows": split,
        "held_out_rows": n,
        "epochs": epochs,
        "minutes": round((time.time() - started) / 60, 1),
        "held_out_collision_rate": truth.mean(0).round(4).tolist(),  # per CANDIDATES
        "auc_all": roc_auc(p.ravel(), truth.ravel()),
        "auc_student_actions": roc_auc(p[:, 0], truth[:, 0]) if truth[:, 0].any() else None,
        "at_threshold": {
            str(t): {
                "precision": float(truth[p >= t].mean()) if (p >= t).any() else None,
                "recall": float((p[truth] >= t).mean()),
                "student_flagged": float((p[:, 0] >= t).mean()),
                "student_recall": float((p[truth[:, 0], 0] >= t).mean())
                if truth[:, 0].any()
                else None,
            }
            for t in (0.1, 0.2, 0.3, 0.5)
        },
    }
    (out / name).with_suffix(".json").write_text(json.dumps(report, indent=1))
    save_head(out / name, head, features.shape[1], record.get("features", "encoding"))
    print(json.dumps({k: v for k, v in report.items() if k != "candidates"}, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    p = commands.add_parser("prepare", help="features and collision labels of a cache's states")
    p.add_argument("policy", help="a student's policy file")
    p.add_argument("cache", type=Path, help="a pool cache (offline.py --pool-cache)")
    p.add_argument("out", type=Path)
    p.add_argument("--rows", type=int, default=146_699, help="the cache's first ROWS states")
    p.add_argument("--features", choices=FEATURES, default="encoding")
    f = commands.add_parser("fit", help="regress the collision head on OUT's states")
    f.add_argument("out", type=Path)
    f.add_argument("--epochs", type=int, default=EPOCHS)
    f.add_argument("--name", default=HEAD_NAME, help="the head's file in OUT (and its .json)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.command == "prepare":
        prepare(args.policy, args.cache, args.out, args.rows, args.features)
    else:
        fit(args.out, args.epochs, args.name)


if __name__ == "__main__":
    main()
