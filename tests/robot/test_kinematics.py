"""Tests of clamgen.robot.kinematics: FK against an independent DH product, closed-form IK round
trips (generic and near-singular), wrapping/sorting, and reaching the workspace box."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays

from clamgen.robot import (
    DEFAULT_TOOL_ORIENTATIONS,
    IK_POSITION_TOL_M,
    IK_ROTATION_TOL_RAD,
    default_tool_orientations,
    flange_pose,
    forward_kinematics,
    inverse_kinematics,
    link_frames,
    rotation_error,
    solve_tip_position,
    tip_pose,
    tip_position,
    tip_to_flange,
    ur5,
    wrap_joints,
)
from clamgen.robot.kinematics import _LIMIT_SLACK_RAD, _wrist_singular_threshold

FAST = settings(max_examples=200, deadline=None)
FEW = settings(max_examples=60, deadline=None)

LOWER, UPPER = ur5.JOINT_LIMITS[:, 0], ur5.JOINT_LIMITS[:, 1]


# ------------------------------------------------------------------------------------------
# Independent reference: a plain per-joint product of elementary transforms.
# ------------------------------------------------------------------------------------------


def _rz(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)


def _rx(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=float)


def _trans(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def reference_frames(q: np.ndarray) -> list[np.ndarray]:
    """DH frames 1..6 and the tip for one configuration, by the textbook product."""
    pose = np.eye(4)
    frames = []
    for i in range(6):
        pose = (
            pose
            @ _rz(q[i])
            @ _trans(0, 0, ur5.DH_D[i])
            @ _trans(ur5.DH_A[i], 0, 0)
            @ _rx(ur5.DH_ALPHA[i])
        )
        frames.append(pose)
    frames.append(pose @ _trans(0, 0, ur5.GRIPPER_TIP_OFFSET_M))
    return frames


def angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.mod(np.asarray(a) - np.asarray(b) + np.pi, 2 * np.pi) - np.pi


def min_joint_gap(solutions: np.ndarray, q: np.ndarray) -> float:
    """Smallest max-abs distance (modulo 2 pi) from q to any solution; inf if none."""
    if len(solutions) == 0:
        return np.inf
    return float(np.min(np.max(np.abs(angle_diff(solutions, q)), axis=1)))


def joint_accuracy(q: np.ndarray, wrist_from_reference: bool = False) -> float:
    """How closely (radians, max-abs) a tip pose pins down the joints ``q`` that produced it.

    The pose is only known to ~1e-16, and the closed form amplifies that near singularities:
    a double root (shoulder at r = d4, elbow at full stretch or fully folded) turns an error e
    of its cosine argument into ~sqrt(2 e), and a near-singular wrist knows q6 only to
    ~1e-16 / |sin q5|, which moves frame 4 by d5 times that. This estimate (times a safety
    factor) is what the round-trip tests demand; it is 1e-6 away from singularities.
    ``wrist_from_reference``: q6 is taken from the reference where the solver deems the wrist
    singular.
    """
    eps = 1e-16
    d4, d5 = ur5.DH_D[3], ur5.DH_D[4]
    wrist = forward_kinematics(q)[4, :3, 3]
    margin = max(np.hypot(wrist[0], wrist[1]) - d4, 0.0)
    q1_err = eps / max(np.sqrt(2.0 * margin / d4), np.sqrt(eps))
    s5 = abs(np.sin(q[4]))
    if wrist_from_reference and s5 < _wrist_singular_threshold(d4 / (d4 + margin)):
        q6_err = 0.0
    else:
        q6_err = min((eps + q1_err) / max(s5, 1e-300), np.pi)
    frame4_err = eps + d5 * q6_err + 0.9 * q1_err  # metres
    c3_err = 5.0 * frame4_err  # d(cos q3) / d(reach) = reach / (a2 a3) <= 5 per metre
    q3_err = c3_err / max(abs(np.sin(q[2])), np.sqrt(2.0 * c3_err))
    return 1e-6 + 100.0 * (q1_err + q6_err + q3_err)


def assert_solutions_reach(solutions: np.ndarray, target: np.ndarray) -> None:
    assert solutions.ndim == 2 and solutions.shape[1] == 6
    assert np.all(np.isfinite(solutions))
    reached = tip_pose(solutions)
    pos_err = np.linalg.norm(reached[:, :3, 3] - target[:3, 3], axis=-1)
    rot_err = rotation_error(reached[:, :3, :3], target[:3, :3])
    assert np.all(pos_err < IK_POSITION_TOL_M), pos_err
    assert np.all(rot_err < IK_ROTATION_TOL_RAD), rot_err
    assert np.all(solutions >= LOWER - 1e-12) and np.all(solutions <= UPPER + 1e-12)


def assert_no_duplicates(solutions: np.ndarray) -> None:
    gaps = np.max(np.abs(angle_diff(solutions[:, None], solutions[None])), axis=-1)
    assert np.all(gaps[np.triu_indices(len(solutions), k=1)] > 1e-7)


angle = st.floats(-np.pi, np.pi, allow_nan=False)
joints_within_limits = st.tuples(*[st.floats(lo, hi) for lo, hi in ur5.JOINT_LIMITS]).map(np.array)


# ------------------------------------------------------------------------------------------
# Forward kinematics
# ------------------------------------------------------------------------------------------


@FAST
@given(joints_within_limits)
def test_fk_matches_reference_dh_product(q: np.ndarray) -> None:
    frames = forward_kinematics(q)
    assert frames.shape == (7, 4, 4)
    np.testing.assert_allclose(frames, np.stack(reference_frames(q)), atol=1e-12)


def test_fk_zero_configuration_known_values() -> None:
    d1, d4, d5, d6 = ur5.DH_D[[0, 3, 4, 5]]
    a2, a3 = ur5.DH_A[1], ur5.DH_A[2]
    flange = flange_pose(np.zeros(6))
    # At q = 0 the UR arm lies stretched along -x of the DH base frame.
    np.testing.assert_allclose(flange[:3, 3], [a2 + a3, -(d4 + d6), d1 - d5], atol=1e-12)
    np.testing.assert_allclose(flange[:3, 3], [-0.81725, -0.19145, -0.005491], atol=1e-12)
    # Flange z axis points along -y there, so the tip is 10 cm further along -y.
    np.testing.assert_allclose(flange[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(tip_position(np.zeros(6)), [-0.81725, -0.29145, -0.005491])


def test_home_is_elbow_up_tool_down_above_workspace() -> None:
    home = ur5.HOME_JOINTS
    assert np.all(home >= LOWER) and np.all(home <= UPPER)
    tip = tip_pose(home)
    np.testing.assert_allclose(tip[:3, 3], [0.6, 0.0, 0.5], atol=1e-5)
    np.testing.assert_allclose(tip[:3, 2], [0.0, 0.0, -1.0], atol=1e-5)
    frames = link_frames(home)
    shoulder, elbow, wrist = frames[1, :3, 3], frames[2, :3, 3], frames[4, :3, 3]
    # Elbow up: the elbow lies above the straight shoulder-wrist line.
    s = np.linalg.norm(elbow[:2] - shoulder[:2]) / np.linalg.norm(wrist[:2] - shoulder[:2])
    assert elbow[2] > shoulder[2] + s * (wrist[2] - shoulder[2]) + 0.1
    # The home pose is one of its own IK solutions, and the nearest one to itself.
    sols = inverse_kinematics(tip, reference_joints=home)
    np.testing.assert_allclose(sols[0], home, atol=1e-9)


@FEW
@given(arrays(float, array_shapes(min_dims=0, max_dims=3, max_side=4), elements=angle))
def test_fk_batches_any_leading_shape(batch: np.ndarray) -> None:
    lead = batch.shape
    q = np.resize(batch, (*lead, 6)) if batch.size else np.zeros((*lead, 6))
    frames = forward_kinematics(q)
    assert frames.shape == (*lead, 7, 4, 4)
    assert flange_pose(q).shape == (*lead, 4, 4)
    assert tip_pose(q).shape == (*lead, 4, 4)
    assert tip_position(q).shape == (*lead, 3)
    assert link_frames(q).shape == (*lead, 7, 4, 4)
    flat = q.reshape(-1, 6)
    one_by_one = np.stack([forward_kinematics(x) for x in flat]) if len(flat) else frames
    np.testing.assert_allclose(frames.reshape(-1, 7, 4, 4), one_by_one.reshape(-1, 7, 4, 4))


def test_fk_rejects_wrong_shape() -> None:
    with pytest.raises(ValueError):
        forward_kinematics(np.zeros(5))
    with pytest.raises(ValueError):
        forward_kinematics(np.zeros((3, 7)))


def test_link_frames_start_at_base() -> None:
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (3, 6))
    frames = link_frames(q)
    np.testing.assert_allclose(frames[:, 0], np.broadcast_to(np.eye(4), (3, 4, 4)))
    np.testing.assert_allclose(frames[:, 1:], forward_kinematics(q)[:, :6])


# ------------------------------------------------------------------------------------------
# Inverse kinematics: generic round trips
# ------------------------------------------------------------------------------------------


@FAST
@given(st.tuples(*[angle] * 6).map(np.array))
def test_ik_round_trip_contains_original(q: np.ndarray) -> None:
    target = tip_pose(q)
    sols = inverse_kinematics(target)
    assert 1 <= len(sols) <= 8
    assert_solutions_reach(sols, target)
    assert_no_duplicates(sols)
    # Without a reference the angles are wrapped to (-pi, pi].
    assert np.all(sols > -np.pi) and np.all(sols <= np.pi)
    if abs(np.sin(q[4])) > 1e-9:
        assert min_joint_gap(sols, q) < joint_accuracy(q)
    # else: the wrist is (numerically) singular, q6 is free and chosen by the solver; the
    # singular tests below recover the original by passing it as the reference.


@FAST
@given(joints_within_limits)
# A joint exactly at its limit next to a near-singular wrist: q6 came back 1e-8 beyond the
# limit and was moved a full turn away instead of being clipped.
@example(np.array([0.0, 0.0, 0.0, 2.0, 1e-9, -2 * np.pi]))
def test_ik_with_reference_returns_it_first_and_sorted(q: np.ndarray) -> None:
    target = tip_pose(q)
    sols = inverse_kinematics(target, reference_joints=q)
    assert_solutions_reach(sols, target)
    # The original is a solution and, being at distance 0, comes first (same 2 pi copies).
    np.testing.assert_allclose(sols[0], q, atol=joint_accuracy(q, wrist_from_reference=True))
    dist = np.max(np.abs(sols - q), axis=1)
    assert np.all(np.diff(dist) >= -1e-12)


def test_ik_returns_eight_solutions_for_a_generic_pose() -> None:
    q = np.array([0.3, -1.1, 1.3, -0.7, 0.9, 0.4])
    sols = inverse_kinematics(tip_pose(q))
    assert sols.shape == (8, 6)
    assert_solutions_reach(sols, tip_pose(q))
    assert_no_duplicates(sols)


def test_ik_rejects_wrong_shapes() -> None:
    with pytest.raises(ValueError):
        inverse_kinematics(np.eye(3))
    with pytest.raises(ValueError):
        inverse_kinematics(np.eye(4), reference_joints=np.zeros(5))


# ------------------------------------------------------------------------------------------
# Inverse kinematics: near-singular and unreachable poses
# ------------------------------------------------------------------------------------------

small_offset = st.one_of(
    st.just(0.0),
    st.floats(-7.0, -3.0).map(lambda e: 10.0**e),
    st.floats(-7.0, -3.0).map(lambda e: -(10.0**e)),
)


def _check_near_singular(q: np.ndarray) -> None:
    """Round trip with and without reference; no NaNs, every solution reaches the pose."""
    target = tip_pose(q)
    sols = inverse_kinematics(target)
    assert len(sols) >= 1
    assert_solutions_reach(sols, target)
    assert_no_duplicates(sols)
    near = inverse_kinematics(target, reference_joints=q)
    assert_solutions_reach(near, target)
    # With the original as reference it is recovered even at an exact singularity (q6 free:
    # the reference value is used), up to the accuracy the pose allows.
    np.testing.assert_allclose(near[0], q, atol=joint_accuracy(q, wrist_from_reference=True))


@FAST
@given(
    st.tuples(*[angle] * 6).map(np.array),
    st.sampled_from([0.0, np.pi, -np.pi]),
    small_offset,
)
def test_ik_near_wrist_singularity(q: np.ndarray, base: float, offset: float) -> None:
    q = q.copy()
    q[4] = base + offset
    _check_near_singular(q)
    if abs(offset) >= 1e-7:
        # Not exactly singular: q6 is still determined by the pose.
        assert min_joint_gap(inverse_kinematics(tip_pose(q)), q) < joint_accuracy(q)


@FAST
@given(
    st.tuples(*[angle] * 6).map(np.array),
    st.sampled_from([0.0, np.pi, -np.pi]),
    small_offset,
    small_offset,
)
def test_ik_near_elbow_singularity(
    q: np.ndarray, base: float, offset: float, wrist_offset: float
) -> None:
    # q3 = 0: full stretch; q3 = +-pi: fully folded (reachable since |a2| != |a3|). Combine
    # with a wrist that is sometimes singular too.
    q = q.copy()
    q[2] = np.clip(base + offset, -np.pi, np.pi)
    if wrist_offset != 0.0:
        q[4] = wrist_offset
    _check_near_singular(q)


def _shoulder_singular_joints(q: np.ndarray, side: float, offset: float) -> np.ndarray:
    """Set q2 so that the wrist center lies (almost) in the plane of the base and shoulder axes.

    In frame 1 the wrist center's x coordinate is its horizontal reach beyond the shoulder
    offset; it is a rotation by q2 of a vector fixed by q3, q4, so q2 can zero it.
    """
    q = q.copy()
    q[1] = 0.0
    frames = link_frames(q)
    wrist_in_1 = np.linalg.solve(frames[1], frames[5][:, 3])
    psi = np.arctan2(wrist_in_1[1], wrist_in_1[0])
    q[1] = side * np.pi / 2 - psi + offset
    return q


@FAST
@given(
    st.tuples(*[angle] * 6).map(np.array),
    st.sampled_from([1.0, -1.0]),
    small_offset,
)
def test_ik_near_shoulder_singularity(q: np.ndarray, side: float, offset: float) -> None:
    q = _shoulder_singular_joints(q, side, offset)
    wrist = link_frames(q)[:, :3, 3][5]
    reach_beyond_offset = np.hypot(wrist[0], wrist[1]) - ur5.DH_D[3]
    assert reach_beyond_offset < 1e-5  # really near the singular surface r = d4
    _check_near_singular(q)


def test_ik_exact_singularities_give_finite_single_branches() -> None:
    # Wrist and elbow exactly singular at once: q5 = 0, q3 = 0.
    q = np.array([0.4, -0.9, 0.0, -1.2, 0.0, 0.7])
    sols = inverse_kinematics(tip_pose(q))
    assert_solutions_reach(sols, tip_pose(q))
    assert_no_duplicates(sols)
    # The coinciding branches (elbow +-0, wrist +-0) collapse to one per shoulder branch.
    assert 1 <= len(sols) <= 4
    # q6 is free here; at full stretch only the original q6 keeps frame 4 in reach, so the
    # solver moves its default (0) there, and a reference picks the original exactly.
    assert min_joint_gap(sols, q) < 1e-6
    np.testing.assert_allclose(inverse_kinematics(tip_pose(q), q)[0], q, atol=1e-9)
    # The UR "straight up" pose: shoulder, elbow and wrist singular all at once.
    up = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])
    sols = inverse_kinematics(tip_pose(up), reference_joints=up)
    assert_solutions_reach(sols, tip_pose(up))
    np.testing.assert_allclose(sols[0], up, atol=1e-6)


def test_ik_unreachable_poses_give_empty() -> None:
    far = np.eye(4)
    far[:3, 3] = (2.0, 0.0, 0.5)
    assert inverse_kinematics(far).shape == (0, 6)
    # Wrist center on the base axis: inside the d4 shoulder offset cylinder, out of reach.
    down = np.diag([1.0, -1.0, -1.0, 1.0])
    down[:3, 3] = (0.0, 0.0, 0.4)
    assert inverse_kinematics(down).shape == (0, 6)
    nan_pose = np.full((4, 4), np.nan)
    assert inverse_kinematics(nan_pose).shape == (0, 6)


def test_ik_drops_the_branch_pushed_beyond_full_stretch() -> None:
    q = np.array([0.2, -0.5, 0.0, 0.3, 0.8, 0.1])  # elbow at full stretch
    target = tip_pose(q)
    assert min_joint_gap(inverse_kinematics(target), q) < 1e-6
    # Move the pose 1 mm further out along the stretched arm (frame 2 to frame 4 origin): the
    # stretched branch can no longer reach it, while the other branches still do.
    frames = forward_kinematics(q)
    direction = frames[3, :3, 3] - frames[1, :3, 3]
    pushed = target.copy()
    pushed[:3, 3] += 1e-3 * direction / np.linalg.norm(direction)
    sols = inverse_kinematics(pushed)
    assert_solutions_reach(sols, pushed)
    assert min_joint_gap(sols, q) > 1e-2


# ------------------------------------------------------------------------------------------
# Wrapping
# ------------------------------------------------------------------------------------------


@FAST
@given(
    st.tuples(*[st.floats(-20.0, 20.0)] * 6).map(np.array),
    st.tuples(*[st.floats(-7.0, 7.0)] * 6).map(np.array),
)
def test_wrap_joints(q: np.ndarray, ref: np.ndarray) -> None:
    free = wrap_joints(q)
    assert np.all(free > -np.pi) and np.all(free <= np.pi)
    assert np.allclose(angle_diff(free, q), 0.0, atol=1e-9)
    near = wrap_joints(q, ref)
    # A copy beyond a limit by less than the slack (rounding) is clipped to the limit.
    assert np.allclose(angle_diff(near, q), 0.0, atol=_LIMIT_SLACK_RAD)
    assert np.all(near >= LOWER - 1e-9) and np.all(near <= UPPER + 1e-9)
    # No other admissible copy is nearer to the reference.
    for shift in (-2 * np.pi, 2 * np.pi):
        other = near + shift
        admissible = (other >= LOWER) & (other <= UPPER)
        gap = np.abs(other - ref) - np.abs(near - ref)
        assert np.all(gap[admissible] >= -_LIMIT_SLACK_RAD)


# ------------------------------------------------------------------------------------------
# Reaching points of the workspace
# ------------------------------------------------------------------------------------------


def test_default_tool_orientations_are_rotations() -> None:
    rots = default_tool_orientations()
    assert rots.shape == (68, 3, 3)
    np.testing.assert_allclose(DEFAULT_TOOL_ORIENTATIONS, rots)
    eye = np.broadcast_to(np.eye(3), rots.shape)
    np.testing.assert_allclose(np.swapaxes(rots, 1, 2) @ rots, eye, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rots), 1.0)
    np.testing.assert_allclose(rots[0, :, 2], [0.0, 0.0, -1.0])
    # Every approach direction points downwards, at most 60 degrees off vertical.
    assert np.all(rots[:, 2, 2] <= -np.cos(np.deg2rad(60.0)) + 1e-12)


def test_solve_tip_position_reaches_workspace_box() -> None:
    rng = np.random.default_rng(1234)
    points = rng.uniform([0.3, -0.2, 0.0], [0.7, 0.2, 0.4], size=(40, 3))
    hits = 0
    for point in points:
        sols = solve_tip_position(point, reference_joints=ur5.HOME_JOINTS)
        if len(sols) == 0:
            continue
        hits += 1
        assert np.all(np.isfinite(sols))
        err = np.linalg.norm(tip_position(sols) - point, axis=-1)
        assert np.all(err < IK_POSITION_TOL_M)
        assert np.all(sols >= LOWER) and np.all(sols <= UPPER)
        assert_no_duplicates(sols)
        dist = np.max(np.abs(sols - ur5.HOME_JOINTS), axis=1)
        assert np.all(np.diff(dist) >= -1e-12)
    assert hits >= 0.9 * len(points)


def test_solve_tip_position_home_point_prefers_home() -> None:
    home_tip = tip_position(ur5.HOME_JOINTS)
    sols = solve_tip_position(home_tip, reference_joints=ur5.HOME_JOINTS)
    # Home points the tool straight down, which is in the default set; only its yaw (q6) is
    # not on the 90 degree yaw grid, so the nearest solution matches home but for q6.
    assert np.max(np.abs(sols[0][:5] - ur5.HOME_JOINTS[:5])) < 1e-5
    assert abs(sols[0][5] - ur5.HOME_JOINTS[5]) <= np.pi / 4


def test_solve_tip_position_custom_orientation_and_unreachable() -> None:
    q = np.array([2.5, -1.0, 1.2, -1.5, -1.4, 0.3])
    target = tip_pose(q)
    sols = solve_tip_position(target[:3, 3], orientations=target[None, :3, :3])
    assert min_joint_gap(sols, q) < 1e-6
    np.testing.assert_allclose(tip_to_flange(target)[:3, 3], flange_pose(q)[:3, 3], atol=1e-12)
    assert solve_tip_position(np.array([3.0, 0.0, 0.0])).shape == (0, 6)
    with pytest.raises(ValueError):
        solve_tip_position(np.zeros(2))
