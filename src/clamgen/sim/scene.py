"""The CLAMGen MuJoCo scene, generated in code from the robot and scene facts.

The UR5 body tree is built directly from the standard DH table, so MuJoCo's body frames and
`clamgen.robot.forward_kinematics` agree by construction: body `link{i}` is DH frame i-1
rotated by joint i about its z axis. Links are capsules with the measured radii; the suction
gripper is a cylinder on the flange with a site at its tip.

Collision filtering (see `constants.OBSTACLE_BIT`): robot geoms only ever touch obstacles and
the table, so after `mj_collision` every contact is a robot-vs-environment contact.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from clamgen.robot import ur5
from clamgen.sim import constants as C


def dh_static(i: int) -> np.ndarray:
    """Tz(d_i) Tx(a_i) Rx(alpha_i) for joint i (0-based): the part of DH link i after the joint."""
    ca, sa = np.cos(ur5.DH_ALPHA[i]), np.sin(ur5.DH_ALPHA[i])
    return np.array(
        [
            [1.0, 0.0, 0.0, ur5.DH_A[i]],
            [0.0, ca, -sa, 0.0],
            [0.0, sa, ca, ur5.DH_D[i]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _pose_attrs(transform: np.ndarray) -> str:
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, transform[:3, :3].flatten())
    pos = transform[:3, 3]
    return f'pos="{_fmt(pos)}" quat="{_fmt(quat)}"'


def _fmt(values) -> str:
    return " ".join(f"{float(v):.6g}" for v in np.atleast_1d(values))


def look_at_xyaxes(position, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera x and y axes (world frame, shape (6,)) for a MuJoCo camera looking at `target`.

    MuJoCo cameras look along their -z axis with +y up in the image.
    """
    forward = np.asarray(target, float) - np.asarray(position, float)
    forward /= np.linalg.norm(forward)
    x_axis = np.cross(forward, up)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(x_axis, forward)
    return np.concatenate([x_axis, y_axis])


def _camera_xml(name: str, pos, target, fovy: float) -> str:
    return (
        f'<camera name="{name}" pos="{_fmt(pos)}" '
        f'xyaxes="{_fmt(look_at_xyaxes(pos, target))}" fovy="{fovy}"/>'
    )


def _zoom_camera_xml(name: str, pos, target, fovy: float) -> str:
    """The zoomed camera of a view camera: its position, turned to the target body."""
    return (
        f'<camera name="{name}{C.ZOOM_SUFFIX}" pos="{_fmt(pos)}" mode="targetbody" '
        f'target="target" fovy="{C.ZOOM_FOVY_DEG}"/>'
    )


# Link capsules in each link body's frame: (name, fromto, radius). Body `link{i}` is DH frame
# i-1 rotated by q_i about z, so e.g. the upper arm runs along x of `link2` from the shoulder to
# a2, displaced by the shoulder offset along the joint axis.
_SO = ur5.SHOULDER_OFFSET_M
_EO = _SO + ur5.ELBOW_OFFSET_M  # height of the forearm along the parallel joint axes
LINK_CAPSULES: dict[int, list[tuple[str, tuple[float, ...], float]]] = {
    1: [("shoulder", (0, 0, 0.02, 0, 0, ur5.DH_D[0]), ur5.SHOULDER_RADIUS_M)],
    2: [
        ("shoulder_joint", (0, 0, -0.02, 0, 0, _SO), ur5.SHOULDER_RADIUS_M),
        ("upper_arm", (0, 0, _SO, ur5.DH_A[1], 0, _SO), ur5.UPPER_ARM_RADIUS_M),
        ("elbow", (ur5.DH_A[1], 0, _SO, ur5.DH_A[1], 0, _EO), ur5.ELBOW_RADIUS_M),
    ],
    3: [("forearm", (0, 0, _EO, ur5.DH_A[2], 0, _EO), ur5.FOREARM_RADIUS_M)],
    4: [("wrist_1", (0, 0, _EO, 0, 0, ur5.DH_D[3]), ur5.WRIST_RADIUS_M)],
    5: [("wrist_2", (0, 0, 0.0, 0, 0, ur5.DH_D[4]), ur5.WRIST_RADIUS_M)],
    6: [("wrist_3", (0, 0, -0.02, 0, 0, ur5.DH_D[5] - 0.01), ur5.WRIST_RADIUS_M)],
}
_ROBOT_RGBA = "0.75 0.77 0.8 1"
_JOINT_RGBA = "0.25 0.45 0.75 1"


