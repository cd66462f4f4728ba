"""The stage-2 agent as a composition: one container of networks, auxiliary losses as modules,
one device, the speed switches, and the shipped policies unchanged by the rebuild."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from clamgen.agents import encoders
from clamgen.agents.aux_losses import (
    AUX_LOSSES,
    AuxLoss,
    AuxLossConfig,
    register_aux_loss,
)
from clamgen.agents.residual import ResidualAgent
from tests.agents.test_residual import base_agent, batch, config

torch.set_num_threads(1)
DATA = Path(__file__).resolve().parent.parent / "data" / "shipped_policy_actions.npz"


@pytest.fixture
def probe_loss():
    """A loss defined here alone: predict the action's sign from the latent."""

    @register_aux_loss
    class ActionSignLoss(AuxLoss):
        name = "action_sign"

        def __init__(self, dims, config):
            super().__init__(dims, config)
            self.head = torch.nn.Linear(dims.latent_dim, dims.action_dim)

        def forward(self, inputs):
            logits = self.head(inputs.latent)
            target = (inputs.action > 0).float()
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, target)
            return loss, {
                "train/action_sign_accuracy": ((logits > 0) == (target > 0)).float().mean().item()
            }

    yield ActionSignLoss
    del AUX_LOSSES["action_sign"]


def test_an_aux_loss_defined_in_a_test_file_trains_through_the_agent(probe_loss, tmp_path):
    aux = AuxLossConfig(collision_hidden_sizes=(16,), extra_weights={"action_sign": 1.0})
    agent = ResidualAgent(config(aux=aux), base_agent())
    head = agent.aux_losses["action_sign"].head
    before = head.weight.detach().clone()
    data = batch()
    losses = [agent.update(data)["train/action_sign_loss"] for _ in range(30)]
    assert not torch.equal(before, head.weight)  # its parameters are in the critic optimiser
    assert losses[-1] < losses[0]  # and it learns
    # It follows the agent's state dict with nothing else to edit.
    state = agent.state_dict()
    assert "aux/action_sign" in state
    other = ResidualAgent(config(aux=aux), base_agent())
    other.load_state_dict(state)
    torch.testing.assert_close(other.aux_losses["action_sign"].head.weight, head.weight)
    # Weight 0 keeps it out of the sum; an unknown name is refused.
    off = ResidualAgent(
        config(aux=dataclasses.replace(aux, extra_weights={"action_sign": 0.0})), base_agent()
    )
    assert "train/action_sign_loss" not in off.update(data)
    with pytest.raises(ValueError, match="unknown auxiliary losses"):
        ResidualAgent(config(aux=AuxLossConfig(extra_weights={"nosuch": 1.0})), base_agent())


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"residual": False}, {"obs_source": "obstacles"}, {"finetune_base": True}],
)
def test_every_parameter_and_buffer_lives_on_the_configured_device(kwargs):
    # "meta" stands in for an accelerator: a tensor left on the CPU is told apart.
    agent = ResidualAgent(config(**kwargs), base_agent())
    assert {t.device.type for t in agent.nets.parameters()} == {"cpu"}
    agent.nets.to("meta")
    devices = {t.device.type for t in (*agent.nets.parameters(), *agent.nets.buffers())}
    assert devices == {"meta"}
    # The frozen base and its normaliser are inside the container, so they moved too.
    assert agent.base.normalizer.std.device.type == "meta"
    assert next(agent.base.critic.parameters()).device.type == "meta"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_an_agent_on_cuda_updates_and_acts():
    agent = ResidualAgent(config(device="cuda"), base_agent())
    devices = {t.device.type for t in (*agent.nets.parameters(), *agent.nets.buffers())}
    assert devices == {"cuda"}
    assert np.isfinite(agent.update(batch())["train/critic_loss"])
    assert agent.act(batch()["obs"], True).shape == (8, 6)


def test_policy_keys_follow_the_container():
    agent = ResidualAgent(config(aux=AuxLossConfig(state_weight=1.0)), base_agent())
    keys = agent.policy_state_keys()
    assert {"critic", "actor", "base_actor", "base_critic", "normalizer", "aux/state"} <= set(keys)
    assert not {"critic_target", "key_encoder", "aux/curl", "critic_optim"} & set(keys)
    # A policy file's subset loads; the training-only parts keep their fresh values.
    state = agent.state_dict()
    other = ResidualAgent(config(aux=AuxLossConfig(state_weight=1.0)), base_agent())
    other.load_state_dict({k: state[k] for k in keys}, policy_only=True)
    data = batch(seed=3)["obs"]
    np.testing.assert_array_equal(agent.act(data, True), other.act(data, True))
    np.testing.assert_array_equal(agent.predict_state(data), other.predict_state(data))
    with pytest.raises(KeyError, match="critic_target"):
        other.load_state_dict({k: state[k] for k in keys})


