"""Stage-2 residual agent: starts exactly at the base, learns, and every switch does its job."""

import dataclasses

import numpy as np
import pytest
import torch

from clamgen.agents.augment import center_crop
from clamgen.agents.aux_losses import AuxLossConfig
from clamgen.agents.encoders import EncoderConfig
from clamgen.agents.residual import ResidualAgent, ResidualConfig
from clamgen.agents.sac import SACAgent, SACConfig

torch.set_num_threads(1)
VIEWS, CROP, PAD = 2, 32, 4


def base_agent() -> SACAgent:
    agent = SACAgent(SACConfig(hidden_sizes=(32, 32), seed=1), obs_dim=9, action_dim=6)
    with torch.no_grad():  # a base with non-trivial normalisation and outputs
        agent.normalizer.mean.copy_(torch.linspace(-0.5, 0.5, 9))
    return agent


def config(**kwargs) -> ResidualConfig:
    encoder = EncoderConfig(
        image_size=CROP,
        num_views=VIEWS,
        num_channels=8,
        strides=(2, 2, 1, 1),
        hidden_dim=32,
        feature_dim=16,
        low_dim_size=16,
    )
    return dataclasses.replace(
        ResidualConfig(
            encoder=encoder,
            crop_padding=PAD,
            hidden_sizes=(32, 32),
            batch_size=8,
            aux=AuxLossConfig(collision_hidden_sizes=(16,)),
        ),
        **kwargs,
    )


def batch(size=8, seed=0, obstacles=False):
    rng = np.random.default_rng(seed)

    def obs():
        data = {
            "observation": rng.uniform(-2, 2, (size, 6)).astype(np.float32),
            "desired_goal": rng.uniform(0, 0.5, (size, 3)).astype(np.float32),
            "achieved_goal": rng.uniform(0, 0.5, (size, 3)).astype(np.float32),
            "images": rng.integers(
                0, 256, (size, VIEWS, 4, CROP + 2 * PAD, CROP + 2 * PAD), dtype=np.uint8
            ),
        }
        if obstacles:
            data["obstacles"] = rng.uniform(-0.5, 0.5, (size, 2, 8)).astype(np.float32)
        return data

    return {
        "obs": obs(),
        "action": rng.uniform(-1, 1, (size, 6)).astype(np.float32),
        "reward": np.full(size, -0.01, np.float32),
        "next_obs": obs(),
        "done": np.zeros(size, np.float32),
        "collision": (rng.random(size) < 0.5).astype(np.float32),
    }


def test_residual_starts_exactly_at_the_base_action_and_base_q():
    base = base_agent()
    agent = ResidualAgent(config(), base)
    data = batch()["obs"]
    np.testing.assert_allclose(
        agent.act(data, deterministic=True), base.act(data, deterministic=True), atol=1e-6
    )
    low_dim = agent.low_dim_input(data)
    latent, _ = agent.critic.features(agent._visual(data, train=False), low_dim)
    action = torch.zeros(8, 6)
    q = agent._q(agent.critic, agent.base_critic, latent, low_dim, action)
    torch.testing.assert_close(q, base.critic(low_dim, action))


