"""Batched forward kinematics and closed-form inverse kinematics of the UR5.

Conventions (see :mod:`clamgen.robot.ur5`):

* Lengths in metres, angles in radians.
* Standard DH: ``A_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` and ``T_0i = A_1 ... A_i``.
* Every pose is a 4x4 homogeneous transform expressed in the DH base frame (frame 0, which is
  also the world frame of every scene). Frame 6 is the tool flange; the *tip* frame is the flange
  translated by ``GRIPPER_TIP_OFFSET_M`` along the flange z axis (same orientation).

The inverse kinematics follows the analytic derivation of Hawkins 2013, "Analytic Inverse
Kinematics for the Universal Robots UR-5/UR-10 Arms": the shoulder angle from the circle of
wrist-center positions, the wrist-2 angle from how much of the flange z axis lies along the
shoulder axis, wrist 3 from the flange x/y axes, and finally a planar two-link problem for
joints 2, 3, 4, whose axes are all parallel. The code is written for this project; it solves a
batch of target poses at once so that searching over many tool orientations stays cheap.
"""

from __future__ import annotations

import numpy as np

from clamgen.robot.ur5 import (
    DH_A,
    DH_ALPHA,
    DH_D,
    GRIPPER_TIP_OFFSET_M,
    JOINT_LIMITS,
    NUM_JOINTS,
)

__all__ = [
    "DEFAULT_TOOL_ORIENTATIONS",
    "IK_POSITION_TOL_M",
    "IK_ROTATION_TOL_RAD",
    "default_tool_orientations",
    "flange_pose",
    "flange_to_tip",
    "forward_kinematics",
    "inverse_kinematics",
    "joint_distance",
    "link_frames",
    "rotation_error",
    "solve_tip_position",
    "tip_pose",
    "tip_position",
    "tip_to_flange",
    "wrap_joints",
]

# A returned IK solution must reproduce the requested pose this well (checked with FK).
IK_POSITION_TOL_M = 1e-5
IK_ROTATION_TOL_RAD = 1e-4

# Below this |sin q5| the wrist is treated as singular: joints 2, 3, 4 and 6 are then all
# parallel, so q6 cannot be read from the flange axes and is chosen instead (the planar
# sub-problem absorbs the choice, so the pose is still reached). Above it, q6 is computed from
# vectors of length |sin q5|, which keeps ~1e-16 / |sin q5| accuracy. See
# _wrist_singular_threshold for the larger value used near the shoulder singularity.
_WRIST_SINGULAR_EPS = 1e-10
# |cos q3| this close to 1 is the elbow at full stretch (or fully folded), up to rounding, and
# is snapped to +-1: arccos's slope is infinite there, so a rounding of a few 1e-16 in cos q3
# would become an elbow angle of 1e-8 rad, and which one depends on the machine's floating
# point. (Snapping changes q3 by at most sqrt(2 * 1e-14) = 1.4e-7 rad and the tip by ~1e-14 m.)
_ELBOW_STRETCH_EPS = 1e-14
# Two solutions closer than this (~L2, modulo 2 pi) are the same solution; this also merges
# the two coinciding branches at a singularity (elbow at full stretch, shoulder boundary).
_DUPLICATE_TOL_RAD = 1e-6

# A joint angle this far beyond a limit is taken as rounding and clipped to the limit (the
# FK check after it still applies). Near a singular wrist q6 is known only to ~1e-16 / |sin q5|
# (1e-7 at |sin q5| = 1e-9), so a joint exactly at its limit can come back that far beyond it.
_LIMIT_SLACK_RAD = 1e-6

_TWO_PI = 2.0 * np.pi


# --------------------------------------------------------------------------------------------
# Forward kinematics
# --------------------------------------------------------------------------------------------


