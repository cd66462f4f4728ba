"""`clamgen export-scene`: a task's MJCF that MuJoCo loads with obstacles in place, the start
pose as a keyframe and the arm held still when simulated."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from clamgen import cli
from clamgen.sim import constants as C
from clamgen.sim.scene import START_KEY, task_mjcf


def task_of(env_id: str, seed: int):
    env = gym.make(env_id).unwrapped
    env.reset(seed=seed)
    return env.task, env.scene


def body_id(model, name: str) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)


@pytest.mark.parametrize("seed", [3, 1_000_000_000])
def test_exported_file_has_the_tasks_obstacles_target_and_start_key(tmp_path, seed):
    out = tmp_path / "task.xml"
    cli.main(["export-scene", "--seed", str(seed), "--out", str(out)])
    task, scene = task_of("CLAMGen/ReachObstacles-v0", seed)
    model = mujoco.MjModel.from_xml_path(str(out))
    data = mujoco.MjData(model)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, START_KEY)
    assert key == 0 and model.nkey == 1
    # MJCF holds numbers to 6 significant digits: 1e-5 rad, 1e-5 m.
    np.testing.assert_allclose(model.key_qpos[key], task.start_joints, atol=1e-5)
    mujoco.mj_resetDataKeyframe(model, data, key)
    mujoco.mj_forward(model, data)

    assert len(task.obstacles) == 2
    for slot in range(C.MAX_OBSTACLES):
        present = body_id(model, f"obstacle{slot}") >= 0
        assert present == (slot < len(task.obstacles))  # no slots parked below the table
    for slot, kind in enumerate(task.obstacles.kinds):
        body = body_id(model, f"obstacle{slot}")
        np.testing.assert_allclose(data.xpos[body], task.obstacles.positions_m[slot], atol=1e-5)
        (geom,) = np.flatnonzero(model.geom_bodyid == body)
        half = task.obstacles.half_sizes_m[slot]
        if kind == C.OBSTACLE_BOX:
            assert model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_BOX
            np.testing.assert_allclose(model.geom_size[geom], half, atol=1e-6)
        else:
            assert model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_CYLINDER
            np.testing.assert_allclose(model.geom_size[geom][:2], half[[0, 2]], atol=1e-6)
        # The same obstacle as the env's own (compiled-slot) scene places.
        env_geom = scene.obstacle_geoms[slot][kind]
        np.testing.assert_allclose(data.geom_xpos[geom], scene.data.geom_xpos[env_geom], atol=1e-5)
    np.testing.assert_allclose(
        data.xpos[body_id(model, "target")], task.target_position_m, atol=1e-5
    )
    tip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tip")
    np.testing.assert_allclose(data.site_xpos[tip], scene.tip_position(), atol=3e-5)
    assert not data.ncon  # the start pose is collision-free, as the task promises

    # Simulated for 2 s (what the viewer does), the arm stays at the start pose.
    while data.time < 2.0:
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(data.qpos, model.key_qpos[key], atol=1e-4)


def test_a_reach_task_exports_without_obstacles():
    task, _ = task_of("CLAMGen/Reach-v0", 5)
    model = mujoco.MjModel.from_xml_string(
        task_mjcf(task.start_joints, task.target_position_m, task.obstacles)
    )
    assert model.nmocap == 1 and body_id(model, "obstacle0") == -1
    assert model.nu == 6 and model.opt.timestep == pytest.approx(0.002)


def test_bad_input_is_refused():
    with pytest.raises(SystemExit, match="--seed must be >= 0"):
        cli.main(["export-scene", "--seed", "-1"])
    with pytest.raises(ValueError, match="start_joints must have shape"):
        task_mjcf(np.zeros(5), np.zeros(3), task_of("CLAMGen/Reach-v0", 0)[0].obstacles)
