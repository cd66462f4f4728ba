import json
import time

import numpy as np
import pytest

from clamgen.envs import ReachEnv
from clamgen.experiments.evaluate import EpisodeRecord, SACPolicy, per_task, run_episode


def test_per_task_keeps_each_episode_in_order_and_the_median_act():
    records = [
        EpisodeRecord(
            seed=3,
            reached=True,
            collided=False,
            steps=20,
            tip_path_m=0.3,
            act_times_s=[0.001, 0.003],
        ),
        EpisodeRecord(
            seed=4, reached=True, collided=True, steps=31, tip_path_m=0.5, act_times_s=[0.002]
        ),
        EpisodeRecord(
            seed=5, reached=False, collided=False, steps=80, tip_path_m=0.1, act_times_s=[0.004]
        ),
    ]
    out = per_task(records)
    # A reach after a collision is no success (the spec's criterion).
    assert out["success"] == [True, False, False]
    assert out["collided"] == [False, True, False]
    assert out["steps"] == [20, 31, 80]
    assert out["act_median_ms"] == pytest.approx(2.5)
    json.dumps(out)  # plain Python types, for the result files


class CountingAgent:
    """Records the observations it acts on; always commands the first joint a little."""

    def __init__(self) -> None:
        self.seen: list[dict] = []

    def act(self, obs, deterministic=False):
        self.seen.append(obs)
        return np.array([0.1, 0, 0, 0, 0, 0], np.float32)


def test_a_policy_warms_up_once_on_a_blank_observation_before_its_first_episode():
    agent = CountingAgent()
    policy = SACPolicy(agent)
    env = ReachEnv(
        num_obstacles=2, task_family="obstacles", num_views=1, image_size=16, obs_mode="both"
    )
    first = run_episode(env, policy, seed=1_000_000_000)
    # One extra act, untimed, on zeros shaped like the env's observations, before the first.
    assert len(agent.seen) == first.steps + 1 == len(first.act_times_s) + 1
    blank = agent.seen[0]
    assert set(blank) == set(env.observation_space.spaces)
    assert blank["images"].shape == (1, 4, 16, 16) and blank["images"].dtype == np.uint8
    assert all(not value.any() for value in blank.values())
    second = run_episode(env, policy, seed=1_000_000_001)
    assert len(agent.seen) == first.steps + 1 + second.steps  # not again
    env.close()


class _NotCLAMGen:
    unwrapped = object()


class _SlowFirstAct:
    """Holds still; its first act of an episode takes `first_s` (a plan), and it counts the
    steps it is told it did not see."""

    def __init__(self, first_s: float) -> None:
        self.first_s = first_s
        self.skipped_steps: list[int] = []

    def reset(self, env=None) -> None:
        self._first = True

    def act(self, obs):
        if self._first:
            time.sleep(self.first_s)
            self._first = False
        return np.zeros(6, np.float32)

    def skipped(self, steps: int) -> None:
        self.skipped_steps.append(steps)


def test_real_time_holds_the_arm_still_for_each_control_period_an_act_took():
    from clamgen.envs.reach_env import CONTROL_DT_S

    env = ReachEnv(num_obstacles=0, target_speed=0.2, max_episode_steps=20)
    slow = _SlowFirstAct(2.2 * CONTROL_DT_S)
    record = run_episode(env, slow, 7, real_time=True)
    late = int(record.act_times_s[0] // CONTROL_DT_S)
    assert late >= 2 and record.held_steps == late and slow.skipped_steps == [late]
    assert record.steps == 20 and len(record.act_times_s) == 20 - late  # the limit counts them
    # By default acting takes no simulated time (the paper's setting).
    record = run_episode(env, slow, 7)
    assert record.held_steps == 0 and len(record.act_times_s) == record.steps == 20
    with pytest.raises(ValueError, match="real_time needs a CLAMGen env"):
        run_episode(_NotCLAMGen(), slow, 7, real_time=True)
