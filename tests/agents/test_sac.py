"""SAC agent: act shapes, numpy fast path, update recipe, determinism, checkpoints, NaN guard,
and a must-learn run on a 2D point-mass goal env with hindsight replay."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from gymnasium import spaces
from point_goal_env import PointGoalEnv

from clamgen.agents.sac import NonFiniteLossError, SACAgent, SACConfig, flatten_obs
from clamgen.replay.buffer import ReplayBuffer, ReplayConfig, obs_spec_from_space
from clamgen.replay.episode import Batch, EpisodeRecorder
from clamgen.replay.pipeline import EpisodePipeline, HindsightConfig

torch.set_num_threads(1)

SMALL = SACConfig(hidden_sizes=(32, 32), batch_size=16)
TOY = SACConfig(hidden_sizes=(64, 64), batch_size=128, actor_lr=1e-3, critic_lr=1e-3, alpha_lr=1e-3)


def random_batch(rng: np.random.Generator, size: int = 16, obs_dim: int = 4) -> Batch:
    def obs() -> dict[str, np.ndarray]:
        return {
            "observation": rng.standard_normal((size, obs_dim - 2)).astype(np.float32),
            "desired_goal": rng.standard_normal((size, 2)).astype(np.float32),
        }

    return Batch(
        obs=obs(),
        action=rng.uniform(-1, 1, (size, 2)).astype(np.float32),
        reward=np.where(rng.random(size) < 0.2, 0.0, -0.01).astype(np.float32),
        next_obs=obs(),
        done=(rng.random(size) < 0.2).astype(np.float32),
        collision=np.zeros(size, np.float32),
    )


def params(agent: SACAgent) -> list[torch.Tensor]:
    modules = (agent.actor, agent.critic, agent.critic_target)
    return [p.detach().clone() for m in modules for p in m.parameters()] + [agent.log_alpha]


def train(config: SACConfig, num_steps: int, seed: int) -> SACAgent:
    """Collect and learn on PointGoalEnv: random actions first, one update per env step."""
    env = PointGoalEnv()
    agent = SACAgent.from_spaces(config, env.observation_space, env.action_space)
    buffer = ReplayBuffer(
        ReplayConfig(capacity=20_000),
        obs_spec_from_space(env.observation_space),
        action_dim=2,
        compute_reward=env.compute_reward,
    )
    pipeline = EpisodePipeline(buffer, HindsightConfig(), env.compute_reward)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    recorder = EpisodeRecorder(obs)
    for step in range(num_steps):
        action = agent.act(obs) if step >= 200 else rng.uniform(-1, 1, 2).astype(np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        recorder.add(action, obs, info)
        if terminated or truncated:
            pipeline.store(recorder.episode())
            obs, _ = env.reset()
            recorder = EpisodeRecorder(obs)
        if len(buffer) >= config.batch_size:
            agent.update(pipeline.sample(config.batch_size, rng))
    return agent


def success_rate(agent: SACAgent, num_episodes: int, seed: int) -> float:
    env = PointGoalEnv()
    successes = 0
    for episode in range(num_episodes):
        obs, _ = env.reset(seed=seed + episode)
        terminated = truncated = False
        while not (terminated or truncated):
            obs, _, terminated, truncated, info = env.step(agent.act(obs, deterministic=True))
        successes += info["is_success"]
    return successes / num_episodes


def test_act_shapes_and_inputs() -> None:
    agent = SACAgent(SMALL, obs_dim=4, action_dim=2)
    obs = {"observation": np.float32([0.1, 0.2]), "desired_goal": np.float32([0.3, 0.4])}
    action = agent.act(obs, deterministic=True)
    assert action.shape == (2,) and action.dtype == np.float32
    np.testing.assert_array_equal(action, agent.act(flatten_obs(obs, SMALL.obs_keys), True))
    batched = {k: np.stack([v, -v, v]) for k, v in obs.items()}
    actions = agent.act(batched, deterministic=True)
    assert actions.shape == (3, 2)
    np.testing.assert_allclose(actions[0], action, atol=1e-6)
    np.testing.assert_array_equal(actions[0], actions[2])
    sampled = agent.act(batched)
    assert sampled.shape == (3, 2) and np.all(np.abs(sampled) <= 1.0)
    assert not np.array_equal(sampled[0], sampled[2])


def test_numpy_fast_path_matches_torch() -> None:
    agent = SACAgent(SMALL, obs_dim=4, action_dim=2)
    rng = np.random.default_rng(0)
    for _ in range(5):  # move weights and normaliser statistics away from their initial values
        agent.update(random_batch(rng))
    features = rng.standard_normal((7, 4)).astype(np.float32) * 3
    fast = agent.act(features, deterministic=True)
    with torch.inference_mode():
        reference = agent.actor.mode(agent.normalizer(torch.from_numpy(features))).numpy()
    np.testing.assert_allclose(fast, reference, atol=1e-5)
    agent._fast_actor = None  # the torch path of act()
    np.testing.assert_allclose(agent.act(features, deterministic=True), reference, atol=1e-6)


def test_actor_log_prob_matches_change_of_variables() -> None:
    agent = SACAgent(SMALL, obs_dim=4, action_dim=2)
    features = torch.randn(64, 4)
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        action, log_prob = agent.actor.sample(features, generator)
        mean, log_std = agent.actor(features)
        pre_squash = torch.atanh(action.double().clamp(-1 + 1e-12, 1 - 1e-12))
        normal = torch.distributions.Normal(mean.double(), log_std.exp().double())
        expected = (normal.log_prob(pre_squash) - torch.log1p(-(action.double() ** 2))).sum(-1)
    torch.testing.assert_close(log_prob.double(), expected, atol=2e-3, rtol=1e-4)


def test_update_returns_metrics_and_soft_updates_target() -> None:
    agent = SACAgent(SMALL, obs_dim=4, action_dim=2)
    target_before = [p.detach().clone() for p in agent.critic_target.parameters()]
    metrics = agent.update(random_batch(np.random.default_rng(0)))
    expected_keys = {
        "train/critic_loss",
        "train/q_mean",
        "train/target_q_mean",
        "train/batch_reward",
        "train/actor_loss",
        "train/entropy",
        "train/alpha",
        "train/alpha_loss",
    }
    assert set(metrics) == expected_keys
    assert all(isinstance(v, float) and np.isfinite(v) for v in metrics.values())
    tau = SMALL.tau
    for before, target, online in zip(
        target_before, agent.critic_target.parameters(), agent.critic.parameters(), strict=True
    ):
        torch.testing.assert_close(target, (1 - tau) * before + tau * online)
    assert agent.num_updates == 1
    assert agent.alpha != SMALL.init_temperature


def test_same_seed_same_parameters() -> None:
    config = dataclasses.replace(TOY, hidden_sizes=(32, 32), seed=3)
    first, second = train(config, 400, seed=3), train(config, 400, seed=3)
    for a, b in zip(params(first), params(second), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    other = SACAgent(dataclasses.replace(config, seed=4), obs_dim=4, action_dim=2)
    fresh = SACAgent(config, obs_dim=4, action_dim=2)
    assert not torch.equal(params(other)[0], params(fresh)[0])


def test_state_dict_round_trip(tmp_path) -> None:
    agent = SACAgent(SMALL, obs_dim=4, action_dim=2)
    rng = np.random.default_rng(0)
    for _ in range(3):
        agent.update(random_batch(rng))
    path = tmp_path / "agent.pt"
    torch.save(agent.state_dict(), path)
    restored = SACAgent(dataclasses.replace(SMALL, seed=123), obs_dim=4, action_dim=2)
    restored.load_state_dict(torch.load(path, weights_only=True))

    features = rng.standard_normal((5, 4)).astype(np.float32)
    np.testing.assert_array_equal(restored.act(features, True), agent.act(features, True))
    np.testing.assert_array_equal(restored.act(features), agent.act(features))
    batch = random_batch(rng)
    assert restored.update(batch) == agent.update(batch)  # optimiser and RNG state resume too
    for a, b in zip(params(restored), params(agent), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_nan_loss_raises_before_changing_parameters() -> None:
    agent = SACAgent(SMALL, obs_dim=4, action_dim=2)
    batch = random_batch(np.random.default_rng(0))
    batch["reward"][3] = np.nan
    critic_before = [p.detach().clone() for p in agent.critic.parameters()]
    with pytest.raises(NonFiniteLossError, match="train/critic_loss is nan"):
        agent.update(batch)
    for before, after in zip(critic_before, agent.critic.parameters(), strict=True):
        assert torch.equal(before, after)
    assert isinstance(NonFiniteLossError("x"), FloatingPointError)


def test_from_spaces_sizes_and_checks() -> None:
    env = PointGoalEnv()
    agent = SACAgent.from_spaces(SMALL, env.observation_space, env.action_space)
    assert (agent.obs_dim, agent.action_dim) == (4, 2)
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        SACAgent.from_spaces(SMALL, env.observation_space, spaces.Box(-2, 2, (2,)))


def test_sac_with_her_solves_point_reaching() -> None:
    agent = train(TOY, num_steps=1500, seed=0)
    assert success_rate(agent, num_episodes=50, seed=10_000) >= 0.9


def test_an_n_step_batch_bootstraps_with_its_own_discount() -> None:
    batch = random_batch(np.random.default_rng(0))
    batch["done"] = np.zeros(16, np.float32)
    batch["discount"] = np.zeros(16, np.float32)  # nothing bootstrapped: the target is r
    metrics = SACAgent(SMALL, obs_dim=4, action_dim=2).update(batch)
    expected = SMALL.reward_scale * batch["reward"].mean()
    assert metrics["train/target_q_mean"] == pytest.approx(expected, rel=1e-5)
    one_step = SACAgent(SMALL, obs_dim=4, action_dim=2).update({**batch, "discount": None})
    assert one_step["train/target_q_mean"] != pytest.approx(expected, rel=1e-5)
