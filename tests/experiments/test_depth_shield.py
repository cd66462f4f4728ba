"""The collision shield on a policy's own depth images: the lifted obstacle surface lies on the
true obstacles, the arm's clearance to points, and obstacle-blind IK interpolation kept off
the obstacles it would hit."""

import json
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
import tyro

from clamgen.baselines import IKInterpolationPolicy
from clamgen.cli import EvalConfig, _depth_guard, _wants_depth_shield, _with_depth_shield
from clamgen.envs import ReachEnv
from clamgen.experiments.config import TEST_SEEDS
from clamgen.experiments.depth_planner import (
    ESCAPES,
    ESCAPES_PLANNER,
    HYBRID,
    DepthGuard,
    DepthShieldPlanner,
)
from clamgen.experiments.depth_shield import ArmCapsules, DepthOccupancy, DepthShield, _in_boxes
from clamgen.experiments.evaluate import evaluate
from clamgen.experiments.tables import _PlanTimeRecorder
from clamgen.experiments.video import RenderConfig
from clamgen.policy import HoldStill
from clamgen.sim import constants as C
from clamgen.sim.scene import Obstacles

REPO = Path(__file__).resolve().parents[2]

VIEWS, SIZE = 3, 64


def surface_distance(points: np.ndarray, obstacles: Obstacles) -> np.ndarray:
    """(P, N) distances of points to each obstacle (0 inside)."""
    out = []
    shapes = zip(obstacles.kinds, obstacles.positions_m, obstacles.half_sizes_m, strict=True)
    for kind, centre, half in shapes:
        rel = points - centre
        if kind == C.OBSTACLE_BOX:
            outside = np.maximum(np.abs(rel) - half, 0.0)
        else:
            radial = np.linalg.norm(rel[:, :2], axis=1) - half[0]
            outside = np.stack(
                [np.maximum(radial, 0.0), np.maximum(np.abs(rel[:, 2]) - half[2], 0.0)], 1
            )
        out.append(np.linalg.norm(outside, axis=1))
    return np.stack(out, 1)


def _blocked_env(**kwargs) -> ReachEnv:
    return ReachEnv(
        num_obstacles=2,
        task_family="blocked",
        obs_mode="both",
        num_views=VIEWS,
        image_size=SIZE,
        **kwargs,
    )


@pytest.fixture(scope="module")
def blocked_env():
    env = _blocked_env()
    yield env
    env.close()


def test_obstacle_points_lie_on_the_obstacles(blocked_env):
    occupancy = DepthOccupancy(VIEWS, SIZE, SIZE)
    for seed in TEST_SEEDS.seeds(4):
        obs, _ = blocked_env.reset(seed=int(seed))
        occupancy.reset()
        points = occupancy.update(obs)
        distance = surface_distance(points, blocked_env.unwrapped.scene.obstacles)
        # Voxel centres: within a voxel's half diagonal and the depth's quantisation.
        assert distance.min(axis=1).max() < 0.015
        # Every obstacle is seen, from several points.
        assert ((distance < 0.015).sum(axis=0) >= 10).all()


def test_pixels_whose_depth_shrank_add_no_obstacle_surface(blocked_env):
    """The map lifts only pixels whose depth grew since the last frame (a nearer surface where
    there was none is the moving arm): the same voxels as lifting every changed pixel, along
    episodes of a moving arm."""

    class EveryChangedPixel(DepthOccupancy):
        def lift(self, images, changed_only=False, **options):
            if changed_only and self._last_depth is not None:
                # Forget what the last frame showed where it differs: every changed pixel.
                depth = np.asarray(images)[:, 3].reshape(-1)
                self._last_depth = np.where(depth != self._last_depth, 0, self._last_depth)
            return super().lift(images, changed_only, **options)

    grown, changed = DepthOccupancy(VIEWS, SIZE, SIZE), EveryChangedPixel(VIEWS, SIZE, SIZE)
    policy = IKInterpolationPolicy()
    steps = 0
    for seed in TEST_SEEDS.seeds(3):
        obs, _ = blocked_env.reset(seed=int(seed))
        policy.reset(blocked_env)
        grown.reset()
        changed.reset()
        done = False
        while not done:
            grown.update(obs)
            changed.update(obs)
            assert np.array_equal(np.sort(grown._cells), np.sort(changed._cells))
            obs, _, terminated, truncated, _ = blocked_env.step(policy.act(obs))
            done, steps = terminated or truncated, steps + 1
    assert steps > 20


def test_a_map_told_the_depth_noise_keeps_the_obstacles_and_not_the_noise_around_the_arm():
    from clamgen.experiments.depth_kernels import within_capsules

    noise_m = 0.003  # sd 8 mm at the cameras' 1.6 m: about a depth level
    env = _blocked_env(depth_noise_m=noise_m)
    phantoms_near_arm = {}
    for model in (0.0, noise_m):
        occupancy = DepthOccupancy(VIEWS, SIZE, SIZE, noise_m=model)
        near_arm = 0
        for seed in TEST_SEEDS.seeds(3):
            obs, _ = env.reset(seed=int(seed))
            occupancy.reset()
            for _ in range(5):  # the arm holds still: five frames of fresh noise
                points = occupancy.update(obs)
                obs = env.step(np.zeros(6, np.float32))[0]
            distance = surface_distance(points, env.unwrapped.scene.obstacles)
            # Every obstacle is still seen, from many points.
            assert ((distance < 0.03).sum(axis=0) >= 10).all()
            off = distance.min(axis=1) > 0.03
            starts, ends = occupancy.arm.segments(obs["observation"][:6].astype(np.float64))
            reach = occupancy.arm.radii + 0.03
            near_arm += int((off & within_capsules(points, starts, ends, reach)).sum())
        phantoms_near_arm[model] = near_arm
    # Untold, the noise on the arm's pixels leaves surface around it that holds it still.
    assert phantoms_near_arm[0.0] >= 10 and phantoms_near_arm[noise_m] <= 1, phantoms_near_arm
    with pytest.raises(ValueError, match="noise_m"):
        DepthOccupancy(VIEWS, SIZE, SIZE, noise_m=-1.0)
    env.close()