def test_update_trains_residual_and_encoder_but_not_the_frozen_base():
    base = base_agent()
    agent = ResidualAgent(config(warmup_updates=1), base)
    frozen = [p.detach().clone() for p in (*base.actor.parameters(), *base.critic.parameters())]
    encoder_before = [p.detach().clone() for p in agent.critic.encoder.parameters()]
    for step in range(3):
        metrics = agent.update(batch(seed=step))
    for name in (
        "train/critic_loss",
        "train/actor_loss",
        "train/curl_loss",
        "train/across_view_loss",
        "train/collision_loss",
    ):
        assert np.isfinite(metrics[name])
    assert metrics["train/warmup"] == 0.0
    after = [p.detach() for p in (*base.actor.parameters(), *base.critic.parameters())]
    for a, b in zip(frozen, after, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    changed = [
        not torch.equal(a, b)
        for a, b in zip(encoder_before, agent.critic.encoder.parameters(), strict=True)
    ]
    assert all(changed)


def test_finetune_base_updates_the_base():
    base = base_agent()
    agent = ResidualAgent(config(finetune_base=True, warmup_updates=0), base)
    before = [p.detach().clone() for p in base.actor.parameters()]
    agent.update(batch())
    assert any(not torch.equal(a, b) for a, b in zip(before, base.actor.parameters(), strict=True))


def test_switches_change_what_they_claim():
    base = base_agent()
    metrics = ResidualAgent(
        config(aux=AuxLossConfig(curl_weight=0, across_view_weight=0, collision_weight=0)), base
    ).update(batch())
    assert not {"train/curl_loss", "train/across_view_loss", "train/collision_loss"} & set(metrics)
    # No residual: no base in the action or in Q, and the actor's mean is not zero-initialised.
    plain = ResidualAgent(config(residual=False), base_agent())
    data = batch()["obs"]
    assert not np.allclose(plain.act(data, True), base.act(data, True), atol=1e-3)
    assert plain._view_mask(64) is not None
    assert ResidualAgent(config(view_dropout=0.0), base_agent())._view_mask(64) is None
    masks = ResidualAgent(config(view_dropout=0.9), base_agent())._view_mask(1000)
    assert masks.any(1).all()  # never all views dropped


def test_image_only_agent_ignores_joints_and_goal():
    agent = ResidualAgent(config(residual=False, use_low_dim=False), base_agent())
    data = batch()["obs"]
    moved = dict(data, observation=data["observation"] + 1.0, desired_goal=data["desired_goal"] * 2)
    np.testing.assert_array_equal(agent.act(data, True), agent.act(moved, True))
    assert np.isfinite(agent.update(batch())["train/critic_loss"])
    with pytest.raises(ValueError, match="image-only"):
        config(use_low_dim=False)  # residual on a joint-space base needs joints


def test_privileged_critic_sees_joints_and_goal_but_the_policy_does_not():
    agent = ResidualAgent(
        config(residual=False, use_low_dim=False, privileged_critic=True), base_agent()
    )
    data = batch()
    moved = dict(data["obs"], observation=data["obs"]["observation"] + 1.0)
    np.testing.assert_array_equal(agent.act(data["obs"], True), agent.act(moved, True))
    x, y = agent._train_inputs(data), agent._train_inputs(dict(data, obs=moved))
    actor_x, actor_y = agent._actor_view(x.state), agent._actor_view(y.state)
    critic_x, critic_y = agent._critic_view(x.state), agent._critic_view(y.state)
    assert torch.equal(actor_x, actor_y) and not torch.equal(critic_x, critic_y)
    with torch.no_grad():
        # Same crops and actions: only the joints and goal differ.
        q = [
            agent.critic(agent.critic.features(x.visual_in, d)[0], x.action)
            for d in (critic_x, critic_y)
        ]
    assert not torch.allclose(*q)
    assert np.isfinite(agent.update(data)["train/actor_loss"])
    with pytest.raises(ValueError, match="privileged_critic"):
        config(privileged_critic=True)


def test_privileged_base_q_starts_the_image_only_critic_at_q_base():
    base = base_agent()
    image_only = dict(residual=False, use_low_dim=False, privileged_critic=True)
    agent = ResidualAgent(config(**image_only, privileged_base_q=True, warmup_updates=2), base)
    data = batch()
    x = agent._train_inputs(data)
    low_dim = agent._critic_view(x.state)
    with torch.no_grad():
        latent, _ = agent.critic.features(x.visual_in, low_dim)
        q = agent._q(agent.critic, agent.base_critic, latent, low_dim, x.action)
    torch.testing.assert_close(q, base.critic(low_dim, x.action))
    # The policy has no base action: it still ignores the joints and the goal.
    moved = dict(data["obs"], observation=data["obs"]["observation"] + 1.0)
    np.testing.assert_array_equal(agent.act(data["obs"], True), agent.act(moved, True))
    warmups = [agent.update(batch(seed=i))["train/warmup"] for i in range(3)]
    assert warmups == [1.0, 1.0, 0.0]
    plain = ResidualAgent(config(**image_only), base_agent())
    assert plain.update(data)["train/warmup"] == 0.0
    with pytest.raises(ValueError, match="privileged_base_q"):
        config(residual=False, use_low_dim=False, privileged_base_q=True)


def test_encoder_from_critic_off_leaves_the_encoder_to_the_aux_losses():
    def encoder_after_update(reward, **kwargs):
        aux = AuxLossConfig(collision_hidden_sizes=(16,), state_weight=1.0)
        agent = ResidualAgent(
            config(residual=False, use_low_dim=False, privileged_critic=True, aux=aux, **kwargs),
            base_agent(),
        )
        data = batch()
        agent.update(dict(data, reward=np.full_like(data["reward"], reward)))
        return list(agent.critic.encoder.parameters())

    def same(a, b):
        return all(torch.equal(p, q) for p, q in zip(a, b, strict=True))

    # The rewards change the critic loss only: they reach the encoder only through the critic.
    assert not same(encoder_after_update(-0.01), encoder_after_update(-1.0))
    detached = dict(encoder_from_critic=False)
    assert same(encoder_after_update(-0.01, **detached), encoder_after_update(-1.0, **detached))
    no_aux = AuxLossConfig(curl_weight=0, across_view_weight=0, state_weight=0)
    with pytest.raises(ValueError, match="encoder_from_critic"):
        config(encoder_from_critic=False, aux=no_aux)


def test_state_regression_trains_the_encoder_and_its_head():
    def trained(state_weight):
        aux = AuxLossConfig(collision_hidden_sizes=(16,), state_weight=state_weight)
        agent = ResidualAgent(config(residual=False, use_low_dim=False, aux=aux), base_agent())
        metrics = agent.update(batch())
        return agent, metrics

    (on, metrics), (off, off_metrics) = trained(1.0), trained(0.0)
    assert np.isfinite(metrics["train/state_loss"]) and "train/state_loss" not in off_metrics
    for module in ("state_head", "critic"):
        a, b = getattr(on, module).state_dict(), getattr(off, module).state_dict()
        assert any(not torch.equal(a[k], b[k]) for k in a), module
    # The head reads the visual encoding only: no joints or goal reach it.
    assert on.state_head[0].in_features == on.feature_dim


def test_privileged_obstacle_residual_uses_poses_not_images():
    agent = ResidualAgent(config(obs_source="obstacles"), base_agent())
    data = batch(obstacles=True)
    metrics = agent.update(data)
    assert "train/curl_loss" not in metrics and np.isfinite(metrics["train/critic_loss"])
    assert agent.act(data["obs"], True).shape == (8, 6)


def test_arm_keypoints_reach_the_privileged_encoding():
    agent = ResidualAgent(config(obs_source="obstacles", arm_keypoints=True), base_agent())
    data = batch(obstacles=True)
    assert np.isfinite(agent.update(data)["train/critic_loss"])
    obs = data["obs"]
    encode = agent.critic.encoder
    features = encode(agent._visual(obs, train=False))
    # The same obstacles with the arm elsewhere: the encoding changes (the poses alone do not).
    moved = {**obs, "observation": obs["observation"] + 0.3}
    assert not torch.allclose(features, encode(agent._visual(moved, train=False)))
    assert agent.act(obs, True).shape == (8, 6)
    with pytest.raises(ValueError, match="arm_keypoints"):
        config(arm_keypoints=True)


def test_goal_offset_gives_the_networks_the_tips_offset_to_the_goal():
    agent = ResidualAgent(config(goal_offset=True), base_agent())
    plain = ResidualAgent(config(), base_agent())
    data = batch()
    obs = data["obs"]
    state = agent.low_dim_input(obs)
    assert state.shape == (8, 9 + 6)
    # The first nine are the paper's normalised joints and goal; the rest depend on both.
    torch.testing.assert_close(state[:, :9], plain.low_dim_input(obs))
    nearer = {**obs, "desired_goal": obs["desired_goal"] + 0.01}
    assert not torch.allclose(agent.low_dim_input(nearer)[:, 9:], state[:, 9:])
    assert np.isfinite(agent.update(data)["train/critic_loss"])
    assert agent.act(obs, True).shape == (8, 6)
    with pytest.raises(ValueError, match="goal_offset"):
        config(goal_offset=True, use_low_dim=False, residual=False)


def test_center_train_crops_learn_on_what_acting_sees_and_keep_curls_random_key():
    obs = batch()["obs"]
    centre = ResidualAgent(config(train_crops="center"), base_agent())
    torch.testing.assert_close(centre._visual(obs, train=True), centre._visual(obs, train=False))
    assert not torch.equal(centre._train_inputs(batch()).key_in(), centre._visual(obs, False))
    randomly = ResidualAgent(config(), base_agent())
    assert not torch.equal(randomly._visual(obs, train=True), randomly._visual(obs, train=False))
    assert np.isfinite(centre.update(batch())["train/curl_loss"])
    with pytest.raises(ValueError, match="train_crops"):
        config(train_crops="corner")


def test_train_shift_padding_widens_the_random_crops_by_repeated_edges():
    obs = batch()["obs"]
    agent = ResidualAgent(config(train_shift_padding=3), base_agent())
    crops = agent._visual(obs, train=True)
    assert crops.shape == (8, VIEWS, 4, CROP, CROP)
    # Every crop is a window of the edge-padded images, the shifts up to PAD + 3 either way.
    padded = np.pad(obs["images"], [(0, 0)] * 3 + [(3, 3), (3, 3)], mode="edge")
    side = CROP + 2 * (PAD + 3)
    offsets = []
    for b in range(8):
        for v in range(VIEWS):
            found = [
                (t, u)
                for t in range(side - CROP + 1)
                for u in range(side - CROP + 1)
                if np.array_equal(crops[b, v].numpy(), padded[b, v, :, t : t + CROP, u : u + CROP])
            ]
            assert found
            offsets += found
    assert any(t < 3 or t > 2 * PAD + 3 or u < 3 or u > 2 * PAD + 3 for t, u in offsets)
    acting = center_crop(torch.as_tensor(obs["images"]), CROP)
    torch.testing.assert_close(agent._visual(obs, train=False), acting)
    with pytest.raises(ValueError, match="train_shift_padding"):
        config(train_shift_padding=2, train_crops="center")
    with pytest.raises(ValueError, match="train_shift_padding"):
        config(train_shift_padding=-1)


def test_an_n_step_batch_bootstraps_with_its_own_discount():
    data = batch(obstacles=True)
    size = len(data["action"])
    data["done"] = np.zeros(size, np.float32)
    agent = ResidualAgent(config(obs_source="obstacles", warmup_updates=0), base_agent())
    target = agent._td_target(agent._train_inputs({**data, "discount": np.zeros(size, "f4")}))
    reward = torch.as_tensor(data["reward"]) * agent.config.reward_scale
    torch.testing.assert_close(target, reward)
    assert not torch.allclose(agent._td_target(agent._train_inputs(data)), reward)


def test_acting_by_the_critic_picks_a_candidate_no_worse_than_the_mean():
    agent = ResidualAgent(config(obs_source="obstacles", warmup_updates=0), base_agent())
    data = batch(obstacles=True)
    for _ in range(3):
        agent.update(data)
    obs = data["obs"]

    def q(actions):
        with torch.no_grad():
            state = agent.low_dim_input(obs)
            visual = agent.critic.encoder(agent._visual(obs, train=False))
            latent, _ = agent.critic.fuse(visual, state)
            values = agent._q(
                agent.critic, agent.base_critic, latent, state, torch.as_tensor(actions)
            )
            return values.min(dim=0).values.numpy()

    chosen = agent.act_by_critic(obs, 16, generator=torch.Generator().manual_seed(0))
    assert chosen.shape == (8, 6) and np.abs(chosen).max() <= 1
    assert np.all(q(chosen) >= q(agent.act(obs, deterministic=True)) - 1e-5)
    # Seeded: the same generator seed gives the same choice; one candidate is the mean action.
    again = agent.act_by_critic(obs, 16, generator=torch.Generator().manual_seed(0))
    np.testing.assert_array_equal(chosen, again)
    np.testing.assert_allclose(agent.act_by_critic(obs, 1), agent.act(obs, True), atol=1e-6)


def test_state_dict_round_trip_gives_identical_actions(tmp_path):
    agent = ResidualAgent(config(warmup_updates=0), base_agent())
    agent.update(batch())
    torch.save(agent.state_dict(), tmp_path / "agent.pt")
    other = ResidualAgent(config(warmup_updates=0), base_agent())
    other.load_state_dict(torch.load(tmp_path / "agent.pt", weights_only=True))
    data = batch(seed=5)["obs"]
    np.testing.assert_array_equal(agent.act(data, True), other.act(data, True))


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="obs_source"):
        config(obs_source="lidar")
    with pytest.raises(ValueError, match="view_dropout"):
        config(view_dropout=1.0)


