"""Distil the RRT planner (full scene model) into a privileged policy with DAgger, then score it
on validation tasks: does imitation of a planner get past the RL residual's blocked-path ceiling?

    python results/stage2/tune/distill.py --out runs/tune/distill-priv

Beyond the paper. The learner sees what the privileged residual sees (joints, tip, goal, the
obstacles' true poses); the expert is a path tracker on an RRTConnect plan made with a
clearance margin (`--plan-margin-m`), so a small imitation error does not touch the obstacle.
At each visited state the expert's label moves toward the next waypoint after the nearest one
on its current path (ahead of its progress); when the arm is farther than `TRACK_TOL_RAD`
from that path the expert plans again from where the arm is (DAgger's relabelling, Ross et al.
2011). Iteration 0 is driven by the expert; later ones by the learner, with the expert taking
over a share `beta = 0.5 ** iteration` of the episodes.

Training tasks are `CLAMGen/ReachMixed-v0` with training seeds from `TRAINING_SEED_BASE`;
every score is on validation seeds (the 100 blocked and 100 standard tasks of `validate.py`),
appended to `validation.jsonl` beside this script.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from tqdm import trange
from validate import score

import clamgen.envs  # noqa: F401  (registers the ids)
from clamgen.baselines.rrt import RRTConfig, goal_candidates, plan_joint_path
from clamgen.envs.reach_env import MAX_JOINT_DELTA_RAD
from clamgen.experiments.config import TRAINING_SEEDS
from clamgen.experiments.policies import load_policy
from clamgen.sim.scene import Scene

TRAINING_SEED_BASE = 700_000_000  # far from the RL runs' env seeds (loop seed * 1000 + env)
TRACK_TOL_RAD = 3 * MAX_JOINT_DELTA_RAD  # off the path by more than this: plan again
BASE_CLAMP = 0.995  # the base's tanh action, clamped before its atanh (its pre-squash mean)
OBS_KEYS = ("observation", "achieved_goal", "desired_goal", "obstacles")


def features(obs: dict) -> np.ndarray:
    """The learner's input: joints, tip, goal, goal - tip, obstacle poses, one flat vector."""
    parts = [np.asarray(obs[k], np.float32).reshape(-1) for k in OBS_KEYS]
    parts.insert(3, parts[2] - parts[1])
    return np.concatenate(parts)


class PathExpert:
    """Follows an RRTConnect path planned with a clearance margin; plans again when off it."""

    def __init__(
        self,
        margin_m: float,
        return_to_path: bool,
        straight_when_clear: bool,
        config: RRTConfig | None = None,
    ) -> None:
        self.config = config or RRTConfig()
        self.return_to_path = return_to_path
        self.straight_when_clear = straight_when_clear
        self.scenes = (Scene(margin_m), Scene(0.0))  # the true scene if the margin one rejects
        self.path: np.ndarray | None = None
        self.progress = 0
        self.replans = 0

    def reset(self, env) -> None:
        task = env.unwrapped.task
        for scene in self.scenes:
            scene.set_obstacles(task.obstacles)
        self.goal_m = np.asarray(task.target_position_m, np.float64)
        self.path = self._plan(np.asarray(task.start_joints, np.float64))

    def _plan(self, start: np.ndarray) -> np.ndarray | None:
        self.progress = 0
        for scene in self.scenes:
            if scene.in_collision(start):
                continue
            for goal in goal_candidates(scene, start, self.goal_m, self.config):
                result = plan_joint_path(
                    lambda q, s=scene: not s.in_collision(q), start, goal, self.config, 0.5
                )
                if result.succeeded:
                    return result.waypoints
        return None

    def _free(self, start: np.ndarray, end: np.ndarray) -> bool:
        """Whether the straight joint motion start -> end is clear with the margin."""
        scene = self.scenes[0]
        if scene.in_collision(start):
            return False
        return not scene.move_along(start, end, self.config.check_resolution_rad)[1]

    def label(self, joints: np.ndarray) -> np.ndarray | None:
        """The expert's action (6,) in [-1, 1] at `joints`, or None if it has no path."""
        joints = np.asarray(joints, np.float64)
        if self.straight_when_clear:
            candidates = goal_candidates(self.scenes[0], joints, self.goal_m, self.config)
            if len(candidates) and self._free(joints, candidates[0]):
                self.path = None  # plan again from wherever the arm is if it is ever needed
                return np.clip((candidates[0] - joints) / MAX_JOINT_DELTA_RAD, -1, 1).astype(
                    np.float32
                )
        if self.path is not None:
            ahead = self.path[self.progress :]
            distance = np.max(np.abs(ahead - joints), axis=1)
            nearest = int(np.argmin(distance))
            if distance[nearest] > TRACK_TOL_RAD and not (
                self.return_to_path and self._free(joints, ahead[nearest])
            ):
                self.path = None
            else:
                self.progress += nearest
        if self.path is None:
            self.replans += 1
            self.path = self._plan(joints)
            if self.path is None:
                return None
        nearest_waypoint = self.path[self.progress]
        if np.max(np.abs(nearest_waypoint - joints)) > TRACK_TOL_RAD:  # back to the path first
            target = nearest_waypoint
        else:
            target = self.path[min(self.progress + 1, len(self.path) - 1)]
        return np.clip((target - joints) / MAX_JOINT_DELTA_RAD, -1, 1).astype(np.float32)