def test_a_map_told_the_depth_noise_keeps_the_obstacle_surface_beside_the_target():
    """The noise moves a point along its ray only: the told map drops the target's noisy pixels
    (tested along the ray) but keeps the obstacle surface beside the target that exact depth
    keeps, down to the same distance from it (a sphere grown by the noise at the target's
    depth hid everything within 8 cm at this noise)."""
    noise_m = 0.01
    noisy_env, exact_env = _blocked_env(depth_noise_m=noise_m), _blocked_env()
    told, exact = (
        DepthOccupancy(VIEWS, SIZE, SIZE, noise_m=noise_m),
        DepthOccupancy(VIEWS, SIZE, SIZE),
    )
    nearest = []
    for seed in TEST_SEEDS.seeds(6):
        obs, _ = noisy_env.reset(seed=int(seed))
        exact_obs, _ = exact_env.reset(seed=int(seed))
        told.reset()
        exact.reset()
        for _ in range(3):
            told.update(obs)
            exact.update(exact_obs)
            obs = noisy_env.step(np.zeros(6, np.float32))[0]
            exact_obs = exact_env.step(np.zeros(6, np.float32))[0]
        goal = obs["desired_goal"].astype(np.float64)
        near = np.linalg.norm(told.points - goal, axis=1) < 0.12
        on_obstacles = surface_distance(told.points, noisy_env.unwrapped.scene.obstacles)
        assert (on_obstacles[near].min(axis=1) > 0.03).sum() <= 1  # no target pixels kept
        nearest.append([np.linalg.norm(m.points - goal, axis=1).min() for m in (told, exact)])
    nearest = np.array(nearest)
    assert (nearest[:, 0] < nearest[:, 1] + 0.015).all(), nearest
    assert (nearest[:, 1] < 0.06).sum() >= 3, nearest  # tasks with surface close to the target
    noisy_env.close()
    exact_env.close()


def test_bridged_pixels_add_surface_on_the_obstacles(blocked_env):
    """Joining neighbouring pixels' obstacle points (bridge_m) keeps more of the obstacles'
    surface, and all of it on them."""
    plain = DepthOccupancy(VIEWS, SIZE, SIZE)
    bridged = DepthOccupancy(VIEWS, SIZE, SIZE, bridge_m=0.05)
    policy = IKInterpolationPolicy()
    for seed in TEST_SEEDS.seeds(2):
        obs, _ = blocked_env.reset(seed=int(seed))
        policy.reset(blocked_env)
        plain.reset()
        bridged.reset()
        done = False
        while not done:
            plain.update(obs)
            bridged.update(obs)
            obs, _, terminated, truncated, _ = blocked_env.step(policy.act(obs))
            done = terminated or truncated
        obstacles = blocked_env.unwrapped.scene.obstacles
        assert surface_distance(bridged.points, obstacles).min(axis=1).max() < 0.015
        assert set(map(tuple, plain.points)) <= set(map(tuple, bridged.points))
        assert len(bridged.points) > 1.5 * len(plain.points)
    with pytest.raises(ValueError, match="bridge_m"):
        DepthOccupancy(VIEWS, SIZE, SIZE, bridge_m=-1.0)


def test_shield_on_the_fine_depth_sees_what_a_shield_on_images_that_size_sees():
    fine = ReachEnv(
        num_obstacles=2,
        task_family="blocked",
        obs_mode="both",
        num_views=1,
        image_size=32,
        fine_depth_size=SIZE,
    )
    plain = DepthShield(IKInterpolationPolicy(), 1, SIZE)
    on_fine = DepthShield(IKInterpolationPolicy(), 1, 32, fine_depth_size=SIZE)
    ik = IKInterpolationPolicy()
    obs, _ = fine.reset(seed=int(TEST_SEEDS.seeds(1)[0]))
    for shield in (plain, on_fine, ik):
        shield.reset(fine)
    for _ in range(8):
        as_images = {**obs, "images": np.repeat(obs["fine_depth"], 4, axis=1)}
        np.testing.assert_array_equal(on_fine.observe(obs), plain.observe(as_images))
        assert len(on_fine.checker.points) > 0
        np.testing.assert_array_equal(on_fine.checker.points, plain.checker.points)
        obs = fine.step(ik.act(obs))[0]
    fine.close()


def test_box_test_by_coordinates_matches_the_box_test_on_whole_points():
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (500, 3))
    points[:50] = np.round(points[:50], 1)  # some on the boxes' faces
    low, high = rng.uniform(-1.0, 0.0, (7, 3)).round(1), rng.uniform(0.0, 1.0, (7, 3)).round(1)
    whole = ((points[:, None] > low) & (points[:, None] < high)).all(axis=2)
    np.testing.assert_array_equal(_in_boxes(points, low, high), whole)
    np.testing.assert_array_equal(_in_boxes(points, low[0], high[0]), whole[:, 0])


def test_arm_clearance_to_points_and_table():
    arm = ArmCapsules()
    model, data = arm.scene.model, arm.scene.data
    table_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    rng = np.random.default_rng(0)
    for joints in [np.array([0.0, -1.2, 1.4, -1.8, -1.57, 0.0]), *rng.uniform(-1.5, 1.5, (10, 6))]:
        table = arm.clearance(joints, np.empty((0, 3)))
        arm.scene.set_joints(joints)
        # MuJoCo's own distances of the geoms that can touch the table; the gripper's cylinders
        # are capsules here, up to their radius nearer.
        exact = min(
            mujoco.mj_geomDistance(model, data, int(g), table_geom, 2.0, None)
            for g in arm.geoms[arm.touch_table]
        )
        if exact > 0:  # (deep inside the thick table the two measure depth differently)
            assert exact - 0.04 <= table <= exact + 1e-6
        else:
            assert table < 0
    joints = np.array([0.0, -1.2, 1.4, -1.8, -1.57, 0.0])
    table = arm.clearance(joints, np.empty((0, 3)))
    arm.scene.set_joints(joints)
    tip = arm.scene.tip_position()
    assert arm.clearance(joints, tip[None]) < 0  # a point on the gripper
    far = tip + np.array([0.0, 0.0, 2.0])  # far above the arm: the table is nearer
    assert arm.clearance(joints, far[None]) == pytest.approx(table)


def test_depth_shield_keeps_blind_ik_interpolation_off_the_obstacles(blocked_env):
    seeds = TEST_SEEDS.seeds(4)
    blind = evaluate(blocked_env, IKInterpolationPolicy(), seeds)
    assert all(r.collided for r in blind)  # blocked tasks: the blind path collides
    shield = DepthShield(IKInterpolationPolicy(), VIEWS, SIZE, margin_m=0.01)
    shielded = evaluate(blocked_env, shield, seeds)
    assert shield.num_shielded > 0
    assert sum(r.collided for r in shielded) <= 1


