"""Stable-Baselines3 SAC + HER from camera images and joints on CLAMGen/ReachObstacles-v0.

`clamgen.envs.wrappers.StackedViews` presents the views as one channel-first uint8 image
(V * 4, H, W), which SB3 recognises: its `MultiInputPolicy` encodes `images` with a CNN
(NatureCNN) and the joints and goals with an MLP. Nothing else is adapted: the env's
vectorised `compute_reward` serves SB3's `HerReplayBuffer` as it is.

    pip install -e ".[bench]"   # stable-baselines3
    python examples/sb3_sac_her_images.py                      # 1000 steps, 1-2 min on 2 CPU cores
    python examples/sb3_sac_her_images.py --steps 100000 --buffer-size 100000 --device cuda
    python examples/sb3_sac_her_images.py --eval-guard escapes  # also through a depth wrapper

The default is a smoke run of the whole pipeline, far too short to learn the task: it prints the
training speed and the success rate of the deterministic policy on held-out tasks, and saves the
model. Two limits of this setup compared with `clamgen train-residual`: SB3's HER relabels the
goal vectors but cannot redraw the target in the stored images (the project's replay re-renders
them), and its buffer keeps every observation twice (current and next), about
2 * V * 4 * H * W bytes per step (64 KiB at 2 views of 64 px).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import clamgen  # noqa: F401  (registers the CLAMGen env ids)
from clamgen.envs.wrappers import StackedViews
from clamgen.experiments.depth_planner import ESCAPES, HYBRID, DepthGuard

SHIELD = dict.fromkeys(HYBRID, DepthGuard())

# Evaluation tasks: seeds far above the small ones the training env starts from.
FIRST_EVAL_SEED = 2_000_000_000
GUARDS = {"none": None, "shield": SHIELD, "escapes": ESCAPES, "hybrid": HYBRID}
"""The depth wrappers the trained model can also be evaluated through (`--eval-guard`):
the shield alone at 1 cm, the escape rows' and the hybrid rows' settings by number of views."""


def make_env(num_views: int, image_size: int, guard: str = "none") -> gym.Env:
    """The obstacle env with joints, goals and `num_views` RGBD views stacked channel-first;
    with a `guard` (`GUARDS`), every action passes that depth wrapper in `env.step`."""
    setting = GUARDS[guard]
    extra = setting[num_views].env_kwargs() if setting else {}
    env = gym.make(
        "CLAMGen/ReachObstacles-v0",
        num_views=num_views,
        image_size=image_size,
        obs_mode="both",
        **extra,
    )
    if setting:
        env = setting[num_views].wrap_env(env)  # reads the views before they are stacked
    return StackedViews(env)


def success_rate(model, env: gym.Env, num_episodes: int) -> float:
    """Success (reached without any collision) of the deterministic policy on held-out seeds."""
    successes = 0
    for i in range(num_episodes):
        obs, _ = env.reset(seed=FIRST_EVAL_SEED + i)
        done, collided = False, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            collided |= bool(info["collision"])
            done = terminated or truncated
        successes += bool(info["is_success"]) and not collided
    return successes / num_episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000, help="env steps to train for")
    parser.add_argument("--num-views", type=int, default=2, help="camera views (1 to 4)")
    parser.add_argument("--image-size", type=int, default=64, help="pixels per side (>= 36)")
    parser.add_argument("--buffer-size", type=int, default=None, help="default: --steps")
    parser.add_argument("--learning-starts", type=int, default=500, help="random steps first")
    parser.add_argument("--eval-episodes", type=int, default=10, help="held-out tasks")
    parser.add_argument(
        "--eval-guard",
        choices=sorted(GUARDS),
        default="none",
        help="also evaluate through this depth wrapper inside env.step (GuardedEnv; the "
        "hybrid plans with OMPL)",
    )
    parser.add_argument("--device", default="auto", help="torch device (cpu, cuda, auto)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/sb3_sac_her_images/model.zip"))
    args = parser.parse_args()
    try:
        from stable_baselines3 import SAC, HerReplayBuffer
    except ImportError as error:
        raise SystemExit(
            "this example needs stable-baselines3: pip install -e '.[bench]'"
        ) from error
    if args.image_size < 36:
        raise SystemExit(f"--image-size must be >= 36 for SB3's NatureCNN, got {args.image_size}")
    # HER samples only from finished episodes (100 steps each): start learning after one.
    learning_starts = max(args.learning_starts, 101)
    if args.steps <= learning_starts:
        raise SystemExit(f"--steps must exceed the {learning_starts} random steps")

    env = make_env(args.num_views, args.image_size)
    print(f"observation: {env.observation_space}")
    model = SAC(
        "MultiInputPolicy",
        env,
        buffer_size=args.buffer_size or args.steps,
        learning_starts=learning_starts,
        batch_size=128,
        gamma=0.98,
        train_freq=2,
        gradient_steps=1,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        policy_kwargs={"net_arch": [256, 256]},
        device=args.device,
        seed=args.seed,
        verbose=0,
    )
    print(f"image encoder: {type(model.policy.actor.features_extractor.extractors['images'])}")
    start = time.perf_counter()
    model.learn(total_timesteps=args.steps, progress_bar=False)
    seconds = time.perf_counter() - start
    print(f"trained {args.steps} steps in {seconds:.1f} s ({args.steps / seconds:.1f} steps/s)")
    rate = success_rate(model, make_env(args.num_views, args.image_size), args.eval_episodes)
    print(f"success rate on {args.eval_episodes} held-out tasks: {rate:.2f}")
    if args.eval_guard != "none":
        guarded = make_env(args.num_views, args.image_size, args.eval_guard)
        rate = success_rate(model, guarded, args.eval_episodes)
        print(f"through the {args.eval_guard} guard in env.step, the same tasks: {rate:.2f}")
        guarded.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    model.save(args.out)
    print(f"saved {args.out}")
    env.close()


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
