"""The multiple-choice actor of distilled students keeps a bimodal teacher's modes apart."""

import pytest
import torch

from clamgen.agents.networks import Actor, MixtureActor

BOUNDS = (-5.0, 2.0)


def fit(actor, features, targets, steps=400):
    optimizer = torch.optim.Adam(actor.parameters(), lr=1e-2)
    for _ in range(steps):
        if isinstance(actor, MixtureActor):
            loss = actor.imitation_loss(features, targets)
        else:
            loss = torch.mean((actor(features)[0] - targets) ** 2)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()


@pytest.mark.parametrize("seed", range(4))
def test_it_acts_with_one_mode_where_a_single_mean_averages_them(seed):
    torch.manual_seed(seed)
    # The same state labelled "pass left" (-1) and "pass right" (+1), half each.
    features = torch.ones(256, 3)
    side = torch.where(torch.arange(256) % 2 == 0, -1.0, 1.0)
    targets = torch.stack([side, torch.full_like(side, 0.5)], dim=-1)
    gaussian = Actor(3, 2, (16,), BOUNDS)
    mixture = MixtureActor(3, 2, (16,), BOUNDS, components=3)
    fit(gaussian, features, targets)
    fit(mixture, features, targets)
    assert abs(float(gaussian(features[:1])[0][0, 0])) < 0.1  # the average: into the obstacle
    mean, _ = mixture(features[:1])
    assert abs(float(mean[0, 0])) == pytest.approx(1.0, abs=0.1)  # one of the two sides
    assert float(mean[0, 1]) == pytest.approx(0.5, abs=0.1)
    # It acts like an Actor: tanh of that mean, and samples with a finite log-probability.
    assert torch.allclose(mixture.mode(features[:1]), torch.tanh(mean))
    action, log_prob = mixture.sample(features[:4])
    assert action.shape == (4, 2) and torch.isfinite(log_prob).all()


def test_the_loss_is_the_nearest_candidates_worked_out_by_hand():
    mixture = MixtureActor(1, 1, (), BOUNDS, components=2, others_weight=0.1)
    with torch.no_grad():  # candidates 0 and 2, choice logits 0 and log 3
        layer = mixture.trunk[-1]
        layer.weight.zero_()
        layer.bias.copy_(torch.tensor([0.0, 2.0, 0.0, 0.0, 0.0, torch.log(torch.tensor(3.0))]))
    # Target 1.5: candidate 2 is nearest (error 0.25, the other's 2.25); the head gives it 3/4.
    loss = mixture.imitation_loss(torch.zeros(1, 1), torch.tensor([[1.5]]))
    expected = 0.9 * 0.25 + 0.1 * 2.25 - torch.log(torch.tensor(0.75))
    assert float(loss) == pytest.approx(float(expected), rel=1e-5)
    assert float(mixture(torch.zeros(1, 1))[0]) == pytest.approx(2.0)  # the chosen candidate