def test_planner_on_the_depth_map_reaches_past_the_obstacles(blocked_env):
    pytest.importorskip("ompl.base")
    from clamgen.experiments.depth_planner import STUCK_STEPS, DepthShieldPlanner

    planner = DepthShieldPlanner(HoldStill(), VIEWS, SIZE, margin_m=0.01)
    recorder = _PlanTimeRecorder(planner)
    records = evaluate(blocked_env, recorder, TEST_SEEDS.seeds(3))
    # It waits out the stuck steps, plans on what the cameras showed, and arrives cleanly.
    assert planner.num_plans >= 3 and planner.num_paths >= 2
    assert sum(r.success for r in records) >= 2
    assert not any(r.collided for r in records)
    assert all(r.steps > STUCK_STEPS for r in records)
    # Its planning time per task is read when each episode is over, and spent in its acts.
    times = recorder.finish()
    assert len(times) == 3 and all(t > 0 for t in times)
    for time_s, record in zip(times, records, strict=True):
        assert sum(record.act_times_s) >= time_s


def test_planner_with_a_budget_in_checks_reaches_past_the_obstacles_the_same_way_twice(
    blocked_env,
):
    pytest.importorskip("ompl.base")
    from clamgen.experiments.depth_planner import DepthShieldPlanner

    runs = []
    for _ in range(2):
        planner = DepthShieldPlanner(HoldStill(), VIEWS, SIZE, margin_m=0.01, plan_checks=10_000)
        assert planner.rrt.max_checks == 10_000 and planner.rrt.simplify_max_checks
        records = evaluate(blocked_env, planner, TEST_SEEDS.seeds(3))
        assert planner.num_paths >= 2 and not any(r.collided for r in records)
        runs.append([(r.success, r.steps, r.tip_path_m) for r in records])
    assert runs[0] == runs[1]
    with pytest.raises(ValueError):
        DepthShieldPlanner(HoldStill(), VIEWS, SIZE, plan_checks=-1)


def test_the_planner_reaches_a_goal_tighter_than_its_margin_only_within_the_goal_zone():
    """A blocked target where every configuration at the goal comes within 1 cm of the seen
    surface (a training task; true clearance at best 5.5 mm): with `goal_zone_m` the plan
    keeps `GOAL_MARGIN_M` within the zone and the margin elsewhere; without, there is none."""
    pytest.importorskip("ompl.base")
    from clamgen.experiments.config import TRAINING_SEEDS
    from clamgen.experiments.depth_planner import GOAL_MARGIN_M, DepthShieldPlanner
    from clamgen.robot.kinematics import tip_position

    env = ReachEnv(
        num_obstacles=2, task_family="blocked", num_views=VIEWS, image_size=SIZE,
        obs_mode="both", fine_depth_size=128,
    )  # fmt: skip
    obs, _ = env.reset(seed=TRAINING_SEEDS.start + 777_126)
    goal = np.asarray(obs["desired_goal"], np.float64)
    paths = {}
    for zone_m in (0.0, 0.1):
        planner = DepthShieldPlanner(
            HoldStill(), VIEWS, SIZE, margin_m=0.01, plan_checks=20_000, fine_depth_size=128,
            goal_zone_m=zone_m,
        )  # fmt: skip
        planner.reset(env)
        joints = planner.observe(obs)
        assert planner.checker.clearance(joints, cap=0.01) >= 0.01
        paths[zone_m] = planner.plan(joints, goal)
    assert paths[0.0] is None
    clearances = np.array([planner.checker.clearance(q, cap=0.01) for q in paths[0.1]])
    off_goal = np.linalg.norm([tip_position(q) - goal for q in paths[0.1]], axis=1)
    assert clearances.min() >= GOAL_MARGIN_M - 1e-6 and clearances.min() < 0.01
    assert (off_goal[clearances < 0.01 - 1e-6] < 0.1).all()
    assert off_goal[-1] < 0.01
    with pytest.raises(ValueError, match="goal_zone_m"):
        DepthShieldPlanner(HoldStill(), VIEWS, SIZE, goal_zone_m=-1.0)


def test_rrt_on_the_depth_map_plans_at_the_first_step_with_no_policy(blocked_env):
    """`plan_first` (the `depth-rrt-*` baselines): with nothing inside but a held arm, the
    planner plans on the first views at once instead of after the stall window, so the same
    tasks are solved sooner."""
    pytest.importorskip("ompl.base")
    from clamgen.experiments.depth_planner import STUCK_STEPS, DepthShieldPlanner

    seeds = TEST_SEEDS.seeds(3)
    waiting = DepthShieldPlanner(HoldStill(), VIEWS, SIZE, margin_m=0.01, plan_checks=10_000)
    first = DepthShieldPlanner(
        HoldStill(), VIEWS, SIZE, margin_m=0.01, plan_checks=10_000, plan_first=True
    )
    waited, planned = evaluate(blocked_env, waiting, seeds), evaluate(blocked_env, first, seeds)
    assert first.num_plans >= len(seeds)  # one at each episode's first step, at least
    assert sum(r.success for r in planned) >= 2 and not any(r.collided for r in planned)
    both = [(w, p) for w, p in zip(waited, planned, strict=True) if w.success and p.success]
    # A held arm shows the planner the same views at the first step as after the window: with
    # a budget in checks, the same path, taken STUCK_STEPS steps sooner.
    assert both and all(w.steps - p.steps == STUCK_STEPS for w, p in both)


def test_target_track_expects_straight_motion_and_counts_path_steps():
    from clamgen.envs.reach_env import MAX_JOINT_DELTA_RAD
    from clamgen.experiments.depth_planner import TargetTrack, follow_steps

    track = TargetTrack()
    goal = np.array([0.5, 0.0, 0.3])
    track.observe(goal)
    assert not track.moving and track.off_course(goal) == 0.0  # no plan yet
    track.planned(goal)
    step = np.array([0.01, 0.0, 0.0])
    for k in range(1, 4):
        track.observe(goal + k * step)
    assert track.moving and np.allclose(track.velocity, step)
    assert track.off_course(goal + 3 * step) == pytest.approx(0.03)  # planned as if still
    track.planned(goal + 3 * step)
    track.observe(goal + 4 * step)
    assert track.off_course(goal + 4 * step) == pytest.approx(0.0)  # on course now
    assert track.off_course(goal + 2 * step) == pytest.approx(0.02)  # bounced back
    assert np.allclose(track.ahead(goal, 5), goal + 5 * step)
    # Steps that passed unseen (the arm held still while a plan was computed): the velocity is
    # the move over all of them, and the course counts them.
    track.skip(2)
    track.observe(goal + 7 * step)
    assert np.allclose(track.velocity, step)
    assert track.off_course(goal + 7 * step) == pytest.approx(0.0)
    joints = np.zeros(6)
    waypoints = np.array([[2.5, 0, 0, 0, 0, 0], [2.5, 1.0, 0, 0, 0, 0]]) * MAX_JOINT_DELTA_RAD
    assert follow_steps(joints, waypoints) == 3 + 1  # ceil(2.5) steps, then one