def _trained_state() -> dict:
    """A policy file's agent state of an agent that has learnt something (a started policy)."""
    source = ResidualAgent(config(warmup_updates=0, seed=3), base_agent())
    for step in range(3):
        source.update(batch(seed=step))
    return {k: v for k, v in source.state_dict().items() if k in source.policy_state_keys()}


def test_start_from_acts_as_the_started_policy_with_fresh_targets_and_temperature():
    state = _trained_state()
    started = ResidualAgent(config(warmup_updates=0, init_temperature=0.05), base_agent())
    started.start_from(state)
    source = ResidualAgent(config(warmup_updates=0, seed=3), base_agent())
    source.load_state_dict(state, policy_only=True)
    data = batch(seed=7)["obs"]
    np.testing.assert_array_equal(started.act(data, True), source.act(data, True))
    # The target copies restart from the started networks, not from the fresh ones.
    for target, online in (
        (started.critic_target, started.critic),
        (started.key_encoder, started.critic.encoder),
    ):
        for a, b in zip(target.parameters(), online.parameters(), strict=True):
            torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert started.num_updates == 0
    assert started.log_alpha.exp().item() == pytest.approx(0.05)
    with pytest.raises(KeyError, match="actor"):
        started.start_from({k: v for k, v in state.items() if k != "actor"})