def _dh_matrices(theta: np.ndarray, d, a, alpha) -> np.ndarray:
    """Standard DH link transform ``Rz(theta) Tz(d) Tx(a) Rx(alpha)``.

    Args:
        theta: joint angles, any shape ``S`` (radians).
        d, a, alpha: the link's DH constants (metres, metres, radians), or arrays of them
            that broadcast against ``theta`` (all six links at once: shape (6,) with theta
            (..., 6)).

    Returns:
        ``S + (4, 4)`` transforms of frame i expressed in frame i-1.
    """
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    out = np.zeros((*np.shape(theta), 4, 4))
    out[..., 0, 0] = ct
    out[..., 0, 1] = -st * ca
    out[..., 0, 2] = st * sa
    out[..., 0, 3] = a * ct
    out[..., 1, 0] = st
    out[..., 1, 1] = ct * ca
    out[..., 1, 2] = -ct * sa
    out[..., 1, 3] = a * st
    out[..., 2, 1] = sa
    out[..., 2, 2] = ca
    out[..., 2, 3] = d
    out[..., 3, 3] = 1.0
    return out


def _tip_offset_transform(offset_m: float) -> np.ndarray:
    """Pure translation by ``offset_m`` along z, shape (4, 4)."""
    t = np.eye(4)
    t[2, 3] = offset_m
    return t


_FLANGE_TO_TIP = _tip_offset_transform(GRIPPER_TIP_OFFSET_M)
_TIP_TO_FLANGE = _tip_offset_transform(-GRIPPER_TIP_OFFSET_M)


def _as_joints(joints: np.ndarray) -> np.ndarray:
    q = np.asarray(joints, dtype=float)
    if q.ndim < 1 or q.shape[-1] != NUM_JOINTS:
        raise ValueError(f"joints must have shape (..., {NUM_JOINTS}), got {q.shape}")
    return q


def forward_kinematics(joints: np.ndarray) -> np.ndarray:
    """Poses of DH frames 1..6 and of the gripper tip.

    Args:
        joints: joint angles, shape ``(..., 6)``, radians; any leading batch shape.

    Returns:
        Homogeneous transforms, shape ``(..., 7, 4, 4)``, all expressed in the DH base frame
        (frame 0): index ``i`` in 0..5 is DH frame ``i + 1`` (index 5 = frame 6 = tool flange),
        index 6 is the gripper tip frame (flange translated by ``GRIPPER_TIP_OFFSET_M`` along the
        flange z axis, same orientation).
    """
    q = _as_joints(joints)
    out = np.empty((*q.shape[:-1], NUM_JOINTS + 1, 4, 4))
    # Every link's transform in one vectorised call (the DH constants broadcast over the
    # joint axis), then the chain: a loop over the 6 joints, each product batched.
    links = _dh_matrices(q, DH_D, DH_A, DH_ALPHA)
    pose = links[..., 0, :, :]
    out[..., 0, :, :] = pose
    for i in range(1, NUM_JOINTS):
        pose = pose @ links[..., i, :, :]
        out[..., i, :, :] = pose
    out[..., NUM_JOINTS, :, :] = pose @ _FLANGE_TO_TIP
    return out


def link_frames(joints: np.ndarray) -> np.ndarray:
    """Base frame plus DH frames 1..6, handy for placing link geometry (capsules).

    Args:
        joints: shape ``(..., 6)``, radians.

    Returns:
        Shape ``(..., 7, 4, 4)`` in the DH base frame: index 0 is the identity (frame 0) and
        index ``i`` is DH frame ``i`` (index 6 = flange). Consecutive origins bound the links.
    """
    q = _as_joints(joints)
    frames = forward_kinematics(q)
    out = np.empty_like(frames)
    out[..., 0, :, :] = np.eye(4)
    out[..., 1:, :, :] = frames[..., :NUM_JOINTS, :, :]
    return out


def flange_pose(joints: np.ndarray) -> np.ndarray:
    """Tool-flange pose (DH frame 6) in the DH base frame, shape ``(..., 4, 4)``."""
    return forward_kinematics(joints)[..., NUM_JOINTS - 1, :, :]


def tip_pose(joints: np.ndarray) -> np.ndarray:
    """Gripper-tip pose in the DH base frame, shape ``(..., 4, 4)``; joints ``(..., 6)`` rad."""
    return forward_kinematics(joints)[..., NUM_JOINTS, :, :]


