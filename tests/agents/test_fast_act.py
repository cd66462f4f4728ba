"""The vision residual's fast deterministic act gives the module path's actions, bit for bit."""

import dataclasses

import numpy as np
import pytest
import torch
from test_residual import base_agent, batch, config

from clamgen.agents.encoders import EMULATED_BF16_ENV
from clamgen.agents.fast_act import ResidualActing
from clamgen.agents.residual import ResidualAgent

ENCODER = config().encoder
VARIANTS = {
    "shipped layout": {},
    "one conv stack per view": {"encoder": dataclasses.replace(ENCODER, share_view_weights=False)},
    "NCHW convs": {"encoder": dataclasses.replace(ENCODER, channels_last=False)},
    "no layer norm, no mask indicator": {
        "encoder": dataclasses.replace(ENCODER, output_layer_norm=False, view_mask_indicator=False)
    },
    "keypoints (spatial softmax)": {
        "encoder": dataclasses.replace(ENCODER, spatial_softmax=True, strides=(2, 1, 1, 1))
    },
    "previous action and goal offset": {"previous_action": True, "goal_offset": True},
    "no residual": {"residual": False},
    "image-only": {"residual": False, "use_low_dim": False},
}


def perturbed_agent(**kwargs) -> ResidualAgent:
    """An agent whose every acting weight is away from its initialisation (the residual's
    output layer starts at zero), so that every part of the forward pass shows."""
    agent = ResidualAgent(config(**kwargs), base_agent())
    generator = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for parameter in agent.nets.policy.parameters():
            parameter.add_(0.1 * torch.randn(parameter.shape, generator=generator))
    return agent


def single_observations(count: int, seed: int):
    data = batch(size=count, seed=seed)["obs"]
    data["previous_action"] = np.random.default_rng(seed).uniform(-1, 1, (count, 6))
    data["previous_action"] = data["previous_action"].astype(np.float32)
    # Dark and bright images too, so that the projection meets sparse and dense features.
    data["images"][0] //= 16
    return [{key: value[i] for key, value in data.items()} for i in range(count)]


@pytest.mark.parametrize("variant", [*VARIANTS, "bf16 convs"])
def test_the_fast_act_is_the_module_paths_action_bit_for_bit(variant, monkeypatch):
    if variant == "bf16 convs":  # as on a CPU that computes bf16 (emulated here, same maths)
        monkeypatch.setenv(EMULATED_BF16_ENV, "1")
        settings = {"encoder": dataclasses.replace(ENCODER, bf16_autocast=True)}
    else:
        settings = VARIANTS[variant]
    agent = perturbed_agent(**settings)
    fast = agent.fast_act
    assert isinstance(fast, ResidualActing)
    for obs in single_observations(4, seed=len(variant)):
        agent.fast_act = fast
        action = agent.act(obs, deterministic=True)
        agent.fast_act = None
        expected = agent.act(obs, deterministic=True)
        assert action.shape == (6,) and action.dtype == np.float32
        np.testing.assert_array_equal(action, expected)
        assert np.abs(expected).max() > 0.01


def test_the_fast_act_reads_the_weights_at_each_call():
    agent = perturbed_agent()
    obs = single_observations(1, seed=0)[0]
    before = agent.act(obs, deterministic=True)
    with torch.no_grad():  # as an optimiser step or load_state_dict changes them: in place
        agent.actor.policy.trunk[-1].bias.add_(0.5)
        agent.critic.encoder.trunks[0][0].weight.mul_(1.5)
    after = agent.act(obs, deterministic=True)
    agent.fast_act = None
    np.testing.assert_array_equal(after, agent.act(obs, deterministic=True))
    assert not np.array_equal(before, after)


def test_batches_samples_and_other_variants_act_through_the_modules():
    assert perturbed_agent(actor_components=2).fast_act is None  # a mixture actor
    privileged = ResidualAgent(config(obs_source="obstacles"), base_agent())
    assert privileged.fast_act is None
    agent = perturbed_agent()
    calls = []
    fast = agent.fast_act
    agent.fast_act = lambda obs: calls.append(obs) or fast(obs)
    observations = batch(size=3, seed=5)["obs"]
    agent.act(observations, deterministic=True)  # a batch
    agent.act({key: value[0] for key, value in observations.items()})  # a sample
    assert not calls
    agent.act({key: value[0] for key, value in observations.items()}, deterministic=True)
    assert len(calls) == 1
