"""Scene: DH-consistent body tree, collision filtering, collision queries, path checking."""

import mujoco
import numpy as np
import pytest

from clamgen.robot import tip_pose, tip_position, ur5
from clamgen.sim import constants as C
from clamgen.sim.scene import Obstacles, Scene


@pytest.fixture(scope="module")
def scene():
    return Scene()


def box_at(position, half=0.04):
    return Obstacles(np.array([C.OBSTACLE_BOX]), np.array([position], float), np.full((1, 3), half))


def test_tip_site_matches_analytic_fk(scene):
    rng = np.random.default_rng(0)
    for joints in rng.uniform(-np.pi, np.pi, (50, 6)):
        scene.set_joints(joints)
        np.testing.assert_allclose(scene.tip_position(), tip_position(joints), atol=1e-9)
        rotation = scene.data.site_xmat[scene.tip_site].reshape(3, 3)
        np.testing.assert_allclose(rotation, tip_pose(joints)[:3, :3], atol=1e-9)


def test_home_pose_is_free_and_arm_through_table_collides(scene):
    scene.set_obstacles(Obstacles.empty())
    assert not scene.in_collision(ur5.HOME_JOINTS)
    # Shoulder lift of +pi/2 points the upper arm straight down through the table.
    assert scene.in_collision(np.array([np.pi, np.pi / 2, 0, 0, 0, 0]))


def test_obstacle_at_the_tip_collides_and_far_away_does_not(scene):
    tip = tip_position(ur5.HOME_JOINTS)
    scene.set_obstacles(box_at(tip))
    assert scene.in_collision(ur5.HOME_JOINTS)
    scene.set_obstacles(box_at(tip + np.array([0.0, 0.5, 0.0])))
    assert not scene.in_collision(ur5.HOME_JOINTS)
    scene.set_obstacles(Obstacles.empty())


def test_cylinder_obstacle_collides_by_its_own_shape(scene):
    tip = tip_position(ur5.HOME_JOINTS)
    # A thin tall cylinder beside the tip: its bounding box would touch, its shape does not.
    offset = np.array([0.0, 0.07, 0.0])
    cylinder = Obstacles(
        np.array([C.OBSTACLE_CYLINDER]), np.array([tip + offset]), np.array([[0.03, 0.03, 0.04]])
    )
    scene.set_obstacles(cylinder)
    free = not scene.in_collision(ur5.HOME_JOINTS)
    scene.set_obstacles(
        Obstacles(np.array([C.OBSTACLE_CYLINDER]), np.array([tip]), np.array([[0.03, 0.03, 0.04]]))
    )
    assert free and scene.in_collision(ur5.HOME_JOINTS)
    scene.set_obstacles(Obstacles.empty())


def test_only_robot_environment_contacts_are_generated(scene):
    scene.set_obstacles(box_at(tip_position(ur5.HOME_JOINTS)))
    scene.in_collision(ur5.HOME_JOINTS)
    robot = set(scene.robot_geoms.tolist())
    for contact in scene.data.contact[: scene.data.ncon]:
        assert (contact.geom1 in robot) != (contact.geom2 in robot)
    scene.set_obstacles(Obstacles.empty())


def test_unused_obstacle_slots_neither_collide_nor_show(scene):
    scene.set_obstacles(Obstacles.empty())
    for box, cylinder in scene.obstacle_geoms:
        assert scene.model.geom_conaffinity[box] == 0 == scene.model.geom_conaffinity[cylinder]
        assert scene.model.geom_rgba[box, 3] == 0 == scene.model.geom_rgba[cylinder, 3]


def test_move_along_stops_before_contact(scene):
    start = ur5.HOME_JOINTS.copy()
    end = start + np.array([0.0, 0.6, 0.0, 0.0, 0.0, 0.0])
    # An obstacle where the tip ends: moving the shoulder lift drives the tip into it.
    scene.set_obstacles(box_at(tip_position(end), half=0.03))
    assert scene.in_collision(end) and not scene.in_collision(start)
    reached, collided = scene.move_along(start, end, resolution_rad=0.01)
    assert collided
    assert not scene.in_collision(reached)
    assert 0 < reached[1] - start[1] < 0.6
    # One more resolution step towards the obstacle collides: it stopped right before contact.
    assert scene.in_collision(reached + np.array([0.0, 0.011, 0, 0, 0, 0]))
    free_end, collided = scene.move_along(start, start - (end - start), resolution_rad=0.01)
    assert not collided
    np.testing.assert_allclose(free_end, start - (end - start))
    scene.set_obstacles(Obstacles.empty())


def test_collision_mask_is_batched_and_restores_the_arm(scene):
    scene.set_joints(ur5.HOME_JOINTS)
    joints = np.stack([ur5.HOME_JOINTS, [np.pi, np.pi / 2, 0, 0, 0, 0]])
    mask = scene.collision_mask(joints[None].repeat(3, axis=0))
    assert mask.shape == (3, 2)
    assert (mask == [False, True]).all()
    np.testing.assert_array_equal(scene.joints, ur5.HOME_JOINTS)


def test_obstacle_geometry_follows_the_requested_sizes(scene):
    obstacles = Obstacles(
        np.array([C.OBSTACLE_BOX, C.OBSTACLE_CYLINDER]),
        np.array([[0.5, 0.1, 0.1], [0.5, -0.1, 0.15]]),
        np.array([[0.03, 0.04, 0.045], [0.035, 0.035, 0.04]]),
    )
    scene.set_obstacles(obstacles)
    box_geom, cylinder_geom = scene.obstacle_geoms[0, 0], scene.obstacle_geoms[1, 1]
    np.testing.assert_allclose(scene.model.geom_size[box_geom], [0.03, 0.04, 0.045])
    np.testing.assert_allclose(scene.model.geom_size[cylinder_geom][:2], [0.035, 0.04])
    mujoco.mj_kinematics(scene.model, scene.data)
    np.testing.assert_allclose(scene.data.geom_xpos[box_geom], [0.5, 0.1, 0.1])
    assert obstacles.as_array().shape == (2, 8)
    scene.set_obstacles(Obstacles.empty())


def test_bad_scene_arguments_are_refused():
    with pytest.raises(ValueError, match="collision_margin_m"):
        Scene(collision_margin_m=-0.01)
    with pytest.raises(ValueError, match="at most"):
        Scene().set_obstacles(Obstacles(np.zeros(5, int), np.zeros((5, 3)), np.full((5, 3), 0.03)))