def test_legacy_state_dict_keys_still_load():
    agent = ResidualAgent(config(), base_agent())
    state = agent.state_dict()
    legacy = dict(state)
    legacy["collision_head"] = {
        k.removeprefix("head."): v for k, v in legacy.pop("aux/collision").items()
    }
    legacy["state_head"] = {k.removeprefix("head."): v for k, v in legacy.pop("aux/state").items()}
    legacy["curl"] = {
        "W": legacy.pop("aux/curl")["W"],
        "W_view": legacy.pop("aux/across_view")["W"],
    }
    other = ResidualAgent(config(seed=5), base_agent())
    other.load_state_dict(legacy)
    for key in ("aux/collision", "aux/state", "aux/curl", "aux/across_view"):
        for name, value in state[key].items():
            torch.testing.assert_close(other.state_dict()[key][name], value)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"target_encoder": "online"},
        {"encoder_bf16": True},
        {"target_encoder": "online", "encoder_bf16": True},
    ],
)
def test_speed_switches_train_and_act(kwargs, monkeypatch):
    monkeypatch.setattr(encoders, "native_bf16", lambda device_type: True)
    bf16 = kwargs.pop("encoder_bf16", False)
    cfg = config(**kwargs)
    cfg = dataclasses.replace(cfg, encoder=dataclasses.replace(cfg.encoder, bf16_autocast=bf16))
    agent = ResidualAgent(cfg, base_agent())
    for seed in range(3):
        metrics = agent.update(batch(seed=seed))
    assert all(np.isfinite(v) for v in metrics.values())
    assert agent.act(batch()["obs"], True).dtype == np.float32


def test_online_target_skips_the_target_encoder():
    calls = []
    agent = ResidualAgent(config(target_encoder="online"), base_agent())
    agent.critic_target.encoder.register_forward_hook(lambda *a: calls.append(1))
    agent.update(batch())
    assert calls == []
    reference = ResidualAgent(config(), base_agent())
    reference.critic_target.encoder.register_forward_hook(lambda *a: calls.append(1))
    reference.update(batch())
    assert calls == [1]
    with pytest.raises(ValueError, match="target_encoder"):
        config(target_encoder="momentum")


def _encodings_fp32_and_bf16() -> tuple[torch.Tensor, torch.Tensor]:
    """The same weights' encodings of a batch's images, without and with bf16 autocast."""
    cfg = config()
    bf16_cfg = dataclasses.replace(
        cfg, encoder=dataclasses.replace(cfg.encoder, bf16_autocast=True)
    )
    fp32, bf16 = ResidualAgent(cfg, base_agent()), ResidualAgent(bf16_cfg, base_agent())
    bf16.load_state_dict(fp32.state_dict())
    images = torch.as_tensor(batch()["obs"]["images"][:, :, :, 4:-4, 4:-4])
    with torch.no_grad():
        return fp32.critic.encoder(images), bf16.critic.encoder(images)


def test_bf16_convs_stay_close_to_float32(monkeypatch):
    monkeypatch.setattr(encoders, "native_bf16", lambda device_type: True)
    a, b = _encodings_fp32_and_bf16()
    assert a.dtype == b.dtype == torch.float32
    assert not torch.equal(a, b)
    assert (a - b).abs().max() < 0.05  # tanh-bounded features, bf16's 8-bit mantissa


@pytest.mark.parametrize(
    ("name", "policy_file"),
    [
        # The RL-trained 2-view residual shipped before the distilled one replaced it.
        (
            "residual-2views",
            Path(__file__).resolve().parent.parent / "data" / "residual-2views-rl.pt",
        ),
        ("image-only", "image-only"),
    ],
)
def test_shipped_policies_act_as_before_the_rebuild(name, policy_file):
    """Actions recorded with the agent before it was rebuilt by composition, on fixed
    rendered observations."""
    from clamgen.experiments.policies import resolve_policy_path
    from clamgen.experiments.stage2 import load_residual_agent

    recorded = np.load(DATA)
    obs = {
        key.split("/")[-1]: recorded[key]
        for key in recorded.files
        if key.startswith(f"{name}/obs/")
    }
    agent, _ = load_residual_agent(resolve_policy_path(policy_file))
    np.testing.assert_allclose(
        agent.act(obs, deterministic=True), recorded[f"{name}/action"], atol=2e-5
    )


def test_behaviour_cloning_pulls_the_mean_action_towards_the_demonstrations():
    data = batch(obstacles=True)
    demo = np.zeros(8, np.float32)
    demo[:4] = 1.0  # half the batch are a teacher's transitions
    data["demonstration"] = demo
    cfg = config(obs_source="obstacles", warmup_updates=0)

    def distance(agent):
        action = agent.act(data["obs"], deterministic=True)
        return float(np.square(action - data["action"])[:4].sum(-1).mean())

    cloning = ResidualAgent(dataclasses.replace(cfg, bc_weight=100.0), base_agent())
    plain = ResidualAgent(cfg, base_agent())
    start = distance(cloning)
    for _ in range(150):
        metrics = cloning.update(data)
        assert "train/bc_loss" not in plain.update(data)
    assert metrics["train/bc_fraction"] == 0.5
    assert distance(cloning) < 0.5 * start
    assert distance(cloning) < distance(plain)
    with pytest.raises(ValueError, match=r"agent\.bc_weight"):
        config(bc_weight=-1.0)


def test_bf16_autocast_runs_float32_where_bf16_is_emulated(monkeypatch):
    """On a CPU without bf16 in hardware the bf16 switch changes nothing: float32 exactly."""
    monkeypatch.setattr(encoders, "native_bf16", lambda device_type: False)
    a, b = _encodings_fp32_and_bf16()
    torch.testing.assert_close(b, a, rtol=0, atol=0)


def test_emulated_bf16_can_be_forced(monkeypatch):
    monkeypatch.setattr(encoders, "native_bf16", lambda device_type: False)
    monkeypatch.setenv(encoders.EMULATED_BF16_ENV, "1")
    a, b = _encodings_fp32_and_bf16()
    assert not torch.equal(a, b)
    assert (a - b).abs().max() < 0.05


def test_native_bf16_only_where_the_hardware_has_it():
    assert encoders.native_bf16("meta") is False
    assert isinstance(encoders.native_bf16("cpu"), bool)
