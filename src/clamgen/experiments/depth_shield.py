"""A collision shield on the policy's own depth images (beyond the paper).

The vision policies see RGBD views from fixed, calibrated cameras. Each step, the depth
pixels are lifted to world points (`DepthOccupancy.update`); the points above the table that
lie neither on the arm (at its known joint angles) nor on the target, nor on the pedestal,
are obstacle surface, and are kept on a voxel grid for the rest of the episode (the
obstacles stand still, so a surface once seen stays even when the arm later hides it). The
shield then checks the policy's next joint step against those points, the arm's collision
capsules and the table, and replaces a step that would come within `margin_m` of them by the
nearest alternative that does not (`clamgen.experiments.shield.choose_action`).

Nothing privileged is read: only the images, the joint angles and the goal of the
observation, and the cameras' fixed poses and fields of view. No pose is learned or estimated,
so this shield works for any vision policy, shipped ones included (`DepthShield`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np

from clamgen.experiments.shield import step_checks, step_target
from clamgen.robot import ur5
from clamgen.robot.kinematics import forward_kinematics
from clamgen.sim import constants as C
from clamgen.sim.render import camera_intrinsics, uint8_to_depth
from clamgen.sim.scene import Scene

VOXEL_M = 0.01
"""Edge of the voxels the obstacle surface is kept on."""
ABOVE_TABLE_M = 0.015
"""Points less than this above the table top are table."""
ARM_FILTER_M = 0.006
"""Points within this of the arm's surface (at its current joints) are arm, not obstacle: the
rendered arm is its collision capsules, and a depth pixel lies on the surface it sees to
within half the uint8 depth step (4.3 mm). Wider, it hides the obstacle surface next to the
gripper, where the shield needs it most."""
TARGET_FILTER_M = 0.02
"""Points within this of the target sphere's surface are taken for target. Wider than the
arm's filter on purpose: it also hides obstacle surface right beside the target, so that the
gripper can make its last approach to a target that sits close to an obstacle (blocked tasks
often put one there) instead of being held off by the margin (chosen on 300 blocked
validation tasks, `residual-3views` with the planner: 0.963 success with 2 cm, 0.920 with
6 mm, where 65 of 191 plans found no path)."""
TARGET_REACH_M = C.TARGET_RADIUS_M + TARGET_FILTER_M
PEDESTAL_RADIUS_M = 0.09
PEDESTAL_TOP_M = 0.01
"""The pedestal (a 7.5 cm cylinder up to z = 0) is not an obstacle."""
SUPPORT_RADIUS_M = 0.03
"""A new obstacle point counts only with another obstacle point (new or kept) within this:
a lone pixel is not a surface (the renderer leaves a rare stray pixel)."""
FAR_CLIP_M = C.DEPTH_RANGE_M[1] - 0.05
"""Depth at or beyond the stored range's far end is background."""
MARGIN_M = 0.01
"""Clearance the depth shield keeps: about a voxel (chosen on validation tasks)."""
ARM_REACH_M = 1.2
"""Farther than any point of the arm gets from the base (UR5 reach 0.85 m, and the gripper)."""
GRID_LOW_M = np.array([-1.0, -1.0, C.TABLE_TOP_Z_M])
GRID_HIGH_M = np.array([1.5, 1.0, 1.2])
"""The voxel grid's bounds (the table's top and the workspace above it); points outside are
not kept."""


