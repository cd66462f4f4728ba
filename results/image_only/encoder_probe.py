"""Can an encoder find the target? Supervised goal regression from two 64 px RGBD views.

Renders random `Reach-v0` scenes (random joints and goal), then trains each encoder variant
with a small dense head to regress the goal position (and the joint angles) from the images
alone, with the same random 56 px crops the RL agent trains on, and reports the goal error on
held-out scenes (centre crop) against always guessing the mean goal. No RL: this isolates the
encoder's ability to locate a 2 cm target.

    python results/image_only/encoder_probe.py [--train 6000] [--steps 3000]
"""

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
from torch import nn

import clamgen  # noqa: F401  (registers the envs)
from clamgen.agents.augment import center_crop, random_crop
from clamgen.agents.encoders import EncoderConfig, MultiViewEncoder

VARIANTS = {
    "flatten, strides 2,2,1,1 (image-only-cpu)": EncoderConfig(
        image_size=56, num_views=2, num_channels=16, strides=(2, 2, 1, 1)
    ),
    "spatial softmax, strides 2,2,1,1": EncoderConfig(
        image_size=56, num_views=2, num_channels=16, strides=(2, 2, 1, 1), spatial_softmax=True
    ),
    "spatial softmax, strides 2,1,1,1": EncoderConfig(
        image_size=56, num_views=2, num_channels=16, strides=(2, 1, 1, 1), spatial_softmax=True
    ),
}


def render_scenes(count: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    env = gym.make("CLAMGen/Reach-v0", num_views=2, obs_mode="both", image_size=64)
    images, states = [], []
    for i in range(count):
        obs, _ = env.reset(seed=seed + i)
        images.append(obs["images"])
        states.append(np.concatenate([obs["observation"], obs["desired_goal"]]))
    env.close()
    return torch.as_tensor(np.stack(images)), torch.as_tensor(np.stack(states))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", type=int, default=6000, help="training scenes")
    parser.add_argument("--test", type=int, default=500, help="held-out scenes")
    parser.add_argument("--steps", type=int, default=3000, help="gradient steps per variant")
    parser.add_argument("--batch", type=int, default=64)
    args = parser.parse_args()
    torch.manual_seed(0)
    start = time.perf_counter()
    train_images, train_states = render_scenes(args.train, seed=0)
    test_images, test_states = render_scenes(args.test, seed=1_000_000)
    print(f"rendered {args.train + args.test} scenes in {time.perf_counter() - start:.0f} s")
    mean, std = train_states.mean(0), train_states.std(0)
    goal = test_states[:, 6:]
    print(f"guessing the mean goal: {(goal - mean[6:]).norm(dim=1).mean():.3f} m")
    generator = torch.Generator().manual_seed(0)
    for name, config in VARIANTS.items():
        encoder = MultiViewEncoder(config)
        head = nn.Sequential(nn.Linear(config.feature_dim, 256), nn.ReLU(), nn.Linear(256, 9))
        params = [*encoder.parameters(), *head.parameters()]
        optimizer = torch.optim.Adam(params, lr=1e-3)
        start = time.perf_counter()
        for step in range(1, args.steps + 1):
            index = torch.randint(args.train, (args.batch,), generator=generator)
            crops = random_crop(train_images[index], config.image_size, generator)
            target = (train_states[index] - mean) / std
            loss = (head(encoder(crops)) - target).pow(2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            if step % (args.steps // 4) == 0:
                with torch.no_grad():
                    crops = center_crop(test_images, config.image_size)
                    predicted = head(encoder(crops)) * std + mean
                goal_error = (predicted[:, 6:] - goal).norm(dim=1).mean()
                joint_error = (predicted[:, :6] - test_states[:, :6]).abs().mean()
                print(
                    f"{name}: step {step}, goal error {goal_error:.3f} m, "
                    f"joint error {joint_error:.3f} rad, {time.perf_counter() - start:.0f} s"
                )


if __name__ == "__main__":
    main()