def _robot_xml() -> str:
    """Nested bodies link1..link6 built from the DH table, gripper and tip site on link6."""
    closing = []
    parts = []
    for i in range(1, ur5.NUM_JOINTS + 1):
        static = np.eye(4) if i == 1 else dh_static(i - 2)
        lo, hi = ur5.JOINT_LIMITS[i - 1]
        parts.append(f'<body name="link{i}" {_pose_attrs(static)}>')
        parts.append(
            f'<joint name="{ur5.JOINT_NAMES[i - 1]}" type="hinge" axis="0 0 1" '
            f'range="{lo:.6f} {hi:.6f}" limited="true"/>'
        )
        # The shoulder column stands on the base: let it touch obstacles but not the table.
        contype = C.OBSTACLE_BIT if i == 1 else C.OBSTACLE_BIT | C.TABLE_BIT
        for name, fromto, radius in LINK_CAPSULES[i]:
            rgba = _JOINT_RGBA if "joint" in name or "wrist" in name or "elbow" in name else None
            parts.append(
                f'<geom name="{name}" type="capsule" fromto="{_fmt(fromto)}" size="{radius}" '
                f'contype="{contype}" conaffinity="0" rgba="{rgba or _ROBOT_RGBA}"/>'
            )
        closing.append("</body>")
    # Gripper on the flange (frame 6 = link6 body translated by d6 along z).
    flange_z = ur5.DH_D[5]
    tip_z = flange_z + ur5.GRIPPER_TIP_OFFSET_M
    contype = C.OBSTACLE_BIT | C.TABLE_BIT
    parts.append(
        f'<geom name="gripper" type="cylinder" fromto="0 0 {flange_z:.6g} 0 0 {tip_z - 0.02:.6g}" '
        f'size="{ur5.GRIPPER_RADIUS_M}" contype="{contype}" conaffinity="0" rgba="0.2 0.2 0.2 1"/>'
    )
    parts.append(
        f'<geom name="suction_cup" type="cylinder" fromto="0 0 {tip_z - 0.02:.6g} 0 0 {tip_z:.6g}"'
        f' size="0.015" contype="{contype}" conaffinity="0" rgba="0.1 0.1 0.1 1"/>'
    )
    parts.append(f'<site name="flange" pos="0 0 {flange_z:.6g}" size="0.005"/>')
    parts.append(f'<site name="tip" pos="0 0 {tip_z:.6g}" size="0.005" rgba="1 1 0 1"/>')
    return "\n".join(parts + closing[::-1])


def _obstacle_xml(slot: int) -> str:
    # Each slot holds a box and a cylinder; the unused shape is disabled at reset time
    # (`Scene.set_obstacles`) because MuJoCo cannot change a geom's type after compiling.
    parked = _fmt(C.PARKED_POSITION_M + np.array([slot, 0.0, 0.0]))
    common = f'contype="0" conaffinity="{C.OBSTACLE_BIT}" rgba="0.1 0.7 0.2 1"'
    return (
        f'<body name="obstacle{slot}" mocap="true" pos="{parked}">'
        f'<geom name="obstacle{slot}_box" type="box" size="0.04 0.04 0.04" {common}/>'
        f'<geom name="obstacle{slot}_cylinder" type="cylinder" size="0.04 0.04" {common}/>'
        f"</body>"
    )