def _segment_distance(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """(P, S) distances of points (P, 3) to segments from `starts` to `ends` (S, 3), by
    matrix products (the squared distance expanded; exact to far below a millimetre at arm
    scale)."""
    axis = ends - starts
    length2 = np.maximum((axis * axis).sum(1), 1e-12)
    along = points @ axis.T - (starts * axis).sum(1)  # (p - s) . a
    t = np.clip(along / length2, 0.0, 1.0)
    to_start2 = (
        (points * points).sum(1)[:, None] - 2.0 * points @ starts.T + (starts * starts).sum(1)
    )
    squared = to_start2 - 2.0 * t * along + t * t * length2
    return np.sqrt(np.maximum(squared, 0.0))


class ArmCapsules:
    """The arm's collision geoms as capsules (segments with radii) at given joint angles (the
    gripper's two cylinders as capsules of the same radius, a little longer: conservative)."""

    def __init__(self, scene: Scene | None = None) -> None:
        self.scene = scene if scene is not None else Scene(0.0)
        model = self.scene.model
        shapes = (int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_CYLINDER))
        self.geoms = np.array(
            [g for g in self.scene.robot_geoms if int(model.geom_type[g]) in shapes], dtype=int
        )
        self.radii = model.geom_size[self.geoms, 0].copy()
        self.half_lengths = model.geom_size[self.geoms, 1].copy()
        # Geoms that can touch the table (the shoulder column stands on the base and cannot).
        self.touch_table = (model.geom_contype[self.geoms] & C.TABLE_BIT) != 0
        # For many configurations at once (`clearances`): each geom's axis in the DH frame of
        # its link (body link{i} carries DH frame i), read off once.
        bodies = [model.body(int(model.geom_bodyid[g])).name for g in self.geoms]
        self._frame = np.array([int(name.removeprefix("link")) - 1 for name in bodies])
        starts, ends = self.segments(ur5.HOME_JOINTS)
        inverse = np.linalg.inv(forward_kinematics(ur5.HOME_JOINTS)[self._frame])
        self._local = np.stack([starts, ends], axis=1)  # (G, 2, 3)
        self._local = (
            np.einsum("gij,gkj->gki", inverse[:, :3, :3], self._local) + inverse[:, None, :3, 3]
        )

    def segments(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(starts, ends), each (G, 3), of the geoms' axes at `joints`."""
        data = self.scene.data
        data.qpos[:] = joints
        mujoco.mj_kinematics(self.scene.model, data)
        centres = data.geom_xpos[self.geoms]
        axes = data.geom_xmat[self.geoms].reshape(-1, 3, 3)[:, :, 2]
        offset = axes * self.half_lengths[:, None]
        return centres - offset, centres + offset

    def segments_many(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(starts, ends), each (B, G, 3), of the geoms' axes at joints (B, 6), by the
        analytic kinematics (batched)."""
        frames = forward_kinematics(np.asarray(joints, np.float64))[:, self._frame]  # B, G
        ends = np.einsum("bgij,gkj->bgki", frames[..., :3, :3], self._local)
        ends = ends + frames[..., None, :3, 3]
        return ends[:, :, 0], ends[:, :, 1]

    def clearances(self, joints: np.ndarray, points: np.ndarray, cap: float) -> np.ndarray:
        """`clearance` at each of joints (B, 6), capped at `cap`: (B,)."""
        starts, ends = self.segments_many(joints)
        lowest = np.minimum(starts[..., 2], ends[..., 2]) - self.radii
        out = np.minimum(cap, (lowest[:, self.touch_table] - C.TABLE_TOP_Z_M).min(axis=1))
        b, g = starts.shape[:2]
        flat_starts, flat_ends = starts.reshape(-1, 3), ends.reshape(-1, 3)
        points = points[self.near(points, flat_starts, flat_ends, cap)]
        if len(points):
            surface = _segment_distance(points, flat_starts, flat_ends).reshape(-1, b, g)
            out = np.minimum(out, (surface - self.radii).min(axis=(0, 2)))
        return out

    def near(self, points: np.ndarray, starts: np.ndarray, ends: np.ndarray, reach: float):
        """Indices of `points` in the box around the arm's segments widened by its largest
        radius and `reach`: the only ones that can lie within `reach` of its surface."""
        reach = self.radii.max() + reach
        low = np.minimum(starts, ends).min(axis=0) - reach
        high = np.maximum(starts, ends).max(axis=0) + reach
        return np.flatnonzero(((points > low) & (points < high)).all(axis=1))

    def clearance(self, joints: np.ndarray, points: np.ndarray, cap: float = np.inf) -> float:
        """Distance (m) of the arm at `joints` to the nearest of `points` (P, 3) or to the table
        (negative: touching), or `cap` when both are farther."""
        starts, ends = self.segments(joints)
        lowest = np.minimum(starts[:, 2], ends[:, 2]) - self.radii
        table = min(cap, float((lowest[self.touch_table] - C.TABLE_TOP_Z_M).min()))
        if np.isfinite(cap):
            points = points[self.near(points, starts, ends, cap)]
        if len(points) == 0:
            return table
        surface = _segment_distance(points, starts, ends) - self.radii[None]
        return min(table, float(surface.min()))


class DepthOccupancy:
    """Obstacle surface points seen so far in an episode, from RGBD views of the fixed cameras.

    `num_views`, `height`, `width`: the observation's views (the first `num_views` cameras of
    `constants.CAMERAS`) and image size.
    """

    def __init__(
        self,
        num_views: int,
        height: int,
        width: int,
        arm: ArmCapsules | None = None,
        extrude_m: float = 0.0,
    ):
        self.arm = arm if arm is not None else ArmCapsules()
        self.extrude_m = extrude_m
        scene = self.arm.scene
        mujoco.mj_kinematics(scene.model, scene.data)
        rays = []
        for camera in scene.camera_ids[:num_views]:
            fx, fy, cx, cy = camera_intrinsics(scene.model, camera, height, width)
            cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
            # Camera frame: x right, y up, looking along -z; depth is along the optical axis.
            local = np.stack([(cols - cx) / fx, -(rows - cy) / fy, -np.ones_like(cols)], -1)
            rotation = scene.data.cam_xmat[camera].reshape(3, 3)
            rays.append(local @ rotation.T)
        # Per pixel, flattened over views: the camera's position and the world offset per metre
        # of depth.
        self.rays = np.stack(rays).reshape(-1, 3).astype(np.float32)
        self.directions = self.rays / np.linalg.norm(self.rays, axis=1, keepdims=True)
        origins = scene.data.cam_xpos[scene.camera_ids[:num_views]].astype(np.float32)
        self.origins = np.repeat(origins, height * width, axis=0)
        self.shape = (num_views, height, width)
        self._dims = np.ceil((GRID_HIGH_M - GRID_LOW_M) / VOXEL_M).astype(np.int64)
        self._grid = np.zeros(int(np.prod(self._dims)), bool)
        self._strides = np.array([self._dims[1] * self._dims[2], self._dims[2], 1])
        self._cells = np.empty(0, np.int64)
        self.points = np.empty((0, 3))
        self._last_depth: np.ndarray | None = None

    def reset(self) -> None:
        self._last_depth = None
        self._grid[self._cells] = False
        self._cells = np.empty(0, np.int64)
        self.points = np.empty((0, 3))

    def lift(
        self, images: np.ndarray, changed_only: bool = False, with_rays: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) of the views' depth pixels that are not background and lie
        above the table; with `changed_only`, of those whose depth changed since the last
        call (a pixel that shows the same depth shows the same point, already looked at).
        With `with_rays`, also their unit viewing directions (N, 3)."""
        images = np.asarray(images)
        if images.shape[0] != self.shape[0] or images.shape[2:] != self.shape[1:]:
            raise ValueError(
                f"expected images of shape (V, 4, H, W) with (V, H, W) = {self.shape}, "
                f"got {images.shape}"
            )
        depth_u8 = images[:, 3].reshape(-1)
        if changed_only and self._last_depth is not None:
            pixels = np.flatnonzero(depth_u8 != self._last_depth)
        else:
            pixels = np.arange(len(depth_u8))
        if changed_only:
            self._last_depth = depth_u8.copy()
        depth = uint8_to_depth(depth_u8[pixels])
        height = self.origins[pixels, 2] + depth * self.rays[pixels, 2]
        valid = np.flatnonzero((depth < FAR_CLIP_M) & (height > C.TABLE_TOP_Z_M + ABOVE_TABLE_M))
        depth, keep = depth[valid], pixels[valid]
        points = (self.origins[keep] + depth[:, None] * self.rays[keep]).astype(np.float64)
        if with_rays:
            return points, self.directions[keep]
        return points

    def voxel_centres(self, cells: np.ndarray) -> np.ndarray:
        return GRID_LOW_M + (np.stack(np.unravel_index(cells, self._dims), axis=1) + 0.5) * VOXEL_M

    def new_obstacle_cells(
        self, images: np.ndarray, joints: np.ndarray, goal: np.ndarray
    ) -> np.ndarray:
        """Voxels (flat indices) of obstacle surface in `images` not yet kept: lifted points
        above the table, off the target, the pedestal and the arm at `joints`, with another
        such point near."""
        points, directions = self.lift(images, changed_only=True, with_rays=True)
        radial2 = np.einsum("ij,ij->i", points[:, :2], points[:, :2])
        off_target = points - np.asarray(goal)
        keep = (radial2 > PEDESTAL_RADIUS_M**2) | (points[:, 2] > PEDESTAL_TOP_M)
        keep &= np.einsum("ij,ij->i", off_target, off_target) > TARGET_REACH_M**2
        points, directions = points[keep], directions[keep]
        voxels = np.floor((points - GRID_LOW_M) * (1.0 / VOXEL_M)).astype(np.int64)
        inside = (voxels >= 0).all(axis=1) & (voxels < self._dims).all(axis=1)
        cells = voxels[inside] @ self._strides
        new = ~self._grid[cells]
        cells, points, directions = cells[new], points[inside][new], directions[inside][new]
        if len(cells):
            off_arm = self._off_arm(points, joints)
            cells, points, directions = cells[off_arm], points[off_arm], directions[off_arm]
        if len(cells):
            others = np.concatenate([points, self.points])
            close = np.linalg.norm(points[:, None] - others[None], axis=-1) < SUPPORT_RADIUS_M
            supported = close.sum(axis=1) >= 2  # (itself and another)
            cells, points, directions = cells[supported], points[supported], directions[supported]
        if len(cells) and self.extrude_m > 0:
            cells = np.concatenate([cells, self._behind(points, directions, joints)])
        return np.unique(cells)

    def _off_arm(self, points: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Which of `points` lie farther than `ARM_FILTER_M` from the arm at `joints`."""
        starts, ends = self.arm.segments(joints)
        near = self.arm.near(points, starts, ends, ARM_FILTER_M)
        arm = _segment_distance(points[near], starts, ends) - self.arm.radii[None]
        off_arm = np.ones(len(points), bool)
        off_arm[near[arm.min(axis=1) <= ARM_FILTER_M]] = False
        return off_arm

    def _behind(self, points: np.ndarray, directions: np.ndarray, joints: np.ndarray):
        """Cells up to `extrude_m` behind surface points along their viewing rays (an obstacle
        is at least that thick: the side hidden from the cameras is taken as filled), off the
        arm."""
        steps = np.arange(1, round(self.extrude_m / VOXEL_M) + 1) * VOXEL_M
        behind = (points[:, None] + steps[None, :, None] * directions[:, None]).reshape(-1, 3)
        voxels = np.floor((behind - GRID_LOW_M) * (1.0 / VOXEL_M)).astype(np.int64)
        inside = (voxels >= 0).all(axis=1) & (voxels < self._dims).all(axis=1)
        behind, voxels = behind[inside], voxels[inside]
        return (voxels @ self._strides)[self._off_arm(behind, joints)]

    def update(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Add the obstacle surface seen in `obs` to the episode's voxels; all voxel centres."""
        joints = np.asarray(obs["observation"], np.float64)[: ur5.NUM_JOINTS]
        cells = self.new_obstacle_cells(obs["images"], joints, obs["desired_goal"])
        if len(cells):
            self._grid[cells] = True
            self._cells = np.concatenate([self._cells, cells])
            self.points = np.concatenate([self.points, self.voxel_centres(cells)])
        return self.points


class DepthClearance:
    """`clamgen.experiments.shield.choose_action`'s checker on the depth shield's points."""

    def __init__(self, arm: ArmCapsules, margin_m: float) -> None:
        self.arm = arm
        self.margin_m = margin_m
        self.points = np.empty((0, 3))

    def clearance(self, joints: np.ndarray) -> float:
        return self.arm.clearance(joints, self.points, cap=self.margin_m)

    def clearances(self, joints: np.ndarray) -> np.ndarray:
        return self.arm.clearances(joints, self.points, cap=self.margin_m)

    def step_clearance(self, joints: np.ndarray, action: np.ndarray) -> float:
        """`shield.step_clearance`, with a shortcut for the usual step far from everything:
        when no kept point lies in the box around any of the arm's geoms at both ends of the
        step, and the arm's lowest point at both ends is well above the table, every check
        along the step would return the margin. (Between its ends a point of the arm strays
        from the straight line by at most R theta^2 / 8, R its distance from the base and
        theta the joints' summed change: about 3 mm for a typical step; the boxes are widened
        by that bound.)"""
        target = step_target(joints, action)
        theta = float(np.abs(target - joints).sum())
        reach = self.margin_m + ARM_REACH_M * theta * theta / 8.0
        axes = np.stack([*self.arm.segments(joints), *self.arm.segments(target)])  # 4, G, 3
        lowest = axes[:, :, 2].min(axis=0) - self.arm.radii
        if lowest[self.arm.touch_table].min() < C.TABLE_TOP_Z_M + reach:
            return float(self.step_clearances(joints, np.asarray(action)[None])[0])
        if len(self.points):
            # Per geom, the box around its axis at both ends widened by its radius and reach.
            widen = (self.arm.radii + reach)[:, None]
            box_low, box_high = axes.min(axis=0) - widen, axes.max(axis=0) + widen
            points = self.points[:, None]
            if ((points > box_low) & (points < box_high)).all(axis=2).any():
                return float(self.step_clearances(joints, np.asarray(action)[None])[0])
        return self.margin_m

    def step_clearances(self, joints: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """`shield.step_clearance` of each of actions (A, 6), all checks in one batch: (A,)."""
        checks = [step_checks(joints, action) for action in actions]
        values = self.clearances(np.concatenate(checks))
        starts = np.cumsum([0] + [len(c) for c in checks[:-1]])
        return np.minimum.reduceat(values, starts)


class DepthShield:
    """Any vision policy acting through the depth shield (a `Policy`).

    `policy`: a `Policy` observing images (and joints and goal); `num_views`, `image_size`:
    its observation's; `extrude_m`: the hidden side of each seen surface is taken as filled
    this deep (`DepthOccupancy`). Counts `num_shielded` of `num_steps`.
    """

    def __init__(
        self,
        policy,
        num_views: int,
        image_size: int,
        margin_m: float = MARGIN_M,
        seed: int = 0,
        sliding: bool = True,
        extrude_m: float = 0.0,
    ) -> None:
        from clamgen.experiments.shield import perturbations

        if not 0 <= margin_m < float("inf"):
            raise ValueError(f"margin_m must be a number >= 0, got {margin_m}")
        self.policy = policy
        arm = ArmCapsules()
        self.occupancy = DepthOccupancy(num_views, image_size, image_size, arm, extrude_m)
        self.checker = DepthClearance(arm, margin_m)
        self.perturbations = perturbations(seed)
        self.sliding = sliding
        self.num_steps = 0
        self.num_shielded = 0

    @property
    def agent(self):
        return getattr(self.policy, "agent", None)

    def reset(self, env: Any | None = None) -> None:
        self.occupancy.reset()
        self.policy.reset(env)

    def act(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        action = np.asarray(self.policy.act(obs), np.float64)
        return self.shield(self.observe(obs), action)

    def observe(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Add what `obs` shows to the obstacle map; the arm's joints."""
        self.checker.points = self.occupancy.update(obs)
        return np.asarray(obs["observation"], np.float64)[: ur5.NUM_JOINTS]

    def shield(self, joints: np.ndarray, action: np.ndarray) -> np.ndarray:
        """The shield's choice for `action` at `joints` (`shield.choose_action`)."""
        from clamgen.experiments.shield import choose_action

        self.num_steps += 1
        pre = np.arctanh(np.clip(action, -0.995, 0.995))
        chosen, shielded = choose_action(
            self.checker, joints, action, pre, self.perturbations, self.sliding
        )
        self.num_shielded += int(shielded)
        return chosen