def test_rrt_on_the_depth_map_meets_a_moving_target_and_plans_a_static_one_as_before():
    """`track_m` (the `depth-rrt-*` baselines): with the target moving at 0.2 m/s the planner
    that meets it arrives where the one that plans to where the target was does not; with a
    static target the two plan the same (a budget in checks: the same plans twice)."""
    pytest.importorskip("ompl.base")
    from clamgen.experiments.depth_planner import TRACK_M, depth_rrt

    seeds = TEST_SEEDS.seeds(3)
    outcomes = {}
    for speed in (0.0, 0.2):
        for track in (0.0, TRACK_M):
            policy, env_kwargs = depth_rrt(2, plan_checks=10_000, track_m=track)
            env = ReachEnv(num_obstacles=2, task_family="blocked", target_speed=speed, **env_kwargs)
            records = evaluate(env, policy, seeds)
            env.close()
            outcomes[speed, track] = [(r.success, r.steps, r.tip_path_m) for r in records]
    assert outcomes[0.0, 0.0] == outcomes[0.0, TRACK_M]
    met = sum(success for success, _, _ in outcomes[0.2, TRACK_M])
    assert met >= 2 and met > sum(success for success, _, _ in outcomes[0.2, 0.0])


def test_a_hybrid_meeting_a_moving_target_plans_only_once_its_policy_stalls():
    """`track_m` in a hybrid: the policy inside acts until it stalls, as without it; only
    then does the planner meet the moving target."""
    from clamgen.experiments.depth_planner import STUCK_STEPS, TRACK_M

    env = ReachEnv(num_obstacles=0, obs_mode="both", num_views=VIEWS, image_size=SIZE,
                   target_speed=0.2)  # fmt: skip
    hybrid = DepthShieldPlanner(HoldStill(), VIEWS, SIZE, plan_checks=2_000, track_m=TRACK_M)
    obs, _ = env.reset(seed=TEST_SEEDS.start)
    hybrid.reset(env)
    first_plan = None
    for step in range(4 * STUCK_STEPS):
        action = hybrid.act(obs)
        if hybrid.num_plans and first_plan is None:
            first_plan = step
        obs, *_ = env.step(action)
    env.close()
    # The stall window's plan, no sooner (a tracker on its own would plan after a few steps).
    assert first_plan is not None and first_plan >= STUCK_STEPS


def test_the_planner_learns_its_latency_only_from_steps_held_after_a_plan():
    """Acting in real time the arm holds still while a plan is computed: the planner meets the
    target that much further ahead (`latency`); without real time it is never told, and plans
    as before."""
    pytest.importorskip("ompl.base")
    from clamgen.experiments.depth_planner import depth_rrt

    planner, env_kwargs = depth_rrt(2, plan_checks=2_000)
    assert planner.latency and planner.latency_steps == 0
    env = ReachEnv(num_obstacles=2, task_family="blocked", target_speed=0.2, **env_kwargs)
    obs, _ = env.reset(seed=TEST_SEEDS.start)
    planner.reset(env)
    action = planner.act(obs)  # plans first
    planner.skipped(3)
    assert planner.latency_steps == 3
    obs, *_ = env.step(action)
    planner.act(obs)
    if not planner._planned_last_act:
        planner.skipped(5)  # held after an act that did not plan: not the planner's latency
        assert planner.latency_steps == 3
    env.close()


