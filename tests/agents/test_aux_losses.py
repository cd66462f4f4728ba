"""Auxiliary losses: CURL and across-view InfoNCE prefer their positives, gradients reach every
parameter, the collision head fits a separable problem, and the momentum update is an EMA."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from clamgen.agents.augment import random_crop
from clamgen.agents.aux_losses import (
    AuxLossConfig,
    CollisionHead,
    CURLHead,
    across_view_loss,
    bilinear_logits,
    collision_loss,
    curl_loss,
    make_momentum_copy,
    momentum_update,
)
from clamgen.agents.encoders import EncoderConfig, LowDimEncoder, MultiViewEncoder, fuse

torch.set_num_threads(1)

DIM = 16


def distinct_embeddings(batch: int, seed: int = 0) -> torch.Tensor:
    """(B, DIM) unit vectors, well separated for B <= DIM."""
    generator = torch.Generator().manual_seed(seed)
    return F.normalize(torch.randn(batch, DIM, generator=generator), dim=-1) * 3.0


# --- CURL ---------------------------------------------------------------------------------------


def test_curl_loss_prefers_the_positive() -> None:
    queries = distinct_embeddings(8)
    keys = queries + 0.05 * torch.randn(8, DIM, generator=torch.Generator().manual_seed(1))
    weight = torch.eye(DIM)
    matching = curl_loss(queries, keys, weight)
    shuffled = curl_loss(queries, keys[torch.roll(torch.arange(8), 1)], weight)
    assert matching < 0.2 * math.log(8) and shuffled > 5 * matching
    logits = bilinear_logits(queries, keys, weight)
    assert logits.shape == (8, 8)
    assert torch.equal(logits.argmax(1), torch.arange(8))
    assert torch.allclose(logits.amax(1), torch.zeros(8))  # max-subtracted


def test_curl_loss_is_log_batch_for_identical_embeddings() -> None:
    same = torch.ones(6, DIM)
    torch.testing.assert_close(curl_loss(same, same, torch.eye(DIM)), torch.tensor(math.log(6)))


def test_across_view_loss_prefers_shared_scene_embeddings() -> None:
    scenes = distinct_embeddings(8)
    generator = torch.Generator().manual_seed(2)
    noise = 0.05 * torch.randn(8, 3, DIM, generator=generator)
    shared = scenes[:, None, :].expand(8, 3, DIM) + noise
    unrelated = torch.stack([distinct_embeddings(8, seed) for seed in (3, 4, 5)], dim=1)
    weight = torch.eye(DIM)
    assert across_view_loss(shared, shared, weight) < 0.2 * across_view_loss(
        unrelated, unrelated, weight
    )


def test_across_view_loss_is_pairwise_curl_over_views() -> None:
    generator = torch.Generator().manual_seed(0)
    queries, keys = torch.randn(2, 5, 2, DIM, generator=generator)
    weight = torch.randn(DIM, DIM, generator=generator)
    expected = 0.5 * (
        curl_loss(queries[:, 0], keys[:, 1], weight) + curl_loss(queries[:, 1], keys[:, 0], weight)
    )
    torch.testing.assert_close(across_view_loss(queries, keys, weight), expected)
    single = torch.randn(5, 1, DIM, requires_grad=True)
    loss = across_view_loss(single, single, weight)
    assert loss.item() == 0.0 and loss.requires_grad


def test_curl_head_without_across_view_has_no_second_form() -> None:
    head = CURLHead(DIM, across_view=False)
    assert [name for name, _ in head.named_parameters()] == ["W"]
    with pytest.raises(RuntimeError):
        head.across_view_loss(torch.zeros(2, 2, DIM), torch.zeros(2, 2, DIM))


def test_gradients_of_every_loss_reach_every_parameter() -> None:
    """One stage-2 auxiliary step: two crops, online + momentum encoders, all three losses."""
    config = EncoderConfig(
        image_size=16, num_views=3, num_channels=8, hidden_dim=32, feature_dim=DIM
    )
    torch.manual_seed(0)
    encoder = MultiViewEncoder(config)
    key_encoder = make_momentum_copy(encoder)
    low_dim_encoder = LowDimEncoder(9, 8)
    head = CURLHead(DIM)
    collision_head = CollisionHead(DIM + 8, 6, (32,))
    generator = torch.Generator().manual_seed(0)
    stored = torch.randint(0, 256, (6, 3, 4, 20, 20), dtype=torch.uint8, generator=generator)
    query_images = random_crop(stored, 16, generator)
    key_images = random_crop(stored, 16, generator)
    action = torch.rand(6, 6, generator=generator) * 2 - 1
    collided = torch.tensor([1, 0, 0, 1, 0, 0], dtype=torch.bool)

    def losses() -> dict[str, tuple[torch.Tensor, list[torch.nn.Module]]]:
        view_features = encoder.conv_trunk(query_images)
        query = encoder.merge(view_features)
        with torch.no_grad():
            key_features = key_encoder.conv_trunk(key_images)
            key = key_encoder.merge(key_features)
            key_views = key_encoder.single_view_encodings(key_features)
        latent = fuse(query, low_dim_encoder(torch.randn(6, 9, generator=generator)))
        logits = collision_head(latent, action)
        assert logits.shape == (6,)
        return {
            "curl": (head.instance_loss(query, key), [encoder]),
            "across_view": (
                head.across_view_loss(encoder.single_view_encodings(view_features), key_views),
                [encoder],
            ),
            "collision": (
                collision_loss(logits, collided, pos_weight=2.0),
                [encoder, low_dim_encoder, collision_head],
            ),
        }

    for name, (loss, modules) in losses().items():
        for module in [encoder, low_dim_encoder, head, collision_head]:
            module.zero_grad(set_to_none=True)
        assert loss.shape == () and torch.isfinite(loss)
        loss.backward(retain_graph=True)  # the three losses share the encoder's graph
        own = {"curl": [head.W], "across_view": [head.W_view], "collision": []}[name]
        params = [p for m in modules for p in m.parameters()] + own
        for param in params:
            assert param.grad is not None and param.grad.abs().sum() > 0, name
        assert all(p.grad is None for p in key_encoder.parameters())


def same_parameters(first: torch.nn.Module, second: torch.nn.Module) -> bool:
    pairs = zip(first.parameters(), second.parameters(), strict=True)
    return all(torch.equal(a, b) for a, b in pairs)


# --- momentum encoder ---------------------------------------------------------------------------


def test_momentum_update_moves_the_target_by_tau() -> None:
    torch.manual_seed(0)
    online = MultiViewEncoder(EncoderConfig(image_size=16, num_channels=4, hidden_dim=8))
    target = make_momentum_copy(online)
    assert all(not p.requires_grad for p in target.parameters())
    assert same_parameters(target, online)
    with torch.no_grad():
        for param in online.parameters():
            param.add_(torch.randn_like(param))
    before = [p.clone() for p in target.parameters()]
    tau = AuxLossConfig().encoder_momentum_tau
    momentum_update(target, online, tau)
    pairs = zip(target.parameters(), online.parameters(), strict=True)
    for old, (new, source) in zip(before, pairs, strict=True):
        torch.testing.assert_close(new, old + tau * (source - old))
    momentum_update(target, online, 1.0)
    assert same_parameters(target, online)
    with pytest.raises(ValueError):
        momentum_update(target, online, 1.5)


# --- collision ----------------------------------------------------------------------------------


def test_collision_loss_matches_weighted_bce() -> None:
    logits = torch.tensor([2.0, -1.0, 0.5])
    collided = torch.tensor([True, False, False])
    log_p, log_not_p = F.logsigmoid(logits), F.logsigmoid(-logits)
    expected = -(3.0 * log_p[0] + log_not_p[1] + log_not_p[2]) / 3
    torch.testing.assert_close(collision_loss(logits, collided, pos_weight=3.0), expected)
    torch.testing.assert_close(
        collision_loss(logits, collided.float()),
        F.binary_cross_entropy_with_logits(logits, collided.float()),
    )


def test_collision_head_fits_a_separable_problem() -> None:
    torch.manual_seed(0)
    latent = torch.randn(256, 10)
    action = torch.rand(256, 6) * 2 - 1
    # Collides when the latent "obstacle side" and the action's first joint push the same way.
    collided = latent[:, 0] + action[:, 0] > 0.3
    head = CollisionHead(10, 6, (32,))
    optimiser = torch.optim.Adam(head.parameters(), lr=1e-2)
    positive_share = collided.float().mean().item()
    for _ in range(300):
        loss = collision_loss(head(latent, action), collided, (1 - positive_share) / positive_share)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    accuracy = ((head(latent, action) > 0) == collided).float().mean()
    assert accuracy > 0.97 and loss < 0.15
