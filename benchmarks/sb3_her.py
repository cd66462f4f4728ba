"""Wall time to 0.9 success on CLAMGen/Reach-v0: our SAC + HER vs Stable-Baselines3's SAC +
`HerReplayBuffer`, side by side on the same environment, budget and evaluation tasks.

Both use 256x256 networks, batch 256, gamma 0.98, Adam 3e-4, "future" HER with 4 relabelled
goals per real one (her_ratio 0.8), 2000 random steps first, one gradient update per two env
steps, rewards scaled by 100 (the env's -0.01 per step becomes HER's usual -1: ours through
`SACConfig.reward_scale`, SB3 through a reward-scaling wrapper, without which it does not learn
at all in 20k steps) and a learned temperature starting at 0.1. Ours steps 4 envs in lockstep
and adds reversible HER; SB3 steps one env (its HER buffer's usual setting). Every
`--eval-every` env steps the deterministic policy runs 50 fixed evaluation tasks; evaluation
time is not counted.

    python benchmarks/sb3_her.py [--max-steps 40000] [--target 0.9]

Prints env steps and wall time to the target for each, the ratio, and writes
results/benchmarks/sb3_her.csv. Target: ours >= 2x faster in wall time.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import write_csv

import clamgen  # noqa: F401
from clamgen.envs import ReachEnv
from clamgen.experiments.config import VALIDATION_SEEDS, load_preset
from clamgen.experiments.evaluate import SACPolicy, evaluate, summarize
from clamgen.experiments.train import Trainer

NUM_EVAL_TASKS = 50
REWARD_SCALE = 100.0


class ScaledReward(gym.Wrapper):
    """Rewards (from `step` and from `compute_reward`, which SB3's HER buffer calls) times a
    factor: what our SAC does internally with `reward_scale`."""

    def __init__(self, env: gym.Env, scale: float) -> None:
        super().__init__(env)
        self.scale = scale

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward * self.scale, terminated, truncated, info

    def compute_reward(self, achieved_goal, desired_goal, info):
        return self.scale * self.env.unwrapped.compute_reward(achieved_goal, desired_goal, info)


def eval_success(policy) -> float:
    env = ReachEnv(num_obstacles=0)
    return summarize(evaluate(env, policy, VALIDATION_SEEDS.seeds(NUM_EVAL_TASKS)))["success_rate"]


def run_ours(args) -> dict:
    config = load_preset("base")
    loop = dataclasses.replace(config.loop, total_env_steps=args.max_steps, seed=args.seed)
    config = dataclasses.replace(config, run_dir=Path(tempfile.mkdtemp()) / "ours", loop=loop)
    trainer = Trainer(config)
    trainer.start_or_resume()
    train_time, next_eval = 0.0, args.eval_every
    while trainer.progress.env_steps < args.max_steps:
        start = time.perf_counter()
        trainer.step()
        train_time += time.perf_counter() - start
        if trainer.progress.env_steps >= next_eval:
            next_eval += args.eval_every
            success = eval_success(SACPolicy(trainer.agent))
            print(
                f"  ours  {trainer.progress.env_steps:6d} steps {train_time:7.1f} s "
                f"success {success:.2f}",
                flush=True,
            )
            if success >= args.target:
                return {
                    "steps": trainer.progress.env_steps,
                    "seconds": train_time,
                    "success": success,
                }
    return {"steps": None, "seconds": train_time, "success": success}


class SB3Policy:
    def __init__(self, model) -> None:
        self.model = model

    def reset(self, env=None) -> None:
        pass

    def act(self, obs):
        return self.model.predict(obs, deterministic=True)[0]


def run_sb3(args) -> dict:
    from stable_baselines3 import SAC, HerReplayBuffer
    from stable_baselines3.common.callbacks import BaseCallback

    env = ScaledReward(gym.make("CLAMGen/Reach-v0"), REWARD_SCALE)
    model = SAC(
        "MultiInputPolicy",
        env,
        learning_rate=3e-4,
        buffer_size=1_000_000,
        learning_starts=2000,
        batch_size=256,
        gamma=0.98,
        train_freq=2,
        gradient_steps=1,
        ent_coef="auto_0.1",
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        policy_kwargs={"net_arch": [256, 256]},
        seed=args.seed,
        verbose=0,
    )
    outcome = {"steps": None, "seconds": 0.0, "success": 0.0}

    class EvalCallback(BaseCallback):
        def _on_training_start(self) -> None:
            self.clock = time.perf_counter()

        def _on_step(self) -> bool:
            if self.num_timesteps % args.eval_every:
                return True
            outcome["seconds"] += time.perf_counter() - self.clock
            success = eval_success(SB3Policy(model))
            print(
                f"  sb3   {self.num_timesteps:6d} steps {outcome['seconds']:7.1f} s "
                f"success {success:.2f}",
                flush=True,
            )
            outcome["success"] = success
            self.clock = time.perf_counter()
            if success >= args.target:
                outcome["steps"] = self.num_timesteps
                return False
            return True

    model.learn(total_timesteps=args.max_steps, callback=EvalCallback())
    return outcome


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-steps", type=int, default=40_000)
    parser.add_argument("--eval-every", type=int, default=2_500)
    parser.add_argument("--target", type=float, default=0.9)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print("CLAMGen SAC + HER + reversible HER:")
    ours = run_ours(args)
    print("Stable-Baselines3 SAC + HerReplayBuffer:")
    sb3 = run_sb3(args)
    print(f"\nto {args.target} success on {NUM_EVAL_TASKS} held-out tasks (eval time excluded):")
    for name, result in (("CLAMGen", ours), ("SB3", sb3)):
        steps = result["steps"] if result["steps"] is not None else f">{args.max_steps}"
        print(f"  {name:8s} {steps} env steps, {result['seconds']:.1f} s")
    reached = ours["steps"] is not None
    # If SB3 never reached the target its time is a lower bound, and so is the ratio.
    ratio = sb3["seconds"] / ours["seconds"] if reached else float("nan")
    bound = "" if sb3["steps"] is not None else " (lower bound: SB3 did not reach it)"
    print(f"  wall-time ratio SB3 / CLAMGen: {ratio:.2f}x{bound} (target >= 2x)")
    path = write_csv(
        "sb3_her",
        [
            {
                "method": "clamgen",
                "steps_to_target": ours["steps"],
                "seconds": round(ours["seconds"], 1),
                "target": args.target,
                "ratio_sb3_over_ours": round(ratio, 2),
            },
            {
                "method": "sb3",
                "steps_to_target": sb3["steps"],
                "seconds": round(sb3["seconds"], 1),
                "target": args.target,
                "ratio_sb3_over_ours": round(ratio, 2),
            },
        ],
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