def test_the_depth_rrt_baselines_are_policies_by_name(tmp_path, capsys):
    """`--policy depth-rrt-<V>views`: the hybrid's shield and planner of V views around a held
    arm, planning first, on V rendered views; no other depth option goes with it."""
    pytest.importorskip("ompl.base")
    from clamgen.cli import main
    from clamgen.experiments.depth_planner import (
        RENDERED_VIEWS_IMAGE_SIZE,
        TRACK_M,
        DepthShieldPlanner,
        depth_rrt,
    )
    from clamgen.experiments.policies import DEPTH_RRT_BASELINES, load_policy, views_suffix

    for name, views in DEPTH_RRT_BASELINES.items():
        assert name == f"depth-rrt-{views_suffix(views)}"
        policy, source, env_kwargs = load_policy(name)
        guard = replace(HYBRID[views], plan_first=True, track_m=TRACK_M)
        assert isinstance(policy, DepthShieldPlanner) and policy.plan_first
        assert policy.track_m == TRACK_M
        assert isinstance(policy.policy, HoldStill) and source.startswith(name)
        assert env_kwargs == {
            "num_views": views,
            "image_size": RENDERED_VIEWS_IMAGE_SIZE,
            "obs_mode": "both",
            **guard.env_kwargs(),
        }
        assert guard.describe().endswith(
            "planner from the first step and when stuck, meeting a moving target "
            f"(replanning {TRACK_M} m off)"
        )
        with pytest.raises(ValueError, match="plans first"):
            guard.flags()
    with pytest.raises(ValueError, match="1 to 4 views"):
        depth_rrt(0)
    assert depth_rrt(2, plan_checks=5000)[0].rrt.max_checks == 5000
    assert depth_rrt(2)[0].rrt.max_checks is None  # the time budget
    # By name with options (as `clamgen eval` builds it, once).
    told = load_policy("depth-rrt-2views", plan_checks=5000, noise_m=0.003)[0]
    assert told.rrt.max_checks == 5000 and told.occupancy.noise_m == 0.003
    with pytest.raises(TypeError, match="depth_rrt_options"):
        load_policy("ik", noise_m=0.003)
    for extra in (["--depth-hybrid"], ["--depth-views", "2", "--depth-escapes"]):
        with pytest.raises(SystemExit, match="drop the --depth-\\* options \\(but"):
            main(["eval", "--policy", "depth-rrt-2views", *extra, "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="--depth-plan-checks must be >= 0"):
        main(["eval", "--policy", "depth-rrt-2views", "--depth-plan-checks", "-1"])
    with pytest.raises(SystemExit, match="--depth-track-m must be a number >= 0"):
        main(["eval", "--policy", "depth-rrt-2views", "--depth-track-m", "-1"])
    with pytest.raises(SystemExit, match="--depth-track-m needs --depth-planner"):
        main(["eval", "--policy", "residual-2views", "--depth-shield-m", "0.01",
              "--depth-track-m", "0.02"])  # fmt: skip
    out = tmp_path / "depth_rrt"
    args = ["--table", "2", "--policy", "depth-rrt-1view", "--families", "blocked"]
    main(["eval", *args, "--num-tasks", "1", "--out", str(out)])
    row = json.loads(out.with_suffix(".json").read_text())["rows"][0]
    assert row["name"] == "RRT on the depth map of 1 RGBD view, no learned policy (ours)"
    assert row["family"] == "blocked" and row["num_tasks"] == 1
    # With a budget in checks: the same episodes twice, the row saying so.
    runs = []
    for run in ("a", "b"):
        out = tmp_path / f"depth_rrt_checks_{run}"
        checks = ["--depth-plan-checks", "10000"]
        main(["eval", *args, *checks, "--num-tasks", "2", "--out", str(out)])
        runs.append(json.loads(out.with_suffix(".json").read_text())["rows"][0])
    assert runs[0]["name"].endswith("no learned policy (ours), 10000 checks a plan")
    assert runs[0]["task_steps"] == runs[1]["task_steps"]
    assert runs[0]["task_tip_path_m"] == runs[1]["task_tip_path_m"]
    # --depth-track-m 0: session 43's baseline, planning to where a moving target is.
    out = tmp_path / "depth_rrt_to_where_it_is"
    main(["eval", *args, "--depth-track-m", "0", "--num-tasks", "1", "--out", str(out)])
    row = json.loads(out.with_suffix(".json").read_text())["rows"][0]
    assert row["name"].endswith("no learned policy (ours), planning to where the target is")
    # --real-time: the plans take simulated time, the row says so and counts the held steps.
    out = tmp_path / "depth_rrt_real_time"
    moving = ["--target-speed", "0.2", "--real-time", "--num-tasks", "2"]
    main(["eval", *args, *moving, "--out", str(out)])
    row = json.loads(out.with_suffix(".json").read_text())["rows"][0]
    assert row["name"].endswith("(ours), target moving at 0.2 m/s, acting in real time")
    assert row["real_time"] and len(row["task_held_steps"]) == 2
    held_and_steps = zip(row["task_held_steps"], row["task_steps"], strict=True)
    assert all(0 <= held < steps for held, steps in held_and_steps)
    # --depth-noise-m: the views' depth noisy, the row says so and records it; untold, a note
    # says what the map assumes.
    out = tmp_path / "depth_rrt_noisy"
    capsys.readouterr()
    main(["eval", *args, "--depth-noise-m", "0.002", "--num-tasks", "1", "--out", str(out)])
    untold = "note: --depth-noise-m without --depth-noise-model-m: the depth map assumes exact"
    assert untold in capsys.readouterr().out
    row = json.loads(out.with_suffix(".json").read_text())["rows"][0]
    assert row["name"].endswith("no learned policy (ours), depth noise sd 0.002*z^2 m")
    assert row["depth_noise_m"] == 0.002
    told = ["--depth-noise-model-m", "0.002", "--depth-noise-m", "0.002", "--num-tasks", "1"]
    main(["eval", *args, *told, "--out", str(out), "--overwrite"])
    assert untold not in capsys.readouterr().out
    row = json.loads(out.with_suffix(".json").read_text())["rows"][0]
    assert row["name"].endswith(
        "(ours), depth noise model sd 0.002*z^2 m, depth noise sd 0.002*z^2 m"
    )


def test_arm_shadow_hides_what_is_behind_the_hand_until_a_camera_sees_it():
    from clamgen.experiments.depth_shield import ArmShadow

    env = ReachEnv(num_obstacles=0, obs_mode="both", num_views=1, image_size=SIZE)
    obs, _ = env.reset(seed=TEST_SEEDS.start)
    joints = np.asarray(obs["observation"], np.float64)[:6]
    occupancy = DepthOccupancy(1, SIZE, SIZE)
    shadow = ArmShadow(occupancy, near_m=0.2)
    shadow.update(obs["images"], joints)
    camera = occupancy.arm.scene.camera_ids[0]
    eye = env.unwrapped.scene.data.cam_xpos[camera].copy()
    starts, ends = occupancy.arm.segments(joints)
    gripper = [occupancy.arm.scene.model.geom(int(g)).name for g in occupancy.arm.geoms]
    hand = 0.5 * (starts + ends)[gripper.index("gripper")]
    ray = (hand - eye) / np.linalg.norm(hand - eye)
    behind, before = hand + 0.15 * ray, hand - 0.15 * ray
    assert shadow.hidden_points(np.stack([behind, before])).tolist() == [True, False]
    # The hand where it is fills its own shadow: no configuration is refused for being there,
    # even beside seen obstacle surface.
    assert not shadow.hidden(joints, behind[None])[0]
    # Moving the hand some ways reaches into its shadow: refused near seen obstacle surface
    # behind it, not when the only surface seen is far away.
    moves = joints + 0.06 * np.concatenate([np.eye(6), -np.eye(6)])
    assert shadow.hidden(moves, behind[None]).any()
    assert not shadow.hidden(moves, behind[None] + np.array([0.0, 0.0, 1.0])).any()
    # Once the arm has turned aside, the camera sees the space it hid.
    aside = joints + np.array([0.6, 0.0, 0.0, 0.0, 0.0, 0.0])
    images = env.unwrapped.render_images(aside, np.asarray(obs["desired_goal"]))
    env.close()
    shadow.update(images, aside)
    assert not shadow.hidden_points(behind[None])[0]


def _blocked_one_view(seed: int):
    """A blocked task seen by one camera: its first observation, the arm's joints (float64) and
    an empty `DepthOccupancy` for that camera."""
    env = ReachEnv(
        num_obstacles=2, task_family="blocked", obs_mode="both", num_views=1, image_size=SIZE
    )
    obs, _ = env.reset(seed=seed)
    env.close()
    joints = np.asarray(obs["observation"], np.float64)[:6]
    return obs, joints, DepthOccupancy(1, SIZE, SIZE)


def test_shadow_behind_surfaces_hides_the_far_side_of_seen_obstacles():
    from clamgen.experiments.depth_shield import ArmShadow

    obs, joints, occupancy = _blocked_one_view(seed=TEST_SEEDS.start + 1)
    surface = occupancy.update(obs)
    assert len(surface) > 0
    eye = occupancy.origins[0].astype(np.float64)
    rays = (surface - eye) / np.linalg.norm(surface - eye, axis=1, keepdims=True)
    far_side = surface + 0.05 * rays  # 5 cm behind the seen surface, along the camera's ray
    arm_only = ArmShadow(occupancy, near_m=0.05)
    anything = ArmShadow(occupancy, near_m=0.05, behind_surfaces=True)
    for shadow in (arm_only, anything):
        shadow.update(obs["images"], joints)
    assert anything.hidden_points(far_side).mean() > 0.9
    assert arm_only.hidden_points(far_side).mean() < 0.1


def test_random_escapes_inside_the_shield_move_a_stuck_policy_without_contact(blocked_env):
    from clamgen.experiments.stall import StallBurst

    guard = DepthGuard(escapes=True)
    shielded = guard.wrap(HoldStill(), VIEWS, SIZE)
    assert isinstance(shielded, DepthShield) and not isinstance(shielded, DepthShieldPlanner)
    assert isinstance(shielded.policy, StallBurst)
    runs = []
    for _ in range(2):
        records = evaluate(blocked_env, guard.wrap(HoldStill(), VIEWS, SIZE), TEST_SEEDS.seeds(3))
        # A policy that never moves stalls at once: the escapes move the arm, never into contact.
        assert all(r.tip_path_m > 0.05 for r in records)
        assert not any(r.collided for r in records)
        runs.append([(r.success, r.steps, r.tip_path_m) for r in records])
    assert runs[0] == runs[1]  # seeded per episode
    assert guard.describe().endswith(" + random escapes when stuck")


class _PlanLog:
    """Records, at each of `planner`'s plans, the step of the episode and the escapes its
    policy (a `StallBurst`) has begun, with the step the latest began."""

    def __init__(self, planner) -> None:
        self.plans: list[tuple[int, int, int]] = []
        self.step, self.escapes, self.escape_step = 0, 0, -1
        plan, act, reset = planner.plan, planner.policy.act, planner.reset

        def logged_plan(joints, goal):
            self.plans.append((self.step, planner.policy.episode_bursts, self.escape_step))
            return plan(joints, goal)

        def logged_act(obs):
            action = act(obs)
            if planner.policy.episode_bursts != self.escapes:
                self.escapes, self.escape_step = planner.policy.episode_bursts, self.step
            return action

        def logged_reset(env=None):
            reset(env)
            self.step, self.escapes, self.escape_step = 0, 0, -1

        def count_step(obs):
            action = planner_act(obs)
            self.step += 1
            return action

        planner.plan, planner.policy.act, planner.reset = logged_plan, logged_act, logged_reset
        planner_act = planner.act
        planner.act = count_step


@pytest.mark.parametrize("escapes_first", [0, 1])
def test_the_planner_waits_for_the_escapes_it_is_given(blocked_env, escapes_first):
    pytest.importorskip("ompl.base")
    from clamgen.experiments.depth_planner import STUCK_STEPS
    from clamgen.experiments.stall import StallBurst

    guard = DepthGuard(planner=True, escapes=True, escapes_before_plan=escapes_first)
    both = guard.wrap(HoldStill(), VIEWS, SIZE)
    assert isinstance(both, DepthShieldPlanner) and isinstance(both.policy, StallBurst)
    log = _PlanLog(both)
    records = evaluate(blocked_env, both, TEST_SEEDS.seeds(3))
    # A policy that never moves stalls at once. With escapes first, each plan comes only after
    # that many escapes, and a full stall window after the latest began (it has its steps to
    # make progress); with none first, the first plan comes before any escape.
    assert log.plans and both.num_paths >= 1
    for step, escapes, escape_step in log.plans:
        assert escapes >= escapes_first
        if escapes:
            assert step - escape_step >= STUCK_STEPS
    if escapes_first == 0:
        assert any(escapes == 0 for _, escapes, _ in log.plans)
    assert not any(r.collided for r in records)
    ending = ("where the planner finds no path", "when stuck (1 before a plan)")[escapes_first]
    assert guard.describe().endswith(f" + planner when stuck + random escapes {ending}")
    with pytest.raises(ValueError, match="escapes_before_plan"):
        DepthShieldPlanner(HoldStill(), VIEWS, SIZE, escapes_before_plan=-1)


@pytest.mark.parametrize("views", sorted(ESCAPES))
def test_random_escapes_alone_are_the_escape_rows_setting(views):
    config = tyro.cli(EvalConfig, args=["--table", "2", "--depth-escapes"])
    assert _wants_depth_shield(config)
    env_kwargs = {"num_views": views, "image_size": 64, "obs_mode": "both"}
    shielded, source, kwargs = _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)
    guard = ESCAPES[views]
    assert source == guard.describe() and kwargs == env_kwargs | guard.env_kwargs()
    assert guard.escapes and not guard.planner and guard.shadow_behind_surfaces
    assert not isinstance(shielded, DepthShieldPlanner)
    config = tyro.cli(EvalConfig, args=["--table", "2", *guard.flags()])
    assert _depth_guard(config) == guard
    render = tyro.cli(RenderConfig, args=["--policy", "residual-3views", "--depth-escapes"])
    assert _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, render)[1] == source
    for args, message in (
        (["--depth-hybrid", "--depth-escapes"], "--depth-hybrid sets the depth options"),
        (["--depth-escapes", "--depth-fine-size", "128"], "needs --depth-shield-m"),
        (["--depth-escapes-before-plan", "1"], "needs --depth-escapes and --depth-planner"),
        (
            ["--depth-escapes", "--depth-escapes-before-plan", "2"],
            "needs --depth-escapes and --depth-planner",
        ),
        (
            ["--depth-shield-m", "0.01", "--depth-escapes", "--depth-escapes-before-plan", "2"],
            "needs --depth-escapes and --depth-planner",
        ),
        (
            ["--depth-planner", "--depth-escapes", "--depth-escapes-before-plan", "-1"],
            "must be >= 0",
        ),
        (
            [
                *("--depth-shield-m", "0.01", "--depth-planner", "--depth-escapes"),
                *("--depth-escapes-before-plan", "-1"),
            ],
            "must be >= 0",
        ),
    ):
        config = tyro.cli(EvalConfig, args=["--table", "2", *args])
        with pytest.raises(SystemExit, match=message):
            _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)


