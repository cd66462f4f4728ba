"""The lookahead teacher: rollouts of itself in a copy of the simulator before each step."""

import numpy as np
import pytest

from clamgen.baselines.ik_interpolation import IKInterpolationPolicy
from clamgen.envs.reach_env import ReachEnv
from clamgen.experiments.evaluate import evaluate, run_episode
from clamgen.experiments.lookahead import PRE_SQUASH_CLIP, LookaheadPolicy, LookaheadTeacher


class BlindAgent:
    """IK interpolation (obstacle-blind) posing as a residual: its pre-squash mean."""

    def __init__(self) -> None:
        self.ik = IKInterpolationPolicy()
        self.calls = 0

    def mean_action(self, batch):
        self.calls += 1
        actions = [
            self.ik.act({k: v[i] for k, v in batch.items()})
            for i in range(len(batch["desired_goal"]))
        ]
        return np.arctanh(np.clip(np.stack(actions), -0.995, 0.995))


def blocked_env() -> ReachEnv:
    return ReachEnv(num_obstacles=2, task_family="blocked", include_obstacle_state=True)


def record_searches(teacher: LookaheadTeacher) -> list:
    """The (plans, outcomes) of each of `teacher`'s searches from now on (rollouts of more
    than one plan), in order."""
    searches = []
    rollout = teacher.rollout

    def recording(state, plans, margin_m=0.0):
        outcomes = rollout(state, plans, margin_m)
        if len(plans) > 1:
            searches.append((plans.copy(), outcomes))
        return outcomes

    teacher.rollout = recording
    return searches


def test_a_rollout_without_offsets_is_the_episode_the_agent_would_run():
    agent = BlindAgent()
    teacher = LookaheadTeacher(agent, num_obstacles=2, horizon=100)
    for family, seed in (("blocked", 3), ("obstacles", 4)):
        env = ReachEnv(num_obstacles=2, task_family=family, include_obstacle_state=True)
        obs, _ = env.reset(seed=seed)
        state = env.get_state()
        (outcome,) = teacher.rollout(state, teacher.new_plan()[None])
        # The same agent, acting in the env itself, until it arrives or collides.
        steps, collided, info = 0, False, {}
        while True:
            action = np.tanh(
                np.clip(agent.mean_action({k: v[None] for k, v in obs.items()})[0], -3, 3)
            )
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            collided = info["collision"]
            if collided or terminated or truncated:
                break
        assert outcome.collided == collided
        assert outcome.arrived_after == (steps if info["is_success"] and not collided else None)
        assert outcome.final_distance_m == pytest.approx(info["distance_m"])
        # Planning leaves the env's own episode untouched.
        env.set_state(state)
        assert np.array_equal(env.observe()["observation"], state.sim.joints.astype(np.float32))


def test_lookahead_turns_the_blind_agents_collisions_into_clean_arrivals():
    env = blocked_env()
    seeds = [0, 1, 2]
    blind = evaluate(env, IKInterpolationPolicy(), seeds)
    assert all(r.collided for r in blind)
    teacher = LookaheadTeacher(BlindAgent(), num_obstacles=2, candidates=16, seed=0)
    planned = evaluate(env, LookaheadPolicy(teacher), seeds)
    assert all(r.success for r in planned)
    assert teacher.searches > 0


def test_plans_keep_the_clearance_where_they_can():
    seeds = [0, 1, 2]
    margin = 0.02
    # Scored by an env that counts approaches within the margin as collisions.
    strict = ReachEnv(
        num_obstacles=2,
        task_family="blocked",
        include_obstacle_state=True,
        collision_margin_m=margin,
    )
    plain = LookaheadTeacher(BlindAgent(), num_obstacles=2, candidates=16, seed=0)
    clear = LookaheadTeacher(BlindAgent(), num_obstacles=2, candidates=16, seed=0, margin_m=margin)
    scores = {
        name: evaluate(strict, LookaheadPolicy(teacher), seeds)
        for name, teacher in (("plain", plain), ("clear", clear))
    }
    assert all(r.success and not r.collided for r in scores["clear"])
    assert any(r.collided for r in scores["plain"])  # the blind agent's plans graze obstacles


def test_without_any_plan_that_keeps_the_clearance_it_plans_against_true_contact():
    # Nothing stays half a metre from the table: every rollout with that margin collides.
    env = blocked_env()
    teacher = LookaheadTeacher(BlindAgent(), num_obstacles=2, candidates=16, margin_m=0.5)
    records = evaluate(env, LookaheadPolicy(teacher), [0, 1])
    assert all(r.success and not r.collided for r in records)


