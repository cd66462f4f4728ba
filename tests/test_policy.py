"""The shared policy interface and its test-time wrappers."""

import numpy as np
import pytest

from clamgen.policy import Policy, ScaledPolicy


class Recording:
    """A policy that returns a fixed action and records its resets."""

    def __init__(self, action):
        self.action = np.asarray(action, np.float32)
        self.resets = []
        self.agent = "its agent"

    def act(self, obs):
        return self.action

    def reset(self, env=None):
        self.resets.append(env)


def test_scaled_policy_shortens_each_step_in_the_same_direction():
    inner = Recording([1.0, -1.0, 0.5, 0.0, -0.25, 0.8])
    policy = ScaledPolicy(inner, 0.6)
    assert isinstance(policy, Policy)
    action = policy.act({})
    assert action.dtype == np.float32
    np.testing.assert_allclose(action, 0.6 * inner.action, rtol=1e-6)
    assert np.all(np.abs(action) <= 0.6 + 1e-6)
    policy.reset("env")
    assert inner.resets == ["env"]
    assert policy.agent == "its agent"  # what the tables read for the observation column
    np.testing.assert_array_equal(ScaledPolicy(inner, 1.0).act({}), inner.action)


def test_scaled_policy_tells_the_wrapped_policy_the_steps_it_did_not_see():
    inner = Recording([1.0] * 6)
    inner.skipped = lambda steps: inner.resets.append(("skipped", steps))
    ScaledPolicy(inner, 0.5).skipped(3)
    assert inner.resets == [("skipped", 3)]
    ScaledPolicy(Recording([1.0] * 6), 0.5).skipped(3)  # a policy that does not listen


@pytest.mark.parametrize("scale", [0.0, -0.5, 1.01, float("nan"), float("inf")])
def test_scaled_policy_refuses_a_scale_outside_0_1(scale):
    with pytest.raises(ValueError, match=r"action scale must be in \(0, 1\]"):
        ScaledPolicy(Recording(np.zeros(6)), scale)
