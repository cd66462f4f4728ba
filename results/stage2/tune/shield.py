"""A collision shield at act time, from the residual's own collision head (an experiment).

    python results/stage2/tune/shield.py RUN_DIR THRESHOLD CANDIDATES NUM_TASKS

Loads RUN_DIR's policy and the collision head of its latest training checkpoint. At each step
it keeps the mean action unless the head predicts a collision with probability >= THRESHOLD;
then it takes, among CANDIDATES samples of the policy and CANDIDATES uniform actions, the one
with the highest Q predicted safe (or the one least likely to collide). Validation seeds only.
"""

import sys
from pathlib import Path

import numpy as np
import torch
from validate import VALIDATION_OFFSET  # the same tasks as validate.py

from clamgen.envs import ReachEnv
from clamgen.experiments import checkpoint as ckpt
from clamgen.experiments.config import VALIDATION_SEEDS
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.stage2 import load_residual_agent


class Shield:
    def __init__(self, agent, threshold: float, candidates: int) -> None:
        self.agent, self.threshold, self.candidates = agent, threshold, candidates
        self.head = agent.aux_losses["collision"].head

    def reset(self, env=None) -> None:
        pass

    @torch.inference_mode()
    def act(self, obs):
        agent, k = self.agent, self.candidates
        batch = {key: np.asarray(value)[None] for key, value in obs.items()}
        low = agent.low_dim_input(batch)
        visual = agent.critic.encoder(agent.encoder_input(batch))
        mean, log_std = agent._pre_squash(visual, agent._actor_view(low))
        generator = torch.Generator().manual_seed(0)
        noise = torch.randn((k, mean.shape[-1]), generator=generator)
        sampled = torch.tanh(mean + noise * log_std.exp())
        uniform = torch.rand((k, mean.shape[-1]), generator=generator) * 2 - 1
        actions = torch.cat([torch.tanh(mean), sampled, uniform])
        n = len(actions)
        critic_low = agent._critic_view(low).expand(n, -1)
        latent, _ = agent.critic.fuse(visual.expand(n, -1), critic_low)
        p_collide = torch.sigmoid(self.head(latent, actions))
        if p_collide[0] < self.threshold:
            return actions[0].numpy()
        safe = p_collide < self.threshold
        if not safe.any():
            return actions[int(p_collide.argmin())].numpy()
        q = agent._q(agent.critic, agent.base_critic, latent, critic_low, actions).min(0).values
        return actions[int(torch.where(safe, q, torch.full_like(q, -1e9)).argmax())].numpy()


def main() -> None:
    torch.set_num_threads(1)
    run, threshold, candidates, num_tasks = sys.argv[1:5]
    run = Path(run)
    agent, config = load_residual_agent(run / "policy.pt")
    state = ckpt.load_torch(ckpt.latest_state_path(run / "checkpoints"), kind=None)["agent"]
    agent.load_state_dict(state)
    kwargs = config.env.make_kwargs()
    kwargs.pop("target_speed")
    seeds = VALIDATION_SEEDS.seeds(int(num_tasks), VALIDATION_SEEDS.start + VALIDATION_OFFSET)
    policy = Shield(agent, float(threshold), int(candidates))
    for family in ("blocked", "obstacles"):
        records = evaluate(ReachEnv(num_obstacles=2, task_family=family, **kwargs), policy, seeds)
        success = np.mean([r.success for r in records])
        collision = np.mean([r.collided for r in records])
        print(
            f"{run.name} {family} threshold {threshold}: success {success:.2f}, "
            f"collision {collision:.2f}"
        )


if __name__ == "__main__":
    main()
