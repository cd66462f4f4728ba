"""How well an image-only agent's encoder knows the joints and the goal.

Runs the state-regression head (`aux.state_weight > 0`) on 200 fresh `Reach-v0` observations
and prints its errors, beside the error of always guessing the mean goal.

    python results/image_only/goal_probe.py runs/image-only-cpu/checkpoints

(a run's checkpoint directory: its newest checkpoint is read; a `state.pt` path works too).
"""

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import clamgen  # noqa: F401  (registers the envs)
from clamgen.agents.residual import LOW_DIM_KEYS, ResidualAgent
from clamgen.agents.sac import flatten_obs
from clamgen.experiments.checkpoint import latest_state_path
from clamgen.experiments.config import config_from_json
from clamgen.experiments.policies import resolve_policy_path
from clamgen.experiments.stage2 import Stage2Config
from clamgen.experiments.train import load_policy_agent

torch.set_num_threads(1)
source = Path(sys.argv[1])
payload = torch.load(latest_state_path(source) if source.is_dir() else source, weights_only=True)
config = config_from_json(payload["config"], Stage2Config)
base, _ = load_policy_agent(resolve_policy_path(config.base_policy))
agent = ResidualAgent(config.agent, base)
agent.load_state_dict(payload["agent"])
env = gym.make(
    "CLAMGen/Reach-v0",
    num_views=config.env.num_views,
    obs_mode="both",
    image_size=config.env.image_size,
)
samples = [env.reset(seed=10_000 + i)[0] for i in range(200)]
obs = {k: np.stack([o[k] for o in samples]) for k in samples[0]}
predicted = torch.as_tensor(agent.predict_state(obs))
true = torch.as_tensor(flatten_obs(obs, LOW_DIM_KEYS))
goal = true[:, 6:]
print("env steps:", payload["progress"]["env_steps"])
joint_error = (predicted - true)[:, :6].abs().mean(0)
goal_error = (predicted[:, 6:] - goal).norm(dim=1).mean()
print("joint error (rad, mean per joint):", joint_error.numpy().round(3))
print("goal error (m, mean distance):", round(goal_error.item(), 3))
print("guessing the mean goal (m):", round((goal - goal.mean(0)).norm(dim=1).mean().item(), 3))
