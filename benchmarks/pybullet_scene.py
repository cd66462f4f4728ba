"""The CLAMGen scene rebuilt in PyBullet from the same facts, as the paper's simulator did it.

Reference for the benchmarks only: same capsules (from `clamgen.sim.scene.LINK_CAPSULES`), same
gripper, table, target sphere, obstacles and cameras. Kinematic stepping sets joint states with
`resetJointState` and checks contacts with `getClosestPoints(distance=0)`, the paper's way.
"""

from __future__ import annotations

import numpy as np
import pybullet as pb

from clamgen.robot import ur5
from clamgen.sim import constants as C
from clamgen.sim.scene import LINK_CAPSULES, Obstacles, dh_static


def _capsule_frame(fromto):
    """Centre, quaternion (x, y, z, w) and length of a capsule given by its end points."""
    a, b = np.asarray(fromto[:3], float), np.asarray(fromto[3:], float)
    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length
    # Rotation taking +z onto the capsule axis.
    cross = np.cross([0.0, 0.0, 1.0], z)
    if np.linalg.norm(cross) < 1e-9:
        quat = [0.0, 0.0, 0.0, 1.0] if z[2] > 0 else [1.0, 0.0, 0.0, 0.0]
    else:
        angle = np.arccos(np.clip(z[2], -1, 1))
        quat = pb.getQuaternionFromAxisAngle(cross / np.linalg.norm(cross), angle)
    return (a + b) / 2, list(quat), length


def _matrix_to_quat(rotation: np.ndarray):
    m = rotation
    w = np.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    return [x, y, z, w]


