"""How well a distilled student locates the obstacles from its views (validation tasks only).

    python results/stage2/distill/pose_error.py runs/distill/d2 [--num-tasks 50]

A student trained with `--distill.pose-weight` > 0 has a training-only linear head that
regresses the obstacles' true poses from its visual encoding (saved in the run's `student.pt`,
not in the policy file). This drives the student on blocked-path and standard validation tasks
(the seeds `validate.py` uses), reads the head on every visited state (centre crops, no view
dropout) and prints, per family, the error of the predicted obstacle centres under the best
matching of predicted to true obstacles: median and 90th percentile over obstacles, in cm,
beside the error of always predicting the mean obstacle centre of those states.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tune"))

from validate import VALIDATION_OFFSET

from clamgen.envs import ReachEnv
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.distill import POSE_SIZE, STATE_NAME
from clamgen.experiments.policies import load_policy

# Columns of an obstacle's pose (`Obstacles.as_array`): its centre, metres.
CENTRE = slice(2, 5)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--num-tasks", type=int, default=50)
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy, _, env_kwargs = load_policy(args.run_dir / "policy.pt")
    agent = policy.agent
    state = ckpt.load_torch(args.run_dir / STATE_NAME, kind="distill")
    weight = state["pose_head"]["weight"]
    head = torch.nn.Linear(weight.shape[1], weight.shape[0])
    head.load_state_dict(state["pose_head"])
    # The student as it was saved last (policy.pt may be an earlier, better iteration).
    agent.load_state_dict(state["student"])
    settings = json.loads((args.run_dir / "config.json").read_text())["distill"]
    scale = settings.get("pose_length_scale_m", 1.0)  # the head predicts lengths in this unit
    seeds = VALIDATION_SEEDS.seeds(args.num_tasks, VALIDATION_SEEDS.start + VALIDATION_OFFSET)
    for family in ("blocked", "obstacles"):
        kwargs = {**env_kwargs, "include_obstacle_state": True}
        env = ReachEnv(num_obstacles=2, task_family=family, **kwargs)
        errors, baseline = pose_errors(env, agent, head, seeds, scale)
        env.close()
        print(
            f"{family:9s} {len(errors)} obstacle views: centre error median "
            f"{np.median(errors) * 100:.1f} cm, p90 {np.percentile(errors, 90) * 100:.1f} cm "
            f"(mean-centre guess: median {np.median(baseline) * 100:.1f} cm)"
        )


def pose_errors(env, agent, head, seeds, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Centre errors (m) of the head's predictions (lengths in units of `scale` m), and of the
    mean centre, per obstacle and visited state, the student driving."""
    predicted, truth = [], []
    for seed in seeds:
        obs, _ = env.reset(seed=int(seed))
        done = False
        while not done:
            batch = {k: v[None] for k, v in obs.items()}
            with torch.no_grad():
                visual = agent.critic.encoder(agent.encoder_input(batch))
                poses = head(visual).view(-1, POSE_SIZE).numpy()
            poses[:, CENTRE] *= scale
            predicted.append(poses)
            truth.append(obs["obstacles"])
            obs, _, terminated, truncated, _ = env.step(agent.act(batch, deterministic=True)[0])
            done = terminated or truncated
    predicted, truth = np.stack(predicted), np.stack(truth)
    best = np.full(len(truth), np.inf)
    errors = np.zeros(truth.shape[:2])
    for order in itertools.permutations(range(truth.shape[1])):
        distance = np.linalg.norm(predicted[:, order, CENTRE] - truth[:, :, CENTRE], axis=-1)
        better = distance.sum(1) < best
        best[better] = distance.sum(1)[better]
        errors[better] = distance[better]
    mean_centre = truth[:, :, CENTRE].reshape(-1, 3).mean(0)
    baseline = np.linalg.norm(truth[:, :, CENTRE] - mean_centre, axis=-1)
    return errors.ravel(), baseline.ravel()


if __name__ == "__main__":
    main()
