"""`GuardedEnv`: a depth guard inside `env.step` acts as the same guard around a policy."""

from dataclasses import replace

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from clamgen.baselines import IKInterpolationPolicy
from clamgen.envs import ReachEnv
from clamgen.experiments.config import TEST_SEEDS
from clamgen.experiments.depth_planner import ESCAPES, HYBRID, DepthGuard
from clamgen.experiments.evaluate import run_episode
from clamgen.experiments.guarded_env import GuardedEnv

VIEWS = 2
SEEDS = [int(s) for s in TEST_SEEDS.seeds(2)]


def _env(guard: DepthGuard, family: str = "blocked") -> ReachEnv:
    return ReachEnv(
        num_obstacles=2,
        task_family=family,
        obs_mode="both",
        num_views=VIEWS,
        image_size=64,
        **guard.env_kwargs(),
    )


def _drive(env: GuardedEnv, policy, seed: int) -> tuple[int, bool, bool, list[bool]]:
    """`policy` acting through `env.step`: steps, reached, collided, and per step whether
    its action was applied as given."""
    obs, _ = env.reset(seed=seed)
    policy.reset(env)
    reached = collided = done = False
    followed = []
    while not done:
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        reached |= info["is_success"]
        collided |= info["collision"]
        followed.append(info["agent_action_followed"])
        done = terminated or truncated
    return len(followed), reached, collided, followed


@pytest.mark.parametrize(
    "guard",
    [DepthGuard(), ESCAPES[VIEWS], replace(HYBRID[VIEWS], plan_checks=3000)],
    ids=["shield", "escapes", "hybrid"],
)
def test_acting_through_the_guarded_env_gives_the_wrapped_policys_episodes(guard):
    env = _env(guard)
    wrapped = guard.wrap(IKInterpolationPolicy(), VIEWS, 64)
    expected = [run_episode(env, wrapped, seed) for seed in SEEDS]
    guarded = guard.wrap_env(_env(guard))
    assert isinstance(guarded, GuardedEnv)
    for seed, record in zip(SEEDS, expected, strict=True):
        steps, reached, collided, followed = _drive(guarded, IKInterpolationPolicy(), seed)
        assert (steps, reached, collided) == (record.steps, record.reached, record.collided)
        # Blind IK interpolation runs into the obstacle on the blocked tasks: the guard
        # replaces some of its actions, and no step collides.
        assert not all(followed) and not collided
    if guard.planner:
        assert guarded.policy.num_plans == wrapped.num_plans > 0
    # The finer depth camera is the guard's: the agent observes the env's other entries.
    hidden = {"fine_depth"} if guard.fine_depth_size else set()
    assert set(guarded.observation_space.spaces) == set(env.observation_space.spaces) - hidden
    env.close()
    guarded.close()


@pytest.mark.filterwarnings("ignore:.*different from the unwrapped version")
def test_the_guarded_env_passes_gymnasiums_checks_and_says_what_it_applied():
    guard = DepthGuard()
    env = guard.wrap_env(_env(guard, "obstacles"))
    check_env(env, skip_render_check=True)
    env.reset(seed=SEEDS[0])
    action = np.zeros(6, np.float32)
    _, _, _, _, info = env.step(action)
    assert info["agent_action_followed"] and np.array_equal(info["applied_action"], action)
    with pytest.raises(ValueError, match="action must have shape"):
        env.step(np.zeros(5))
    env.close()


def test_the_guarded_env_refuses_an_env_it_cannot_read():
    blind = ReachEnv(num_obstacles=2, obs_mode="joints")
    with pytest.raises(ValueError, match="reads the env's joints and RGBD views"):
        GuardedEnv(blind, DepthGuard())
    coarse = _env(DepthGuard())  # no 128-pixel depth camera for the hybrid's shield
    with pytest.raises(ValueError, match="fine depth camera"):
        GuardedEnv(coarse, HYBRID[VIEWS])
    with pytest.raises(RuntimeError, match="reset"):
        GuardedEnv(coarse, DepthGuard()).step(np.zeros(6, np.float32))
    blind.close()
    coarse.close()