def test_freeze_encoder_and_critic_first_updates():
    agent = ResidualAgent(
        config(warmup_updates=0, freeze_encoder=True, critic_first_updates=2), base_agent()
    )
    agent.start_from(_trained_state())
    encoder = [p.detach().clone() for p in agent.critic.encoder.parameters()]
    actor = [p.detach().clone() for p in agent.actor.parameters()]
    q_head = [p.detach().clone() for p in agent.critic.q.parameters()]
    alpha = agent.log_alpha.item()
    for step in range(2):  # critic only: the actor and the temperature wait
        metrics = agent.update(batch(seed=step))
        assert metrics["train/critic_first"] == 1.0 and "train/actor_loss" not in metrics
    assert all(torch.equal(a, b) for a, b in zip(actor, agent.actor.parameters(), strict=True))
    assert agent.log_alpha.item() == alpha
    assert any(
        not torch.equal(a, b) for a, b in zip(q_head, agent.critic.q.parameters(), strict=True)
    )
    metrics = agent.update(batch(seed=2))  # then the actor learns too
    assert "train/actor_loss" in metrics
    assert any(not torch.equal(a, b) for a, b in zip(actor, agent.actor.parameters(), strict=True))
    for a, b in zip(encoder, agent.critic.encoder.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_anchor_loss_starts_at_zero_and_pulls_towards_the_started_actor():
    state = _trained_state()
    agent = ResidualAgent(config(warmup_updates=0, anchor_weight=1.0), base_agent())
    agent.start_from(state)
    metrics = agent.update(batch(seed=0))
    assert metrics["train/anchor_loss"] == pytest.approx(0.0, abs=1e-10)
    # After moving away, a heavily anchored actor moves back towards the started one.
    anchored = ResidualAgent(config(warmup_updates=0, anchor_weight=1e4), base_agent())
    anchored.start_from(state)
    with torch.no_grad():
        for p in anchored.actor.parameters():
            p.add_(0.05 * torch.randn_like(p))
    losses = [anchored.update(batch(seed=s))["train/anchor_loss"] for s in range(20)]
    assert losses[-1] < 0.5 * losses[0]
    with pytest.raises(ValueError, match="anchor_weight"):
        config(anchor_weight=-1.0)
    with pytest.raises(ValueError, match="critic_first_updates"):
        config(critic_first_updates=-1)