@pytest.mark.parametrize("views", sorted(ESCAPES_PLANNER))
def test_escapes_with_the_planner_alone_are_the_escape_rows_shield_planning_first(views):
    env_kwargs = {"num_views": views, "image_size": 64, "obs_mode": "both"}
    for extra, first in (([], 0), (["--depth-escapes-before-plan", "2"], 2)):
        args = ["--table", "2", "--depth-escapes", "--depth-planner", *extra]
        config = tyro.cli(EvalConfig, args=args)
        shielded, source, kwargs = _with_depth_shield(
            IKInterpolationPolicy(), "", env_kwargs, config
        )
        guard = replace(ESCAPES_PLANNER[views], escapes_before_plan=first)
        assert guard == replace(ESCAPES[views], planner=True, escapes_before_plan=first)
        assert source == guard.describe() and kwargs == env_kwargs | guard.env_kwargs()
        assert isinstance(shielded, DepthShieldPlanner)
        assert shielded.escapes_before_plan == first
        config = tyro.cli(EvalConfig, args=["--table", "2", *guard.flags()])
        assert _depth_guard(config) == guard


def test_a_policy_that_sees_no_images_acts_through_the_wrapper_on_rendered_views(tmp_path):
    """`--depth-views V`: the env renders V views (at the shipped residuals' size) for the
    wrapper alone; the policy's own observation is unchanged, and the row says so."""
    from clamgen.cli import main
    from clamgen.experiments.depth_planner import RENDERED_VIEWS_IMAGE_SIZE

    for views in (1, 3):
        config = tyro.cli(EvalConfig, args=["--depth-hybrid", "--depth-views", str(views)])
        assert _wants_depth_shield(config)
        shielded, source, kwargs = _with_depth_shield(IKInterpolationPolicy(), "ik", {}, config)
        guard = HYBRID[views]
        assert source == "ik" + guard.describe()
        rendered = {"num_views": views, "image_size": RENDERED_VIEWS_IMAGE_SIZE, "obs_mode": "both"}
        assert kwargs == rendered | guard.env_kwargs()
        assert isinstance(shielded, DepthShieldPlanner)
    # A vision residual's own views are the wrapper's: --depth-views may repeat them.
    own = {"num_views": 2, "image_size": 64, "obs_mode": "both"}
    config = tyro.cli(EvalConfig, args=["--depth-escapes", "--depth-views", "2"])
    assert _with_depth_shield(IKInterpolationPolicy(), "", own, config)[2] == (
        own | ESCAPES[2].env_kwargs()
    )
    # End to end: IK interpolation (no obstacle model) through the escape rows' wrapper on
    # one rendered view, on one blocked task.
    out = tmp_path / "ik_escapes"
    args = ["--table", "2", "--policy", "ik", "--depth-views", "1", "--depth-escapes"]
    main(["eval", *args, "--families", "blocked", "--num-tasks", "1", "--out", str(out)])
    row = json.loads(out.with_suffix(".json").read_text())["rows"][0]
    assert row["name"] == (
        "IK interpolation (no obstacle model)" + ESCAPES[1].describe() + ", 1 view rendered for it"
    )
    assert row["family"] == "blocked" and row["num_tasks"] == 1
    # A wrapped row says a moving target and real time too, as an unwrapped one does.
    out = tmp_path / "ik_escapes_moving"
    moving = ["--target-speed", "0.2", "--real-time", "--families", "blocked", "--num-tasks", "1"]
    main(["eval", *args, *moving, "--out", str(out)])
    row = json.loads(out.with_suffix(".json").read_text())["rows"][0]
    assert row["name"] == (
        "IK interpolation (no obstacle model)" + ESCAPES[1].describe() + ", 1 view rendered for "
        "it, target moving at 0.2 m/s, acting in real time"
    )