def tip_position(joints: np.ndarray) -> np.ndarray:
    """Gripper-tip position in the DH base frame, shape ``(..., 3)``, metres."""
    return tip_pose(joints)[..., :3, 3]


def tip_to_flange(tip: np.ndarray) -> np.ndarray:
    """Flange pose(s) ``(..., 4, 4)`` that put the tip at ``tip`` ``(..., 4, 4)`` (base frame)."""
    return np.asarray(tip, dtype=float) @ _TIP_TO_FLANGE


def flange_to_tip(flange: np.ndarray) -> np.ndarray:
    """Tip pose(s) ``(..., 4, 4)`` of flange pose(s) ``(..., 4, 4)`` (base frame)."""
    return np.asarray(flange, dtype=float) @ _FLANGE_TO_TIP


def rotation_error(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """Angle (radians) of the relative rotation ``r_a^T r_b``; inputs ``(..., 3, 3)``.

    Uses ``atan2(|sin|, cos)`` of the relative rotation, which stays accurate for tiny angles
    (``arccos`` of the trace does not).
    """
    rel = np.swapaxes(np.asarray(r_a), -1, -2) @ np.asarray(r_b)
    vee = np.stack(
        [
            rel[..., 2, 1] - rel[..., 1, 2],
            rel[..., 0, 2] - rel[..., 2, 0],
            rel[..., 1, 0] - rel[..., 0, 1],
        ],
        axis=-1,
    )
    sin_angle = 0.5 * np.linalg.norm(vee, axis=-1)
    cos_angle = 0.5 * (np.trace(rel, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(sin_angle, cos_angle)


# --------------------------------------------------------------------------------------------
# Joint-space helpers
# --------------------------------------------------------------------------------------------


def wrap_joints(joints: np.ndarray, reference_joints: np.ndarray | None = None) -> np.ndarray:
    """Pick, per joint, which 2 pi copy of an angle to use.

    Args:
        joints: shape ``(..., 6)``, radians.
        reference_joints: shape ``(6,)`` or broadcastable to ``joints``, radians, or ``None``.

    Returns:
        Shape ``(..., 6)``. Without a reference every angle is wrapped to ``(-pi, pi]`` (inside
        every UR5 limit). With a reference, each angle becomes the copy inside
        ``ur5.JOINT_LIMITS`` nearest to the reference angle; every limit range is at least
        2 pi wide, so such a copy always exists.
    """
    q = _as_joints(joints)
    if reference_joints is None:
        out = np.pi - np.mod(np.pi - q, _TWO_PI)
        # np.mod can round up to exactly 2 pi for tiny negative inputs, giving -pi.
        return np.where(out <= -np.pi, out + _TWO_PI, out)
    ref = np.asarray(reference_joints, dtype=float)
    out = q + _TWO_PI * np.round((ref - q) / _TWO_PI)
    lo, hi = JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1]
    # The nearest copy can fall outside the limits when the reference sits near a limit (or
    # outside it); the first copy back inside is then the nearest admissible one. A copy
    # beyond a limit by mere rounding (a joint exactly at its limit) is clipped instead.
    above = np.maximum(out - hi - _LIMIT_SLACK_RAD, 0.0)
    below = np.maximum(lo - _LIMIT_SLACK_RAD - out, 0.0)
    out = out - _TWO_PI * np.ceil(above / _TWO_PI) + _TWO_PI * np.ceil(below / _TWO_PI)
    return np.clip(out, lo, hi)


def joint_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Max-abs joint difference (radians) of ``(..., 6)`` arrays, not taken modulo 2 pi.

    Every UR5 joint has the same speed limit, so this is proportional to the shortest time a
    joint-space move between the two configurations needs.
    """
    return np.max(np.abs(np.asarray(a, dtype=float) - np.asarray(b, dtype=float)), axis=-1)


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b`` wrapped to ``[-pi, pi)``, elementwise."""
    return np.mod(a - b + np.pi, _TWO_PI) - np.pi


def _unique_rows(q: np.ndarray, tol: float) -> np.ndarray:
    """Boolean mask keeping the first of every group of solutions equal modulo 2 pi.

    ``q`` has shape ``(n, 6)``. Two rows count as equal when their chord distance
    ``sqrt(sum_i (2 sin(dq_i / 2))^2)`` (about the L2 distance modulo 2 pi) is below ``tol``.
    The chord form turns the n x n comparison into one small matrix product, which matters for
    the hundreds of candidates of :func:`solve_tip_position`.
    """
    if len(q) == 0:
        return np.zeros(0, dtype=bool)
    emb = np.concatenate([np.cos(q), np.sin(q)], axis=-1)
    # sum_i (2 sin(dq_i / 2))^2 = 2 sum_i (1 - cos dq_i) = 2 (6 - <emb_a, emb_b>).
    chord_sq = 2.0 * (q.shape[-1] - emb @ emb.T)
    earlier_duplicate = np.tril(chord_sq < tol * tol, k=-1)
    return ~np.any(earlier_duplicate, axis=1)


def _sort_by_reference(q: np.ndarray, reference: np.ndarray | None) -> np.ndarray:
    """Sort ``(n, 6)`` solutions by max-abs, then L2, distance to ``reference``."""
    if reference is None or len(q) == 0:
        return q
    delta = q - reference
    order = np.lexsort((np.linalg.norm(delta, axis=-1), np.max(np.abs(delta), axis=-1)))
    return q[order]


def _check_reference(reference_joints: np.ndarray | None) -> np.ndarray | None:
    if reference_joints is None:
        return None
    ref = np.asarray(reference_joints, dtype=float)
    if ref.shape != (NUM_JOINTS,):
        raise ValueError(f"reference_joints must have shape ({NUM_JOINTS},), got {ref.shape}")
    return ref


# --------------------------------------------------------------------------------------------
# Inverse kinematics
# --------------------------------------------------------------------------------------------


def _rigid_inverse(t: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    rot_t = np.swapaxes(t[..., :3, :3], -1, -2)
    out = np.zeros_like(t)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -(rot_t @ t[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def _frame4_in_frame1(
    t01_inv: np.ndarray, flange: np.ndarray, q5: np.ndarray, q6: np.ndarray
) -> np.ndarray:
    """``T14 = T01^-1 T06 (T45 T56)^-1`` for the (m, 2, 2) shoulder x wrist branches."""
    t45 = _dh_matrices(q5, DH_D[4], DH_A[4], DH_ALPHA[4])
    t56 = _dh_matrices(q6, DH_D[5], DH_A[5], DH_ALPHA[5])
    return t01_inv @ flange[:, None, None] @ _rigid_inverse(t45 @ t56)


def _wrist_singular_threshold(shoulder_ratio: np.ndarray) -> np.ndarray:
    """|sin q5| below which the wrist counts as singular, given ``d4 / r`` of the shoulder.

    q1 = phi + pi/2 +- acos(d4 / r) inherits an error of ~1e-16 / sqrt(1 - (d4/r)^2) from the
    rounding of the pose, up to ~1e-8 where the two shoulder branches meet (r = d4). That error
    tilts the computed shoulder axis and shows up as a spurious |sin q5| of the same size, from
    which q6 would be read as noise; below this threshold q6 is chosen instead.
    """
    spread = np.sqrt(np.clip(1.0 - np.square(shoulder_ratio), 0.0, 1.0))
    return _WRIST_SINGULAR_EPS + 1e-14 / np.maximum(spread, 1e-7)


def _q6_shift_into_reach(wrist: np.ndarray, frame4: np.ndarray, c5: np.ndarray) -> np.ndarray:
    """Smallest change of q6 that brings frame 4's origin within the elbow's reach.

    Args:
        wrist: wrist center (frame 5 origin), x-y in frame 1, shape (m, 2, 2, 2) metres.
        frame4: frame 4 origin for the current q6, x-y in frame 1, same shape.
        c5: cos q5 = +-1 per (m, 2) shoulder branch.

    Returns:
        q6 increments, shape (m, 2, 2), radians; 0 where the current q6 already works or where
        nothing works (the elbow test then rejects the branch).

    Exact at s5 = 0 (a first-order model near it): the flange z axis is then c5 z1, and raising
    q6 by delta with the flange held fixed turns frame 5, and with it the offset
    v = frame4 - wrist (length d5), by -c5 delta about z1.
    Frame 4 is reachable when |wrist + v| lies in [|a2| - |a3|, |a2| + |a3|], i.e. when the
    angle beta between v and the wrist direction satisfies cos(beta) in [lo, hi].
    """
    reach_min = abs(abs(DH_A[1]) - abs(DH_A[2]))
    reach_max = abs(DH_A[1]) + abs(DH_A[2])
    v = frame4 - wrist
    wrist_norm = np.linalg.norm(wrist, axis=-1)
    v_norm = np.linalg.norm(v, axis=-1)
    denom = np.maximum(2.0 * wrist_norm * v_norm, 1e-300)
    base = wrist_norm**2 + v_norm**2
    cos_hi = (reach_max**2 - base) / denom
    cos_lo = (reach_min**2 - base) / denom
    feasible = (cos_hi >= -1.0) & (cos_lo <= 1.0) & (wrist_norm > 1e-12)
    beta_min = np.arccos(np.clip(cos_hi, -1.0, 1.0))
    beta_max = np.arccos(np.clip(cos_lo, -1.0, 1.0))
    beta = _angle_diff(np.arctan2(v[..., 1], v[..., 0]), np.arctan2(wrist[..., 1], wrist[..., 0]))
    side = np.where(beta < 0.0, -1.0, 1.0)
    beta_new = side * np.clip(np.abs(beta), beta_min, beta_max)
    shift = -c5[..., None] * (beta_new - beta)
    return np.where(feasible, shift, 0.0)


def _ik_branches(
    flange: np.ndarray, q6_if_singular: float, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """All 8 closed-form branches for a batch of flange poses (Hawkins 2013).

    Args:
        flange: target flange poses in the DH base frame, shape ``(m, 4, 4)``.
        q6_if_singular: q6 (radians) used where the wrist is singular (sin q5 ~ 0).
        tol: slack on the cosine arguments: values up to ``1 + tol`` are clipped to 1 (full
            stretch / shoulder boundary); beyond that the branch is unreachable.

    Returns:
        ``(q, ok)``: joint angles ``(m, 8, 6)`` in radians, unwrapped, and a mask ``(m, 8)`` of
        the branches that passed the reachability tests (not yet FK-verified). Branch index is
        ``4 * shoulder + 2 * wrist + elbow``. Invalid branches hold finite dummy values.
    """
    d1, d4, d6 = DH_D[0], DH_D[3], DH_D[5]
    a2, a3 = DH_A[1], DH_A[2]
    m = flange.shape[0]
    rot = flange[:, :3, :3]
    z6 = rot[:, :, 2]
    p6 = flange[:, :3, 3]

    # --- Shoulder (q1). The wrist center p5 (origin of frame 5) lies d6 behind the flange.
    # The shoulder axis z1 = (sin q1, -cos q1, 0) is horizontal, and along z1 the chain up to
    # frame 5 only advances by d4 (d2 = d3 = 0, and d5 runs along z4, which is perpendicular to
    # z1), so p5 . z1 = d4. With p5 = r (cos phi, sin phi) in the plane this gives
    # sin(q1 - phi) = d4 / r: two shoulder branches q1 = phi + pi/2 +- acos(d4 / r).
    # r = d4 is the shoulder singularity (wrist center in the plane of the base axis and the
    # shoulder axis): the branches merge and acos is clipped. Because d4 > 0 the wrist center can
    # never reach the base axis itself (r < d4 is unreachable), so q1 is never free for a UR5.
    p5 = p6 - d6 * z6
    r = np.hypot(p5[:, 0], p5[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(r > 0.0, d4 / np.where(r > 0.0, r, 1.0), np.inf)
    ok_shoulder = ratio <= 1.0 + tol
    phi = np.arctan2(p5[:, 1], p5[:, 0])
    spread = np.arccos(np.clip(ratio, -1.0, 1.0))
    q1 = phi[:, None] + 0.5 * np.pi + np.stack([spread, -spread], axis=1)  # (m, 2)

    # --- Wrist 2 (q5). The flange z axis z6 makes angle q5 with the shoulder axis z1, and
    # z1 seen from the flange is w = R06^T z1 = (s5 c6, -s5 s6, c5) (product of the wrist DH
    # rotations). Hawkins takes c5 = (p6 . z1 - d4) / d6 and acos; reading s5 = +-|w_xy| and
    # c5 = w_z with atan2 is equivalent but well conditioned near sin q5 = 0.
    z1 = np.stack([np.sin(q1), -np.cos(q1), np.zeros_like(q1)], axis=-1)  # (m, 2, 3)
    w = np.einsum("mji,mbj->mbi", rot, z1)  # (m, 2, 3): z1 in flange coordinates
    s5_abs = np.hypot(w[..., 0], w[..., 1])
    sign5 = np.array([1.0, -1.0])
    q5 = np.arctan2(sign5 * s5_abs[..., None], w[..., 2][..., None])  # (m, 2, 2)

    # --- Wrist 3 (q6) from w_x = s5 c6, w_y = -s5 s6.
    q6 = np.arctan2(-sign5 * w[..., 1][..., None], sign5 * w[..., 0][..., None])
    threshold = _wrist_singular_threshold(ratio)[:, None, None]
    singular = np.broadcast_to(s5_abs[..., None] < threshold, q5.shape)
    q6 = np.where(singular, q6_if_singular, q6)

    # --- Planar problem for joints 2, 3, 4 (parallel axes). Strip the known transforms:
    # T14 = T01^-1 T06 (T45 T56)^-1; its origin (x, y) in frame 1 is reached by two links of
    # lengths a2, a3, and its x axis has angle q2 + q3 + q4 about z1.
    q1_b = np.broadcast_to(q1[:, :, None], (m, 2, 2))
    t01_inv = _rigid_inverse(_dh_matrices(q1_b, d1, DH_A[0], DH_ALPHA[0]))
    t14 = _frame4_in_frame1(t01_inv, flange, q5, q6)
    # Frame 4's origin must lie within the elbow's reach. At the wrist singularity (s5 = 0) the
    # axes of joints 2, 3, 4 and 6 are parallel and q6 is free, but not every value works:
    # turning q6 swings frame 4's origin on a circle of radius d5 around the wrist center. So
    # keep the requested q6 when it works, else move it to the nearest value that does. Near the
    # singularity the same move absorbs the noise of q6 read from the flange axes (~dq1 / s5),
    # which can push frame 4 out of reach when the elbow is also at full stretch. Elsewhere a
    # moved q6 breaks the orientation and the FK check drops the branch, as it should.
    wrist_in_1 = np.einsum("mbcij,mj->mbci", t01_inv[..., :3, :3], p5) + t01_inv[..., :3, 3]
    shift = _q6_shift_into_reach(wrist_in_1[..., :2], t14[..., :2, 3], np.sign(w[..., 2]))
    if np.any(shift != 0.0):
        q6 = q6 + shift
        t14 = _frame4_in_frame1(t01_inv, flange, q5, q6)
    px, py = t14[..., 0, 3], t14[..., 1, 3]
    # Law of cosines for the elbow. |c3| = 1 is the elbow at full stretch (or fully folded):
    # both elbow branches coincide, and tiny overshoots from rounding are clipped.
    c3 = (px * px + py * py - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
    c3 = np.where(np.abs(np.abs(c3) - 1.0) < _ELBOW_STRETCH_EPS, np.sign(c3), c3)
    ok_elbow = np.abs(c3) <= 1.0 + tol
    elbow = np.arccos(np.clip(c3, -1.0, 1.0))
    q3 = np.stack([elbow, -elbow], axis=-1)  # (m, 2, 2, 2)
    # Link 3's end, in frame 2, is (a2 + a3 c3, a3 s3): subtract its angle from the target's.
    q2 = np.arctan2(py, px)[..., None] - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
    q234 = np.arctan2(t14[..., 1, 0], t14[..., 0, 0])
    q4 = q234[..., None] - q2 - q3

    shape = (m, 2, 2, 2)
    q = np.stack(
        [
            np.broadcast_to(q1[:, :, None, None], shape),
            q2,
            q3,
            q4,
            np.broadcast_to(q5[..., None], shape),
            np.broadcast_to(q6[..., None], shape),
        ],
        axis=-1,
    ).reshape(m, 8, NUM_JOINTS)
    ok = np.broadcast_to(ok_shoulder[:, None, None, None] & ok_elbow[..., None], shape)
    ok = ok.reshape(m, 8)
    # Dummy (but finite) values on the rejected branches keep NaNs out of the later steps.
    q = np.where(ok[..., None] & np.isfinite(q), q, 0.0)
    return q, ok & np.all(np.isfinite(q), axis=-1)


def inverse_kinematics(
    tip_pose: np.ndarray,
    reference_joints: np.ndarray | None = None,
    tol: float = 1e-6,
) -> np.ndarray:
    """Every joint configuration that puts the gripper tip at ``tip_pose`` (closed form).

    Hawkins 2013 (Analytic Inverse Kinematics for the Universal Robots UR-5/UR-10): up to
    2 shoulder x 2 wrist x 2 elbow = 8 solutions.

    Args:
        tip_pose: target tip pose, shape ``(4, 4)``, in the DH base frame (metres). The tip is
            ``GRIPPER_TIP_OFFSET_M`` past the flange along the flange z axis.
        reference_joints: optional ``(6,)`` radians. Used to pick each joint's 2 pi copy (the one
            within ``ur5.JOINT_LIMITS`` nearest to it), to sort the solutions (nearest first by
            max-abs, then L2, joint distance) and as q6 at a wrist singularity.
        tol: slack on the cosine arguments of the closed form: values up to ``1 + tol`` are
            clipped to 1 (elbow at full stretch, wrist center at the shoulder boundary), larger
            ones make the branch unreachable.

    Returns:
        Solutions, shape ``(n, 6)``, radians, ``0 <= n <= 8``; ``(0, 6)`` if the pose is out of
        reach. Each solution reproduces the pose (FK tip position within ``IK_POSITION_TOL_M``,
        rotation within ``IK_ROTATION_TOL_RAD``); duplicates (modulo 2 pi) are removed. Angles
        are wrapped to ``(-pi, pi]`` when no reference is given.

    Singular cases: at sin q5 = 0 (wrist singularity) q6 is free and set to the reference value
    (or 0), or to the nearest value that keeps the elbow within reach when that one does not
    (e.g. with the elbow at full stretch only one q6 works); when branches coincide (elbow at
    full stretch or fully folded, wrist center at the shoulder boundary r = d4) the solution is
    returned once. The wrist center of a UR5 can never lie on the base axis itself (r >= d4 > 0
    is needed), so q1 is never free.
    """
    target = np.asarray(tip_pose, dtype=float)
    if target.shape != (4, 4):
        raise ValueError(f"tip_pose must have shape (4, 4), got {target.shape}")
    ref = _check_reference(reference_joints)
    if not np.all(np.isfinite(target)):
        return np.zeros((0, NUM_JOINTS))
    q6_free = 0.0 if ref is None else float(ref[5])
    q, ok = _ik_branches(tip_to_flange(target)[None], q6_free, tol)
    q = wrap_joints(q[0][ok[0]], ref)
    # Verify with FK: this also weeds out anything the clipping let through.
    reached = forward_kinematics(q)[:, NUM_JOINTS]
    pos_err = np.linalg.norm(reached[:, :3, 3] - target[:3, 3], axis=-1)
    rot_err = rotation_error(reached[:, :3, :3], target[:3, :3])
    q = q[(pos_err < IK_POSITION_TOL_M) & (rot_err < IK_ROTATION_TOL_RAD)]
    # Sort before removing duplicates so that, of two copies, the one nearer the reference stays.
    q = _sort_by_reference(q, ref)
    return q[_unique_rows(q, _DUPLICATE_TOL_RAD)]


# --------------------------------------------------------------------------------------------
# Reaching a point with any of several tool orientations
# --------------------------------------------------------------------------------------------


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def default_tool_orientations(
    tilts_deg: tuple[float, ...] = (30.0, 60.0),
    num_azimuths: int = 8,
    yaws_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0),
) -> np.ndarray:
    """Tool orientations tried by :func:`solve_tip_position`.

    The set is the tool z axis (approach direction of the suction cup) pointing straight down,
    plus a cone of approach directions tilted ``tilts_deg`` off vertical at ``num_azimuths``
    evenly spaced azimuths (tool z = (sin t cos az, sin t sin az, -cos t)), each combined with
    the yaw angles ``yaws_deg`` about the tool axis. Yaw only changes q6, but a choice of yaws
    lets the solution nearest a reference keep wrist 3 close to where it was.

    Returns:
        Rotation matrices, shape ``(k, 3, 3)``, tool frame in the DH base frame; the
        straight-down ones come first. Defaults: k = (1 + 2 * 8) * 4 = 68.
    """
    # Tool pointing down: a half turn about the base x axis (tool x = base x, tool z = -base z).
    down = np.diag([1.0, -1.0, -1.0])
    tilts = [(0.0, 0.0)]
    for tilt in tilts_deg:
        for k in range(num_azimuths):
            tilts.append((np.deg2rad(tilt), _TWO_PI * k / num_azimuths))
    rotations = [
        _rot_z(azimuth) @ _rot_y(-tilt) @ down @ _rot_z(np.deg2rad(yaw))
        for tilt, azimuth in tilts
        for yaw in yaws_deg
    ]
    return np.stack(rotations)


DEFAULT_TOOL_ORIENTATIONS = default_tool_orientations()
DEFAULT_TOOL_ORIENTATIONS.setflags(write=False)


def solve_tip_position(
    point: np.ndarray,
    orientations: np.ndarray | None = None,
    reference_joints: np.ndarray | None = None,
) -> np.ndarray:
    """Joint configurations that put the gripper tip at a point, over several tool orientations.

    Args:
        point: target tip position, shape ``(3,)``, metres, DH base frame.
        orientations: tool orientations to try, shape ``(k, 3, 3)`` rotation matrices in the DH
            base frame; defaults to :data:`DEFAULT_TOOL_ORIENTATIONS`.
        reference_joints: optional ``(6,)`` radians; picks 2 pi copies, sorts nearest first
            (max-abs, then L2, joint distance) and sets q6 at wrist singularities.

    Returns:
        Shape ``(n, 6)``, radians: every closed-form solution over all orientations whose FK tip
        position is within ``IK_POSITION_TOL_M`` of ``point``, without duplicates (modulo 2 pi);
        ``(0, 6)`` when none is found.
    """
    target = np.asarray(point, dtype=float)
    if target.shape != (3,):
        raise ValueError(f"point must have shape (3,), got {target.shape}")
    rots = DEFAULT_TOOL_ORIENTATIONS if orientations is None else np.asarray(orientations, float)
    if rots.ndim == 2:
        rots = rots[None]
    if rots.ndim != 3 or rots.shape[1:] != (3, 3):
        raise ValueError(f"orientations must have shape (k, 3, 3), got {rots.shape}")
    ref = _check_reference(reference_joints)
    if not np.all(np.isfinite(target)):
        return np.zeros((0, NUM_JOINTS))

    tips = np.zeros((len(rots), 4, 4))
    tips[:, :3, :3] = rots
    tips[:, :3, 3] = target
    tips[:, 3, 3] = 1.0
    q6_free = 0.0 if ref is None else float(ref[5])
    q, ok = _ik_branches(tip_to_flange(tips), q6_free, 1e-6)
    q = wrap_joints(q[ok], ref)
    err = np.linalg.norm(tip_position(q) - target, axis=-1)
    q = _sort_by_reference(q[err < IK_POSITION_TOL_M], ref)
    return q[_unique_rows(q, _DUPLICATE_TOL_RAD)]