def build_mjcf() -> str:
    """The scene's MJCF: table, UR5 with suction gripper, target, obstacle slots, cameras."""
    tx, ty = C.TABLE_CENTER_XY_M
    hx, hy, hz = C.TABLE_HALF_SIZE_M
    cameras = "\n".join(
        [
            *(_camera_xml(*cam) for cam in (*C.CAMERAS, C.OVERVIEW_CAMERA)),
            *(_zoom_camera_xml(*cam) for cam in C.CAMERAS),
        ]
    )
    obstacles = "\n".join(_obstacle_xml(i) for i in range(C.MAX_OBSTACLES))
    extent = 1.0  # near/far planes below are given in units of the extent, i.e. metres
    return f"""<mujoco model="clamgen_ur5">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.05"/>
  <statistic extent="{extent}" center="0.4 0 0.2"/>
  <visual>
    <global offwidth="1280" offheight="960"/>
    <map znear="{C.CAMERA_NEAR_M / extent}" zfar="{C.CAMERA_FAR_M / extent}"/>
    <quality shadowsize="0"/>
    <headlight ambient="0.45 0.45 0.45" diffuse="0.5 0.5 0.5" specular="0.05 0.05 0.05"/>
  </visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" width="256" height="256"
      rgb1="0.55 0.5 0.45" rgb2="0.6 0.55 0.5"/>
    <material name="table" texture="grid" texrepeat="6 6" reflectance="0"/>
  </asset>
  <worldbody>
    <light name="key" pos="0.6 -0.6 2.0" dir="-0.2 0.3 -1" diffuse="0.5 0.5 0.5"
      castshadow="false"/>
    <geom name="table" type="box" pos="{tx} {ty} {C.TABLE_TOP_Z_M - hz}"
      size="{hx} {hy} {hz}" material="table" contype="0" conaffinity="{C.TABLE_BIT}"/>
    <geom name="pedestal" type="cylinder" fromto="0 0 {C.TABLE_TOP_Z_M} 0 0 0" size="0.075"
      rgba="0.3 0.3 0.32 1" contype="0" conaffinity="0"/>
    {cameras}
    <body name="target" mocap="true" pos="0.6 0 0.2">
      <geom name="target" type="sphere" size="{C.TARGET_RADIUS_M}" rgba="0.9 0.05 0.05 1"
        contype="0" conaffinity="0"/>
    </body>
    {obstacles}
    {_robot_xml()}
  </worldbody>
</mujoco>
"""


@dataclass(frozen=True)
class Obstacles:
    """Obstacle set of one task, as arrays (N = number of obstacles).

    kinds: (N,) int, `constants.OBSTACLE_BOX` or `constants.OBSTACLE_CYLINDER`.
    positions_m: (N, 3) centres in the world frame.
    half_sizes_m: (N, 3) half extents; for a cylinder (radius, radius, half height).
    """

    kinds: np.ndarray
    positions_m: np.ndarray
    half_sizes_m: np.ndarray

    @staticmethod
    def empty() -> Obstacles:
        return Obstacles(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))

    def __len__(self) -> int:
        return len(self.kinds)

    def as_array(self) -> np.ndarray:
        """(N, 8) float32: [is_box, is_cylinder, x, y, z, hx, hy, hz] per obstacle."""
        one_hot = np.eye(2)[self.kinds]
        return np.concatenate([one_hot, self.positions_m, self.half_sizes_m], axis=1).astype(
            np.float32
        )

    @staticmethod
    def from_array(array: np.ndarray) -> Obstacles:
        """The obstacles an `as_array` row set describes (as float64)."""
        array = np.asarray(array, np.float64).reshape(-1, 8)
        kinds = np.where(array[:, 0] > 0.5, C.OBSTACLE_BOX, C.OBSTACLE_CYLINDER)
        return Obstacles(kinds.astype(np.int64), array[:, 2:5].copy(), array[:, 5:8].copy())