@pytest.mark.parametrize("views", sorted(HYBRID))
def test_hybrid_guard_flags_give_the_same_guard_through_clamgen_eval(views):
    guard = HYBRID[views]
    finer = DepthGuard(0.02, True, 0.05, False, 0.03, 128, 5000)
    escaping = DepthGuard(0.01, fine_depth_size=128, escapes=True)
    tracking = DepthGuard(0.01, planner=True, track_m=0.03)
    both = [replace(ESCAPES[views], planner=True, escapes_before_plan=first) for first in (0, 1, 2)]
    for each in (guard, finer, escaping, tracking, *both):
        config = tyro.cli(EvalConfig, args=["--table", "2", *each.flags()])
        assert _depth_guard(config) == each
    config = tyro.cli(EvalConfig, args=["--table", "2", "--depth-hybrid"])
    assert _wants_depth_shield(config)
    env_kwargs = {"num_views": views, "image_size": 64, "obs_mode": "both"}
    _, source, kwargs = _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)
    assert source == guard.describe()
    assert kwargs == env_kwargs | guard.env_kwargs()
    assert finer.env_kwargs() == {"fine_depth_size": 128}
    # `around`: the wrapper on the views the env options render, and the options it adds.
    shielded, around_kwargs = guard.around(IKInterpolationPolicy(), env_kwargs)
    assert isinstance(shielded, DepthShieldPlanner) and shielded.depth_key == "fine_depth"
    assert around_kwargs == kwargs


@pytest.mark.parametrize("views", sorted(HYBRID))
def test_the_preset_wrappers_take_their_planners_budget_and_tracking(views):
    env_kwargs = {"num_views": views, "image_size": 64, "obs_mode": "both"}
    planning = ["--depth-plan-checks", "5000", "--depth-track-m", "0", "--depth-goal-zone-m", "0.1"]
    noise = ["--depth-noise-model-m", "0.003"]
    for preset, guard in (
        (["--depth-hybrid"], HYBRID[views]),
        (["--depth-escapes", "--depth-planner"], ESCAPES_PLANNER[views]),
    ):
        config = tyro.cli(EvalConfig, args=["--table", "2", *preset, *planning, *noise])
        shielded, source, _ = _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)
        told = replace(guard, plan_checks=5000, track_m=0.0, noise_m=0.003, goal_zone_m=0.1)
        assert source == told.describe() and "depth noise model sd 0.003*z^2 m" in source
        assert "keeping 3 mm within 0.1 m of a goal" in source
        assert (shielded.rrt.max_checks, shielded.track_m, shielded.goal_zone_m) == (5000, 0.0, 0.1)
        assert shielded.occupancy.noise_m == 0.003
        assert _depth_guard(tyro.cli(EvalConfig, args=["--table", "2", *told.flags()])) == told
    # The escapes alone plan nothing, but their map takes the noise model.
    config = tyro.cli(EvalConfig, args=["--table", "2", "--depth-escapes", *noise])
    shielded = _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)[0]
    assert shielded.occupancy.noise_m == 0.003
    # Session 43's hybrid (planning to where the target is) by name, and the default kept.
    config = tyro.cli(EvalConfig, args=["--table", "2", "--depth-hybrid", "--depth-track-m", "0"])
    assert (
        "meeting a moving target"
        not in _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)[1]
    )
    config = tyro.cli(EvalConfig, args=["--table", "2", "--depth-escapes", "--depth-planner"])
    shielded = _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)[0]
    assert shielded.track_m == ESCAPES_PLANNER[views].track_m == 0.0
    for args, message in (
        (["--depth-escapes", "--depth-track-m", "0.02"], "need a planner"),
        (["--depth-escapes", "--depth-plan-checks", "100"], "need a planner"),
        (["--depth-escapes", "--depth-goal-zone-m", "0.1"], "need a planner"),
        (["--depth-hybrid", "--depth-goal-zone-m", "-1"], "must be a number >= 0"),
        (["--depth-shield-m", "0.01", "--depth-goal-zone-m", "0.1"], "needs --depth-planner"),
        (["--depth-hybrid", "--depth-track-m", "-1"], "must be a number >= 0"),
        (["--depth-hybrid", "--depth-plan-checks", "-1"], "must be >= 0"),
        (["--depth-hybrid", "--depth-noise-model-m", "-1"], "must be a number >= 0"),
        (["--depth-noise-model-m", "0.003"], "--depth-noise-model-m needs a depth wrapper"),
        (["--depth-hybrid", "--depth-fine-size", "64"], "--depth-hybrid sets the depth options"),
    ):
        config = tyro.cli(EvalConfig, args=["--table", "2", *args])
        with pytest.raises(SystemExit, match=message):
            _with_depth_shield(IKInterpolationPolicy(), "", env_kwargs, config)