class PyBulletScene:
    """Equivalent scene in a DIRECT PyBullet client."""

    def __init__(self) -> None:
        self.client = pb.connect(pb.DIRECT)
        c = self.client
        hx, hy, hz = C.TABLE_HALF_SIZE_M
        tx, ty = C.TABLE_CENTER_XY_M
        table_col = pb.createCollisionShape(
            pb.GEOM_BOX, halfExtents=[hx, hy, hz], physicsClientId=c
        )
        table_vis = pb.createVisualShape(
            pb.GEOM_BOX,
            halfExtents=[hx, hy, hz],
            rgbaColor=[0.58, 0.53, 0.48, 1],
            physicsClientId=c,
        )
        self.table = pb.createMultiBody(
            0, table_col, table_vis, [tx, ty, C.TABLE_TOP_Z_M - hz], physicsClientId=c
        )
        target_vis = pb.createVisualShape(
            pb.GEOM_SPHERE,
            radius=C.TARGET_RADIUS_M,
            rgbaColor=[0.9, 0.05, 0.05, 1],
            physicsClientId=c,
        )
        self.target = pb.createMultiBody(0, -1, target_vis, [0.6, 0, 0.2], physicsClientId=c)
        self.robot = self._build_robot()
        self.obstacles: list[int] = []

    def _build_robot(self) -> int:
        c = self.client
        col, vis, pos, orn, parents, axes = [], [], [], [], [], []
        for i in range(1, ur5.NUM_JOINTS + 1):
            capsules = list(LINK_CAPSULES[i])
            if i == ur5.NUM_JOINTS:  # the gripper rides on the last link
                z0, z1 = ur5.DH_D[5], ur5.DH_D[5] + ur5.GRIPPER_TIP_OFFSET_M
                capsules.append(("gripper", (0, 0, z0, 0, 0, z1), ur5.GRIPPER_RADIUS_M))
            frames = [_capsule_frame(f) for _, f, _ in capsules]
            kwargs = dict(
                shapeTypes=[pb.GEOM_CAPSULE] * len(capsules),
                radii=[r for _, _, r in capsules],
                lengths=[f[2] for f in frames],
                physicsClientId=c,
            )
            col.append(
                pb.createCollisionShapeArray(
                    collisionFramePositions=[f[0].tolist() for f in frames],
                    collisionFrameOrientations=[f[1] for f in frames],
                    **kwargs,
                )
            )
            vis.append(
                pb.createVisualShapeArray(
                    visualFramePositions=[f[0].tolist() for f in frames],
                    visualFrameOrientations=[f[1] for f in frames],
                    rgbaColors=[[0.75, 0.77, 0.8, 1]] * len(capsules),
                    **kwargs,
                )
            )
            static = np.eye(4) if i == 1 else dh_static(i - 2)
            pos.append(static[:3, 3].tolist())
            orn.append(_matrix_to_quat(static[:3, :3]))
            parents.append(i - 1)
            axes.append([0, 0, 1])
        n = ur5.NUM_JOINTS
        return pb.createMultiBody(
            baseMass=0,
            basePosition=[0, 0, 0],
            linkMasses=[1.0] * n,
            linkCollisionShapeIndices=col,
            linkVisualShapeIndices=vis,
            linkPositions=pos,
            linkOrientations=orn,
            linkInertialFramePositions=[[0, 0, 0]] * n,
            linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
            linkParentIndices=parents,
            linkJointTypes=[pb.JOINT_REVOLUTE] * n,
            linkJointAxis=axes,
            physicsClientId=self.client,
        )

    def set_obstacles(self, obstacles: Obstacles) -> None:
        c = self.client
        for body in self.obstacles:
            pb.removeBody(body, physicsClientId=c)
        self.obstacles = []
        for kind, position, half in zip(
            obstacles.kinds, obstacles.positions_m, obstacles.half_sizes_m, strict=True
        ):
            if kind == C.OBSTACLE_BOX:
                shape = dict(shapeType=pb.GEOM_BOX, halfExtents=half.tolist())
            else:
                shape = dict(shapeType=pb.GEOM_CYLINDER, radius=half[0], height=2 * half[2])
            col_kw = {k: v for k, v in shape.items()}
            if "height" in col_kw:
                col_kw["height"] = shape["height"]
            col = pb.createCollisionShape(physicsClientId=c, **col_kw)
            vis_kw = dict(shape)
            if "height" in vis_kw:
                vis_kw["length"] = vis_kw.pop("height")
            vis = pb.createVisualShape(rgbaColor=[0.1, 0.7, 0.2, 1], physicsClientId=c, **vis_kw)
            self.obstacles.append(
                pb.createMultiBody(0, col, vis, position.tolist(), physicsClientId=c)
            )

    def set_joints(self, joints: np.ndarray) -> None:
        for j, q in enumerate(joints):
            pb.resetJointState(self.robot, j, float(q), physicsClientId=self.client)

    def in_collision(self, joints: np.ndarray) -> bool:
        """The paper's check: closest points at distance 0 between the arm and each body."""
        self.set_joints(joints)
        c = self.client
        for body in self.obstacles:
            if pb.getClosestPoints(self.robot, body, 0.0, physicsClientId=c):
                return True
        # The shoulder column (link 0) stands on the table: only later links count there.
        return any(
            point[3] > 0
            for point in pb.getClosestPoints(self.robot, self.table, 0.0, physicsClientId=c)
        )

    def tip_position(self) -> np.ndarray:
        state = pb.getLinkState(
            self.robot,
            ur5.NUM_JOINTS - 1,
            computeForwardKinematics=True,
            physicsClientId=self.client,
        )
        position, orientation = np.array(state[4]), state[5]
        rotation = np.array(pb.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        return position + rotation[:, 2] * (ur5.DH_D[5] + ur5.GRIPPER_TIP_OFFSET_M)

    def set_target(self, position: np.ndarray) -> None:
        pb.resetBasePositionAndOrientation(
            self.target, position.tolist(), [0, 0, 0, 1], physicsClientId=self.client
        )

    def camera_images(self, height: int, width: int, num_views: int):
        """RGB (V, H, W, 3) uint8 and metric depth (V, H, W) from TinyRenderer."""
        rgbs, depths = [], []
        near, far = C.CAMERA_NEAR_M, C.CAMERA_FAR_M
        for name, position, lookat, fovy in C.CAMERAS[:num_views]:
            del name
            view = pb.computeViewMatrix(position, lookat, [0, 0, 1])
            projection = pb.computeProjectionMatrixFOV(fovy, width / height, near, far)
            _, _, rgba, depth_buffer, _ = pb.getCameraImage(
                width,
                height,
                view,
                projection,
                renderer=pb.ER_TINY_RENDERER,
                physicsClientId=self.client,
            )
            rgba = np.reshape(rgba, (height, width, 4)).astype(np.uint8)
            buffer = np.reshape(depth_buffer, (height, width))
            rgbs.append(rgba[..., :3])
            depths.append(far * near / (far - (far - near) * buffer))
        return np.stack(rgbs), np.stack(depths).astype(np.float32)

    def close(self) -> None:
        pb.disconnect(self.client)