class Scene:
    """MuJoCo model + data of the scene with names resolved to ids once.

    The arm is moved kinematically: `set_joints` writes qpos and runs `mj_kinematics`; nothing
    here steps physics.
    """

    def __init__(self, collision_margin_m: float = 0.0) -> None:
        if not np.isfinite(collision_margin_m) or collision_margin_m < 0:
            raise ValueError(f"collision_margin_m must be >= 0, got {collision_margin_m}")
        self.model = mujoco.MjModel.from_xml_string(build_mjcf())
        self.data = mujoco.MjData(self.model)
        m = self.model
        name2id = mujoco.mj_name2id
        self.tip_site = name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tip")
        self.flange_site = name2id(m, mujoco.mjtObj.mjOBJ_SITE, "flange")
        self.target_mocap = m.body_mocapid[name2id(m, mujoco.mjtObj.mjOBJ_BODY, "target")]
        self.target_geom = name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "target")
        self.obstacle_mocap = np.array(
            [
                m.body_mocapid[name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"obstacle{i}")]
                for i in range(C.MAX_OBSTACLES)
            ]
        )
        self.obstacle_geoms = np.array(
            [
                [
                    name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"obstacle{i}_box"),
                    name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"obstacle{i}_cylinder"),
                ]
                for i in range(C.MAX_OBSTACLES)
            ]
        )
        self.camera_ids = np.array(
            [name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, cam[0]) for cam in C.CAMERAS]
        )
        self.zoom_camera_ids = np.array(
            [name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, cam[0] + C.ZOOM_SUFFIX) for cam in C.CAMERAS]
        )
        self.overview_camera_id = name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, C.OVERVIEW_CAMERA[0])
        robot_bodies = {name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"link{i}") for i in range(1, 7)}
        self.robot_geoms = np.array([g for g in range(m.ngeom) if m.geom_bodyid[g] in robot_bodies])
        # Contacts are generated below this distance: a margin makes the checker conservative.
        self.collision_margin_m = collision_margin_m
        env_geoms = [name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table"), *self.obstacle_geoms.ravel()]
        m.geom_margin[env_geoms] = collision_margin_m
        self._obstacles = Obstacles.empty()
        self.set_obstacles(Obstacles.empty())
        mujoco.mj_forward(m, self.data)

    # ----------------------------------------------------------------------------- state
    @property
    def joints(self) -> np.ndarray:
        """(6,) current joint angles, radians."""
        return self.data.qpos.copy()

    @property
    def target_position(self) -> np.ndarray:
        """(3,) target centre, world frame, metres."""
        return self.data.mocap_pos[self.target_mocap].copy()

    @property
    def obstacles(self) -> Obstacles:
        return self._obstacles

    def tip_position(self) -> np.ndarray:
        """(3,) gripper tip position for the current joints, world frame, metres."""
        return self.data.site_xpos[self.tip_site].copy()

    def set_joints(self, joints: np.ndarray) -> None:
        """Place the arm at `joints` (6,) radians and update all frames (no physics)."""
        self.data.qpos[:] = joints
        mujoco.mj_kinematics(self.model, self.data)

    def set_target(self, position_m: np.ndarray) -> None:
        """Move the (visual) target sphere to `position_m` (3,), world frame."""
        self.data.mocap_pos[self.target_mocap] = position_m
        mujoco.mj_kinematics(self.model, self.data)

    def set_obstacles(self, obstacles: Obstacles) -> None:
        """Place `obstacles` in the first slots and park the rest out of sight."""
        if len(obstacles) > C.MAX_OBSTACLES:
            raise ValueError(f"at most {C.MAX_OBSTACLES} obstacles, got {len(obstacles)}")
        m = self.model
        for slot in range(C.MAX_OBSTACLES):
            box, cyl = self.obstacle_geoms[slot]
            used = slot < len(obstacles)
            kind = obstacles.kinds[slot] if used else -1
            for geom, geom_kind in ((box, C.OBSTACLE_BOX), (cyl, C.OBSTACLE_CYLINDER)):
                active = kind == geom_kind
                m.geom_conaffinity[geom] = C.OBSTACLE_BIT if active else 0
                m.geom_rgba[geom, 3] = 1.0 if active else 0.0
                if active:
                    half = obstacles.half_sizes_m[slot]
                    if geom_kind == C.OBSTACLE_BOX:
                        m.geom_size[geom] = half
                        m.geom_aabb[geom] = [0, 0, 0, *half]
                        m.geom_rbound[geom] = np.linalg.norm(half)
                    else:
                        m.geom_size[geom] = [half[0], half[2], 0.0]
                        m.geom_aabb[geom] = [0, 0, 0, half[0], half[0], half[2]]
                        m.geom_rbound[geom] = np.hypot(half[0], half[2])
            parked = C.PARKED_POSITION_M + np.array([slot, 0.0, 0.0])
            position = obstacles.positions_m[slot] if used else parked
            self.data.mocap_pos[self.obstacle_mocap[slot]] = position
        self._obstacles = obstacles
        mujoco.mj_kinematics(m, self.data)

    # ------------------------------------------------------------------------- collision
    def in_collision(self, joints: np.ndarray | None = None) -> bool:
        """Whether the arm at `joints` (default: current) touches an obstacle or the table.

        Leaves the arm at `joints`.
        """
        if joints is not None:
            self.data.qpos[:] = joints
            mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_collision(self.model, self.data)
        return self.data.ncon > 0

    def move_along(self, start: np.ndarray, end: np.ndarray, resolution_rad: float) -> tuple:
        """Move the arm straight (in joint space) from `start` to `end`, stopping before contact.

        The segment is checked at sub-steps no larger than `resolution_rad` on any joint. If a
        sub-step collides the arm stays at the last collision-free sub-step.

        Returns (joints reached (6,), collided: bool). `start` is assumed collision-free.
        """
        delta = end - start
        num_checks = max(1, int(np.ceil(np.max(np.abs(delta)) / resolution_rad)))
        reached = start
        for k in range(1, num_checks + 1):
            joints = start + delta * (k / num_checks)
            if self.in_collision(joints):
                self.set_joints(reached)
                return reached.copy(), True
            reached = joints
        return reached.copy(), False

    def collision_mask(self, joints: np.ndarray) -> np.ndarray:
        """(...,) bool: collision for each configuration in `joints` (..., 6). Restores the arm."""
        joints = np.asarray(joints, dtype=np.float64)
        saved = self.data.qpos.copy()
        flat = joints.reshape(-1, ur5.NUM_JOINTS)
        out = np.fromiter((self.in_collision(q) for q in flat), dtype=bool, count=len(flat))
        self.set_joints(saved)
        return out.reshape(joints.shape[:-1])


# ------------------------------------------------------------------- viewer-ready export
# The exported scene is simulated by MuJoCo's viewer, not moved kinematically. The links are
# gravity-compensated (as a real arm's controller does), so the position servos only hold
# against contacts and drift; the rotor inertia (armature) keeps the servo of the light wrist
# stable at the 2 ms step: sqrt(kp / armature) * dt = 0.28.
EXPORT_TIMESTEP_S = 0.002
HOLD_KP_NM_PER_RAD = 1000.0
HOLD_DAMPING_RATIO = 1.0
JOINT_ARMATURE_KG_M2 = 0.05
START_KEY = "start"


def task_spec(
    start_joints: np.ndarray, target_position_m: np.ndarray, obstacles: Obstacles
) -> mujoco.MjSpec:
    """One task's scene as an `MjSpec` for MuJoCo's viewer and for other simulators.

    Unlike the model `Scene` compiles (obstacle slots parked at z = -10 and shaped at reset),
    the task's obstacles stand in place with their own shapes and sizes, unused slots are
    removed, the target is at `target_position_m`, and a keyframe named "start" holds the
    start joints (6,) radians. The links are gravity-compensated and each joint gets a
    position actuator (`hold_<joint>`) whose control the keyframe sets to the start joints, so
    the arm stays still instead of falling; the time step is `EXPORT_TIMESTEP_S`.
    """
    if len(obstacles) > C.MAX_OBSTACLES:
        raise ValueError(f"at most {C.MAX_OBSTACLES} obstacles, got {len(obstacles)}")
    start_joints = np.asarray(start_joints, np.float64)
    if start_joints.shape != (ur5.NUM_JOINTS,):
        raise ValueError(f"start_joints must have shape ({ur5.NUM_JOINTS},)")
    spec = mujoco.MjSpec.from_string(build_mjcf())
    spec.modelname = "clamgen_task"
    spec.option.timestep = EXPORT_TIMESTEP_S
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    for i in range(1, ur5.NUM_JOINTS + 1):
        spec.body(f"link{i}").gravcomp = 1.0
    for name in ur5.JOINT_NAMES:
        spec.joint(name).armature = JOINT_ARMATURE_KG_M2
    spec.body("target").pos = np.asarray(target_position_m, np.float64)
    for slot in range(C.MAX_OBSTACLES):
        body = spec.body(f"obstacle{slot}")
        if slot >= len(obstacles):
            spec.delete(body)
            continue
        body.pos = obstacles.positions_m[slot]
        half = obstacles.half_sizes_m[slot]
        box, cylinder = spec.geom(f"obstacle{slot}_box"), spec.geom(f"obstacle{slot}_cylinder")
        if obstacles.kinds[slot] == C.OBSTACLE_BOX:
            box.size = half
            spec.delete(cylinder)
        else:
            cylinder.size = [half[0], half[2], 0.0]
            spec.delete(box)
    for name in ur5.JOINT_NAMES:
        actuator = spec.add_actuator(
            name=f"hold_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT
        )
        actuator.set_to_position(kp=HOLD_KP_NM_PER_RAD, dampratio=HOLD_DAMPING_RATIO)
        lo, hi = ur5.JOINT_LIMITS[ur5.JOINT_NAMES.index(name)]
        actuator.ctrlrange = [lo, hi]
    spec.add_key(name=START_KEY, qpos=start_joints, ctrl=start_joints)
    return spec


def task_mjcf(start_joints: np.ndarray, target_position_m: np.ndarray, obstacles: Obstacles) -> str:
    """`task_spec` as MJCF text: `python -m mujoco.viewer --mjcf FILE`, then load key "start"."""
    spec = task_spec(start_joints, target_position_m, obstacles)
    spec.compile()
    return spec.to_xml()