def test_a_depth_wrapper_reading_noisy_depth_untold_says_what_its_map_assumes(capsys):
    from clamgen.cli import _check_depth_request

    for args, noted in (
        (["--depth-hybrid", "--depth-noise-m", "0.01"], True),
        (["--depth-escapes", "--depth-noise-m", "0.01", "--depth-noise-model-m", "0.01"], False),
        (["--depth-noise-m", "0.01"], False),  # the policy alone: no map
        (["--depth-hybrid"], False),
    ):
        _check_depth_request(tyro.cli(EvalConfig, args=["--table", "2", *args]))
        assert ("--depth-noise-m without --depth-noise-model-m" in capsys.readouterr().out) == noted


def test_hybrid_guards_describe_the_committed_hybrid_rows():
    one_view = Path("results/table2/planned_hidden_fine_residual-1view.json")
    two_views = Path("results/table2/planned_fine_residual-2views.json")
    for views, path in ((1, one_view), (2, two_views)):
        policy = json.loads((REPO / path).read_text())["policy"]
        # Measured before the planner met moving targets (static targets: the same plans).
        assert policy.endswith(replace(HYBRID[views], track_m=0.0).describe())
        assert HYBRID[views].track_m > 0
    guard = HYBRID[1]
    assert isinstance(guard.wrap(IKInterpolationPolicy(), 1, 64), DepthShieldPlanner)
    assert guard.wrap(IKInterpolationPolicy(), 1, 64).depth_key == "fine_depth"
    assert not isinstance(DepthGuard().wrap(IKInterpolationPolicy(), 1, 64), DepthShieldPlanner)


def test_compiled_frames_equal_the_forward_kinematics() -> None:
    """The shield's compiled DH frames are `forward_kinematics`' first six, to rounding."""
    from clamgen.experiments.depth_kernels import dh_frames
    from clamgen.robot import ur5
    from clamgen.robot.kinematics import forward_kinematics

    joints = np.random.default_rng(4).uniform(-np.pi, np.pi, (40, ur5.NUM_JOINTS))
    frames = dh_frames(joints, ur5.DH_D, ur5.DH_A, ur5.DH_ALPHA)
    np.testing.assert_allclose(frames, forward_kinematics(joints)[:, :6], rtol=0, atol=1e-12)


def test_depth_step_clearance_equals_the_exact_check_along_the_step():
    """The depth checker's step clearance (shortcut boxes, one batch of checks) is the smallest
    clearance of the step's checked configurations one by one, with the unseen-space test."""
    from clamgen.experiments.depth_shield import HIDDEN_CLEARANCE_M, ArmShadow, DepthClearance
    from clamgen.experiments.shield import step_clearance

    obs, joints, occupancy = _blocked_one_view(seed=TEST_SEEDS.start + 2)
    shadow = ArmShadow(occupancy, near_m=0.05, behind_surfaces=True)
    checker = DepthClearance(occupancy.arm, margin_m=0.02, shadow=shadow)
    checker.points = occupancy.update(obs)
    shadow.update(obs["images"], joints)
    rng = np.random.default_rng(3)
    # Configurations from the start towards the obstacles and the table, random actions.
    along = joints + rng.uniform(-0.8, 0.8, (30, 6)) * np.linspace(0.0, 1.0, 30)[:, None]
    values = []
    for q in along:
        for action in rng.uniform(-1.0, 1.0, (4, 6)):
            fast = checker.step_clearance(q, action)
            assert fast == pytest.approx(step_clearance(checker, q, action), abs=1e-9)
            values.append(fast)
    values = np.array(values)
    # The steps tested cover every branch: clear, near points or the table, into hidden space.
    assert (values == checker.margin_m).any()
    assert (values == HIDDEN_CLEARANCE_M).any()
    assert ((values < checker.margin_m) & (values != HIDDEN_CLEARANCE_M)).any()


WARM_UP_CHECK = """
from numba.core.registry import CPUDispatcher

from clamgen.baselines import IKInterpolationPolicy
from clamgen.envs import ReachEnv
from clamgen.experiments import depth_kernels
from clamgen.experiments.config import TEST_SEEDS
from clamgen.experiments.depth_planner import ESCAPES, HYBRID
from clamgen.experiments.depth_shield import warm_up
from clamgen.experiments.evaluate import evaluate
from dataclasses import replace


def signatures():
    kernels = [getattr(depth_kernels, name) for name in dir(depth_kernels)]
    return {k: set(k.signatures) for k in kernels if isinstance(k, CPUDispatcher)}


warm_up()
warm = signatures()
told = replace(HYBRID[2], noise_m=0.003)  # a map told the depth noise
for views, guard in ((1, ESCAPES[1]), (3, HYBRID[3]), (2, told)):
    env = ReachEnv(num_obstacles=2, task_family="blocked", num_views=views, image_size=64,
                   obs_mode="both", depth_noise_m=guard.noise_m, **guard.env_kwargs())
    evaluate(env, guard.wrap(IKInterpolationPolicy(), views, 64), TEST_SEEDS.seeds(2))
    env.close()
added = {k.__name__: s - warm[k] for k, s in signatures().items() if s - warm[k]}
print("added", added)
"""


def test_warm_up_loads_every_kernel_a_shielded_episode_calls():
    """In a fresh process, after `warm_up` no shielded episode (escapes with the unseen-space
    test, the hybrid's planner) calls a kernel with argument types it has not loaded: the first
    act loads nothing."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-c", WARM_UP_CHECK], capture_output=True, text=True, check=True
    )
    assert done.stdout.strip().splitlines()[-1] == "added {}", done.stdout + done.stderr