class Learner(nn.Module):
    """An MLP from the feature vector (normalised with the data's statistics) to an action:
    with `residual`, a residual added before the tanh to the frozen base policy's (as CLAMGen's
    residual; it starts as the base), else the action itself."""

    def __init__(self, in_dim: int, residual: bool, hidden: int = 256, layers: int = 3) -> None:
        super().__init__()
        dims = [in_dim] + [hidden] * layers
        blocks = []
        for a, b in itertools.pairwise(dims):
            blocks += [nn.Linear(a, b), nn.ReLU()]
        head = nn.Linear(hidden, 6)
        if residual:
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)
        self.net = nn.Sequential(*blocks, head)
        self.residual = residual
        self.register_buffer("mean", torch.zeros(in_dim))
        self.register_buffer("std", torch.ones(in_dim))

    def forward(self, x: torch.Tensor, base_action: torch.Tensor) -> torch.Tensor:
        out = self.net((x - self.mean) / self.std)
        if self.residual:
            out = out + torch.atanh(base_action.clamp(-BASE_CLAMP, BASE_CLAMP))
        return torch.tanh(out)


class LearnerPolicy:
    """`clamgen.policy.Policy`: the learner on the base policy's action."""

    def __init__(self, learner: Learner, base) -> None:
        self.learner, self.base = learner, base

    def reset(self, env=None) -> None:
        pass

    @torch.inference_mode()
    def act(self, obs: dict, base_action: np.ndarray | None = None) -> np.ndarray:
        if base_action is None:
            base_action = self.base.act(obs)
        x = torch.from_numpy(features(obs))[None]
        return self.learner(x, torch.as_tensor(base_action)[None])[0].numpy()


def fit(learner: Learner, x: np.ndarray, b: np.ndarray, y: np.ndarray, steps: int, rng) -> float:
    learner.mean.copy_(torch.from_numpy(x.mean(0)))
    learner.std.copy_(torch.from_numpy(x.std(0) + 1e-3))
    optimizer = torch.optim.Adam(learner.parameters(), lr=1e-3)
    xt, bt, yt = torch.from_numpy(x), torch.from_numpy(b), torch.from_numpy(y)
    loss = torch.zeros(())
    for _ in range(steps):
        idx = torch.from_numpy(rng.integers(0, len(x), 512))
        loss = ((learner(xt[idx], bt[idx]) - yt[idx]) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return float(loss.detach())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--episodes", type=int, default=150, help="per iteration")
    parser.add_argument("--fit-steps", type=int, default=3000, help="per iteration")
    parser.add_argument("--plan-margin-m", type=float, default=0.02)
    parser.add_argument("--num-tasks", type=int, default=100, help="validation tasks per family")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--residual", action=argparse.BooleanOptionalAction, default=True,
        help="learn a residual on the base policy (default) or the action alone",
    )  # fmt: skip
    parser.add_argument(
        "--return-to-path", action=argparse.BooleanOptionalAction, default=True,
        help="off the path, head straight back to it when that is clear, before planning again",
    )  # fmt: skip
    parser.add_argument(
        "--straight-when-clear", action=argparse.BooleanOptionalAction, default=True,
        help="head straight for the nearest goal solution whenever that motion is clear",
    )  # fmt: skip
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    obstacle_kwargs = {"include_obstacle_state": True}
    env = gym.make("CLAMGen/ReachMixed-v0", **obstacle_kwargs).unwrapped
    expert = PathExpert(args.plan_margin_m, args.return_to_path, args.straight_when_clear)
    learner = Learner(len(features(env.reset(seed=0)[0])), args.residual)
    policy = LearnerPolicy(learner, load_policy("base")[0])
    xs: list[np.ndarray] = []
    bs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    next_seed = TRAINING_SEED_BASE + args.seed * 1_000_000
    log = args.out / "log.jsonl"
    for iteration in range(args.iterations):
        tic = time.perf_counter()
        beta = 0.5**iteration
        expert.replans = 0
        successes = 0
        for _ in trange(args.episodes, desc=f"iteration {iteration}", leave=False):
            assert next_seed in TRAINING_SEEDS
            obs, _ = env.reset(seed=next_seed)
            next_seed += 1
            expert.reset(env)
            expert_drives = rng.random() < beta
            clean = True
            for _ in range(env.max_episode_steps or 100):
                label = expert.label(obs["observation"])
                base_action = policy.base.act(obs)
                if label is not None:
                    xs.append(features(obs))
                    bs.append(base_action)
                    ys.append(label)
                if expert_drives and label is not None:
                    action = label
                else:
                    action = policy.act(obs, base_action)
                obs, _, terminated, truncated, info = env.step(action)
                clean &= not info["collision"]
                if terminated or truncated:
                    break
            successes += bool(info["is_success"]) and clean
        loss = fit(learner, np.stack(xs), np.stack(bs), np.stack(ys), args.fit_steps, rng)
        entry = {
            "iteration": iteration,
            "beta": beta,
            "samples": len(xs),
            "rollout_success": successes / args.episodes,
            "replans": expert.replans,
            "loss": loss,
            "seconds": time.perf_counter() - tic,
        }
        print(json.dumps(entry), flush=True)
        with log.open("a") as f:
            f.write(json.dumps(entry) + "\n")
        torch.save(learner.state_dict(), args.out / "learner.pt")
    (args.out / "args.json").write_text(json.dumps(vars(args), default=str, indent=2))
    score(policy, f"distill-priv ({args.out.name})", str(args.out), obstacle_kwargs, args.num_tasks)


if __name__ == "__main__":
    main()
