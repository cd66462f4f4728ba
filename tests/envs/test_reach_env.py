"""Environment contract: Gymnasium checker, rewards, collisions, determinism, bad input."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import clamgen  # noqa: F401  (registers the ids)
from clamgen.envs import ENV_IDS, MAX_JOINT_DELTA_RAD, EnvState, ReachEnv
from clamgen.sim.state import SimState
from clamgen.tasks import reach

SMALL = 32  # image side for fast tests


def make(env_id, **kwargs):
    return gym.make(env_id, **kwargs).unwrapped


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize(
    "kwargs",
    [
        {"obs_mode": "joints"},
        {"obs_mode": "images", "num_views": 2, "image_size": SMALL},
        {"obs_mode": "both", "num_views": 3, "image_size": SMALL, "include_obstacle_state": True},
        {"obs_mode": "joints", "previous_action": True},
    ],
    ids=["joints", "images", "both", "previous_action"],
)
def test_check_env(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    if kwargs["obs_mode"] == "images":
        assert "observation" not in obs
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_compute_reward_agrees_with_step_and_terms_add_up(env_id):
    env = make(env_id, collision_penalty=0.1)
    rng = np.random.default_rng(0)
    achieved, desired, infos, rewards = [], [], [], []
    for episode in range(4):
        obs, _ = env.reset(seed=episode)
        for _ in range(30):
            obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, 6))
            assert reward == pytest.approx(info["reward_step"] + info["reward_collision"])
            achieved.append(obs["achieved_goal"])
            desired.append(obs["desired_goal"])
            infos.append(info)
            rewards.append(reward)
            if terminated or truncated:
                break
    achieved, desired = np.array(achieved), np.array(desired)
    rewards = np.array(rewards, np.float32)
    np.testing.assert_allclose(env.compute_reward(achieved, desired, infos), rewards, atol=1e-6)
    as_dict = {"collision": np.array([i["collision"] for i in infos])}
    np.testing.assert_allclose(env.compute_reward(achieved, desired, as_dict), rewards, atol=1e-6)
    # Vectorised over any leading shape.
    batch = env.compute_reward(achieved[:6].reshape(2, 3, 3), desired[:6].reshape(2, 3, 3))
    assert batch.shape == (2, 3)


def test_success_terminates_with_zero_step_reward():
    env = make(ENV_IDS[0])
    obs, _ = env.reset(seed=0)
    goal = obs["desired_goal"].astype(np.float64)
    assert env.compute_reward(goal, goal, None) == 0.0
    from clamgen.baselines import IKInterpolationPolicy

    policy = IKInterpolationPolicy()
    for _ in range(100):
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        if terminated:
            break
    assert terminated and info["is_success"] and reward == 0.0 and not truncated
    assert np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"]) < 0.02


@pytest.mark.parametrize("through_make", [True, False])
def test_truncation_after_max_episode_steps(through_make):
    env = (
        gym.make(ENV_IDS[0], max_episode_steps=5) if through_make else ReachEnv(max_episode_steps=5)
    )
    env.reset(seed=1)
    outcomes = [env.step(np.zeros(6))[3] for _ in range(5)]
    assert outcomes == [False] * 4 + [True]
    assert gym.spec(ENV_IDS[0]).max_episode_steps == 100


def test_steps_never_end_inside_an_obstacle():
    from clamgen.baselines import IKInterpolationPolicy

    env = make(ENV_IDS[1])
    policy = IKInterpolationPolicy()
    rng = np.random.default_rng(2)
    collisions = 0
    for episode in range(6):
        obs, _ = env.reset(seed=100 + episode)
        # Head for the first obstacle's centre, with some noise, to provoke contacts.
        centre = env.task.obstacles.positions_m[0]
        for _ in range(40):
            aim = {"observation": obs["observation"], "desired_goal": centre}
            action = np.clip(policy.act(aim) + rng.normal(0, 0.3, 6), -1, 1)
            obs, _, terminated, truncated, info = env.step(action)
            assert not env.scene.in_collision()
            collisions += info["collision"]
            if info["collision"]:
                # The executed motion is shorter than the commanded one.
                assert np.abs(info["executed_action"]).max() < np.abs(action).max() + 1e-6
            if terminated or truncated:
                break
    assert collisions > 0  # the check above was exercised


def test_executed_action_is_clipped_by_joint_limits():
    env = make(ENV_IDS[0])
    env.reset(seed=0)
    state = env.get_state()
    joints = state.sim.joints.copy()
    joints[2] = np.pi - 0.01  # elbow limit is +-pi
    sim = SimState(joints, state.sim.target_position_m, state.sim.obstacles)
    env.set_state(EnvState(sim, state.target_velocity_mps, 0))
    _, _, _, _, info = env.step(np.array([0, 0, 1.0, 0, 0, 0]))
    assert info["executed_action"][2] == pytest.approx(0.01 / MAX_JOINT_DELTA_RAD, abs=1e-5)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_seeded_runs_are_reproducible(env_id):
    def rollout():
        env = make(env_id, num_views=1, obs_mode="both", image_size=SMALL, target_speed="variable")
        obs, _ = env.reset(seed=7)
        trace = [obs]
        rng = np.random.default_rng(0)
        for _ in range(15):
            trace.append(env.step(rng.uniform(-1, 1, 6))[0])
        return trace

    for a, b in zip(rollout(), rollout(), strict=True):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])


def test_state_save_restore_continues_identically():
    env = make(ENV_IDS[1], num_views=2, obs_mode="both", image_size=SMALL, target_speed=0.1)
    env.reset(seed=5)
    for _ in range(3):
        env.step(np.full(6, 0.3))
    state = env.get_state()
    first = [env.step(np.full(6, -0.2))[0] for _ in range(3)]
    env.set_state(state)
    second = [env.step(np.full(6, -0.2))[0] for _ in range(3)]
    for a, b in zip(first, second, strict=True):
        for key in ("observation", "achieved_goal", "images"):
            np.testing.assert_array_equal(a[key], b[key])


def test_previous_action_is_the_last_step_executed_and_survives_a_state_restore():
    env = make(ENV_IDS[1], previous_action=True)
    obs, _ = env.reset(seed=4)
    np.testing.assert_array_equal(obs["previous_action"], np.zeros(6, np.float32))
    for action in (np.full(6, 0.5), np.array([1.0, -1, 0.2, 0, 0.7, -0.3])):
        obs, _, _, _, info = env.step(action)
        np.testing.assert_array_equal(obs["previous_action"], info["executed_action"])
    np.testing.assert_allclose(obs["previous_action"], [1.0, -1, 0.2, 0, 0.7, -0.3], atol=1e-5)
    state = env.get_state()
    env.step(np.zeros(6))
    env.set_state(state)
    np.testing.assert_allclose(env.observe()["previous_action"], obs["previous_action"])
    assert np.all(env.reset(seed=5)[0]["previous_action"] == 0)
    assert "previous_action" not in make(ENV_IDS[1]).reset(seed=4)[0]
    with pytest.raises(ValueError, match="previous_action must be True or False"):
        make(ENV_IDS[1], previous_action="yes")


def test_render_images_moves_the_target_without_stepping():
    env = make(ENV_IDS[1], num_views=2, obs_mode="both", image_size=SMALL)
    obs, _ = env.reset(seed=4)
    state = env.get_state()
    same = env.render_images(obs["observation"], obs["desired_goal"])
    np.testing.assert_array_equal(same, obs["images"])
    moved = env.render_images(obs["observation"], obs["achieved_goal"])
    assert not np.array_equal(moved, obs["images"])
    after = env.get_state()
    np.testing.assert_array_equal(after.sim.joints, state.sim.joints)
    np.testing.assert_array_equal(after.sim.target_position_m, state.sim.target_position_m)
    assert after.num_steps == state.num_steps


@pytest.mark.parametrize("speed", [0.05, 0.2, "variable"])
def test_moving_targets_stay_in_the_box_at_their_speed(speed):
    env = make(ENV_IDS[0], target_speed=speed)
    obs, _ = env.reset(seed=9)
    positions = [obs["desired_goal"]]
    for _ in range(100):
        obs, _, terminated, truncated, _ = env.step(np.zeros(6))
        positions.append(obs["desired_goal"])
        if terminated or truncated:
            break
    positions = np.array(positions)
    assert (positions >= reach.REACH_BOX_LOW_M - 1e-6).all()
    assert (positions <= reach.REACH_BOX_HIGH_M + 1e-6).all()
    step = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    top = max(reach.VARIABLE_SPEEDS_MPS) if speed == "variable" else speed
    assert step.max() <= top * 0.05 + 1e-6 and step.mean() > 0


def test_obstacle_tasks_are_valid_over_many_seeds():
    env = make(ENV_IDS[1])
    for seed in range(40):
        env.reset(seed=seed)
        task = env.task
        assert len(task.obstacles) == 2
        assert not env.scene.in_collision(task.start_joints)
        free = reach.collision_free_solutions(env.scene, task.target_position_m)
        assert len(free) > 0
        assert (task.target_position_m >= reach.GOAL_BOX_LOW_M).all()
        assert (task.target_position_m <= reach.GOAL_BOX_HIGH_M).all()
        centres = task.obstacles.positions_m
        assert (centres >= reach.OBSTACLE_CENTER_LOW_M).all()
        assert (centres <= reach.OBSTACLE_CENTER_HIGH_M).all()
        full = task.obstacles.half_sizes_m * 2
        assert (full >= 0.06 - 1e-9).all() and (full <= 0.09 + 1e-9).all()
        tip_start = env.scene.tip_position()
        assert np.linalg.norm(tip_start - task.target_position_m) >= 0.1 - 1e-9


def test_each_id_samples_its_task_family():
    assert {
        env_id: (make(env_id).num_obstacles, make(env_id).task_family) for env_id in ENV_IDS
    } == {
        "CLAMGen/Reach-v0": (0, "reach"),
        "CLAMGen/ReachObstacles-v0": (2, "obstacles"),
        "CLAMGen/ReachBlocked-v0": (2, "blocked"),
        "CLAMGen/ReachMixed-v0": (2, "mixed"),
    }
    # The same seed gives different tasks in the two obstacle families.
    standard, blocked = make(ENV_IDS[1]), make(ENV_IDS[2])
    standard.reset(seed=1)
    blocked.reset(seed=1)
    assert not np.array_equal(standard.task.target_position_m, blocked.task.target_position_m)


def test_the_mixed_family_draws_blocked_and_standard_tasks():
    from clamgen.sim.scene import Scene
    from clamgen.tasks import MIXED_BLOCKED_FRACTION, TASK_FAMILIES

    mixed, blocked, standard = (TASK_FAMILIES[f][0] for f in ("mixed", "blocked", "obstacles"))
    scene = Scene()
    drew_blocked = []
    for seed in range(12):
        # The mixed family draws one uniform number, then samples the chosen family.
        rng = np.random.default_rng(seed)
        chose_blocked = rng.random() < MIXED_BLOCKED_FRACTION
        expected = (blocked if chose_blocked else standard)(rng, scene, 2, 0.0)
        task = mixed(np.random.default_rng(seed), scene, 2, 0.0)
        np.testing.assert_array_equal(task.target_position_m, expected.target_position_m)
        np.testing.assert_array_equal(task.obstacles.positions_m, expected.obstacles.positions_m)
        drew_blocked.append(chose_blocked)
    assert 0 < sum(drew_blocked) < len(drew_blocked)  # both families appear


def test_reset_replays_a_given_task():
    env = make(ENV_IDS[1])
    env.reset(seed=11)
    task = env.task
    obs, _ = env.reset(options={"task": task})
    np.testing.assert_allclose(obs["observation"], task.start_joints, atol=1e-6)
    np.testing.assert_allclose(obs["desired_goal"], task.target_position_m, atol=1e-6)


def test_bad_input_is_refused_clearly():
    env = make(ENV_IDS[0])
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(5))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([0, 0, np.nan, 0, 0, 0]))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.array([0, 0, np.inf, 0, 0, 0]))
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"speed": 1})
    with pytest.raises(TypeError, match="Task"):
        env.reset(options={"task": "easy"})
    for kwargs, message in [
        ({"obs_mode": "pixels"}, "obs_mode"),
        ({"obs_mode": "images"}, "num_views"),
        ({"num_views": 5}, "num_views"),
        ({"target_speed": "fast"}, "variable"),
        ({"target_speed": -0.1}, ">= 0"),
        ({"image_size": 4, "num_views": 1, "obs_mode": "both"}, "image_size"),
        ({"collision_penalty": -1.0}, "collision_penalty"),
        ({"render_mode": "human"}, "render_mode"),
        ({"task_family": "hard", "num_obstacles": 2}, "task_family must be one of"),
        ({"task_family": "blocked"}, "needs num_obstacles >= 1"),
        ({"task_family": "reach", "num_obstacles": 2}, "needs num_obstacles = 0"),
        ({"fine_depth_size": 64}, "needs num_views >= 1"),
        ({"fine_depth_size": 4, "num_views": 1, "obs_mode": "both"}, "fine_depth_size"),
        ({"depth_noise_m": 0.01}, "needs num_views >= 1"),
        ({"depth_noise_m": -0.01, "num_views": 1, "obs_mode": "both"}, "depth_noise_m"),
        ({"depth_noise_m": float("nan"), "num_views": 1, "obs_mode": "both"}, "depth_noise_m"),
    ]:
        with pytest.raises(ValueError, match=message):
            ReachEnv(**kwargs)


def test_fine_depth_is_the_views_depth_rendered_finer():
    fine = make(ENV_IDS[1], num_views=2, obs_mode="both", image_size=SMALL, fine_depth_size=48)
    check_env(fine, skip_render_check=True)
    plain = make(ENV_IDS[1], num_views=2, obs_mode="both", image_size=48)
    action = np.full(6, 0.5)
    for env in (fine, plain):
        env.reset(seed=5)
    for _ in range(3):
        obs_fine = fine.step(action)[0]
        obs_plain = plain.step(action)[0]
        assert obs_fine["images"].shape == (2, 4, SMALL, SMALL)
        assert obs_fine["fine_depth"].shape == (2, 1, 48, 48)
        np.testing.assert_array_equal(obs_fine["fine_depth"], obs_plain["images"][:, 3:])
    fine.close()
    plain.close()


def test_depth_noise_grows_with_the_square_of_the_depth_and_keeps_the_tasks():
    from clamgen.sim.constants import DEPTH_RANGE_M
    from clamgen.sim.render import uint8_to_depth

    noise_m = 0.01
    kwargs = {"num_views": 3, "obs_mode": "both", "image_size": 64, "fine_depth_size": 64}
    clean = make(ENV_IDS[2], **kwargs)
    noisy = make(ENV_IDS[2], depth_noise_m=noise_m, **kwargs)
    check_env(noisy, skip_render_check=True)
    level_m = (DEPTH_RANGE_M[1] - DEPTH_RANGE_M[0]) / 255
    action = np.full(6, 0.3)
    for env in (clean, noisy):
        env.reset(seed=11)
    for _ in range(3):
        obs_clean, obs_noisy = clean.step(action)[0], noisy.step(action)[0]
        # The same task, target and arm; RGB untouched.
        for key in ("observation", "achieved_goal", "desired_goal"):
            np.testing.assert_array_equal(obs_clean[key], obs_noisy[key])
        np.testing.assert_array_equal(obs_clean["images"][:, :3], obs_noisy["images"][:, :3])
        depth = uint8_to_depth(obs_clean["images"][:, 3])
        error = uint8_to_depth(obs_noisy["images"][:, 3]) - depth
        inside = (depth > DEPTH_RANGE_M[0] + 0.1) & (depth < DEPTH_RANGE_M[1] - 0.3)
        # Normalised by the model's deviation, the error is about standard normal (up to the
        # depth's quantisation, a level of about 9 mm).
        scaled = error[inside] / (noise_m * depth[inside] ** 2)
        assert abs(scaled.mean()) < 0.1 and 0.9 < scaled.std() < 1.3
        assert np.abs(error[inside]).max() > 2 * level_m
        # The guard's finer camera gets its own draw of the same model.
        fine_error = uint8_to_depth(obs_noisy["fine_depth"][:, 0]) - depth
        assert not np.array_equal(fine_error, error)
        assert 0.9 < (fine_error[inside] / (noise_m * depth[inside] ** 2)).std() < 1.3
    # Seeded: the same noise again.
    first = noisy.reset(seed=11)[0]["images"]
    np.testing.assert_array_equal(first, noisy.reset(seed=11)[0]["images"])
    assert not np.array_equal(first, noisy.reset(seed=12)[0]["images"])
    clean.close()
    noisy.close()


def test_render_mode_rgb_array_gives_an_outside_view():
    env = make(ENV_IDS[1], render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8 and frame.std() > 5
    env.close()


def _make_image_env():
    return gym.make(ENV_IDS[1], num_views=2, obs_mode="both", image_size=SMALL)


def test_async_vector_env_renders_in_every_worker():
    # "spawn": a process forked after its parent made a GL context inherits a broken EGL state.
    envs = gym.vector.AsyncVectorEnv([_make_image_env, _make_image_env], context="spawn")
    obs, _ = envs.reset(seed=[0, 1])
    assert obs["images"].shape == (2, 2, 4, SMALL, SMALL)
    assert not np.array_equal(obs["images"][0], obs["images"][1])
    for _ in range(3):
        obs, rewards, *_ = envs.step(np.zeros((2, 6), np.float32))
    assert rewards.shape == (2,) and obs["images"].std() > 0
    envs.call("set_collision_penalty", 0.05)
    assert envs.get_attr("collision_penalty") == (0.05, 0.05)
    envs.close()


def test_forked_worker_after_gl_fails_fast_with_a_hint():
    env = make(ENV_IDS[0], num_views=1, obs_mode="both", image_size=SMALL)
    env.reset(seed=0)  # this process now has a GL context
    envs = gym.vector.AsyncVectorEnv([_make_image_env], context="fork")
    with pytest.raises(RuntimeError, match="spawn"):
        envs.reset(seed=0)
    envs.close(terminate=True)