def test_a_plan_seen_to_arrive_is_not_rolled_out_again_while_the_teacher_follows_it():
    env = ReachEnv(num_obstacles=2, task_family="obstacles", include_obstacle_state=True)
    teacher = LookaheadTeacher(BlindAgent(), num_obstacles=2)
    record = run_episode(env, LookaheadPolicy(teacher), seed=4)
    assert record.success and record.steps > 1
    assert (teacher.rollouts, teacher.searches) == (1, 0)


def test_labels_are_clipped_pre_squash_actions_and_plans_shift():
    env = blocked_env()
    obs, _ = env.reset(seed=0)
    teacher = LookaheadTeacher(BlindAgent(), num_obstacles=2, candidates=4, horizon=10, seed=1)
    label, plan, _ = teacher.act(env.get_state(), obs, teacher.new_plan(), known_clean=False)
    assert label.shape == (6,) and np.abs(label).max() <= PRE_SQUASH_CLIP
    assert plan.shape == (10, 6) and not plan[-1].any()


@pytest.mark.parametrize("fixed", [True, False])
def test_fixed_offsets_search_the_same_library_at_every_state(fixed):
    env = blocked_env()
    obs, _ = env.reset(seed=0)
    teacher = LookaheadTeacher(
        BlindAgent(), num_obstacles=2, candidates=4, horizon=10, seed=1, fixed_offsets=fixed
    )
    searches = record_searches(teacher)
    zero = teacher.new_plan()
    for _ in range(2):  # the same state, searched twice from the same (empty) plan
        teacher.act(env.get_state(), obs, zero, known_clean=False)
    assert len(searches) == 2
    (first, _), (second, _) = searches  # (the perturbed plans follow the zero plan)
    assert np.array_equal(first[1:], second[1:]) == fixed


def test_a_search_keeps_the_clean_plan_nearest_to_the_preferred_action():
    env = blocked_env()
    obs, _ = env.reset(seed=0)
    teacher = LookaheadTeacher(BlindAgent(), num_obstacles=2, candidates=16, horizon=40, seed=2)
    searches = record_searches(teacher)
    mean = BlindAgent().mean_action({k: v[None] for k, v in obs.items()})[0]
    for prefer in (np.full(6, 2.0), np.full(6, -2.0)):
        label, _, clean = teacher.act(env.get_state(), obs, teacher.new_plan(), False, prefer)
        plans, outcomes = searches[-1]
        firsts = [mean + plans[i, 0] for i, o in enumerate(outcomes) if o.clean]
        assert clean and len(firsts) > 1
        nearest = min(firsts, key=lambda a: np.linalg.norm(a - prefer))
        np.testing.assert_allclose(label, np.clip(nearest, -PRE_SQUASH_CLIP, PRE_SQUASH_CLIP))


def test_least_offset_keeps_the_clean_plan_that_deviates_least():
    env = blocked_env()
    obs, _ = env.reset(seed=0)
    searches = {}
    labels = {}
    for least in (False, True):
        teacher = LookaheadTeacher(
            BlindAgent(), num_obstacles=2, candidates=16, horizon=40, seed=2, least_offset=least
        )
        recorded = record_searches(teacher)
        labels[least], _, clean = teacher.act(env.get_state(), obs, teacher.new_plan(), False)
        assert clean and len(recorded) == 1
        searches[least] = recorded[0]
    plans, outcomes = searches[True]
    clean = [i for i, o in enumerate(outcomes) if o.clean]
    assert len(clean) > 1 and not outcomes[0].clean  # the blind agent alone collides
    least = min(clean, key=lambda i: np.linalg.norm(plans[i]))
    earliest = min(clean, key=lambda i: outcomes[i].arrived_after)
    assert least != earliest  # (this search tells the two rules apart)
    mean = BlindAgent().mean_action({k: v[None] for k, v in obs.items()})[0]
    expected = np.clip(mean + plans[least, 0], -PRE_SQUASH_CLIP, PRE_SQUASH_CLIP)
    np.testing.assert_allclose(labels[True], expected, rtol=1e-6)
    # The same search (same seed, same state) under the default rule keeps the earliest.
    np.testing.assert_array_equal(searches[False][0], plans)
    default = np.clip(mean + plans[earliest, 0], -PRE_SQUASH_CLIP, PRE_SQUASH_CLIP)
    np.testing.assert_allclose(labels[False], default, rtol=1e-6)


@pytest.mark.parametrize(
    "kwargs",
    [{"candidates": 0}, {"horizon": 0}, {"segments": 0}, {"noise": -1.0}, {"margin_m": -0.01}],
)
def test_bad_lookahead_settings_are_refused(kwargs):
    with pytest.raises(ValueError, match="lookahead"):
        LookaheadTeacher(BlindAgent(), num_obstacles=2, **kwargs)
