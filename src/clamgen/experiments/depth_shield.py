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

from clamgen.experiments.depth_kernels import (
    any_in_boxes,
    capsule_clearances,
    dh_frames,
    hidden_configurations,
    hidden_points,
    lift_pixels,
    rays_within_capsules,
    supported,
    surface_candidates,
    told_off_table_and_target,
    within_capsules,
)
from clamgen.experiments.shield import checks_to, step_checks_many, step_target
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
validation tasks, the `residual-3views` of that time with the planner: 0.963 success with
2 cm, 0.920 with 6 mm, where 65 of 191 plans found no path)."""
TARGET_REACH_M = C.TARGET_RADIUS_M + TARGET_FILTER_M
PEDESTAL_RADIUS_M = 0.09
PEDESTAL_TOP_M = 0.01
"""The pedestal (a 7.5 cm cylinder up to z = 0) is not an obstacle."""
SUPPORT_RADIUS_M = 0.03
"""A new obstacle point counts only with another obstacle point (new or kept) within this:
a lone pixel is not a surface (the renderer leaves a rare stray pixel)."""
_SUPPORT_REACH = float(np.nextafter(SUPPORT_RADIUS_M, 0.0))
"""The support test's radius: points strictly nearer than `SUPPORT_RADIUS_M` support."""
FAR_CLIP_M = C.DEPTH_RANGE_M[1] - 0.05
"""Depth at or beyond the stored range's far end is background."""
MARGIN_M = 0.01
"""Clearance the depth shield keeps: about a voxel (chosen on validation tasks)."""
NOISE_SIGMAS = 3.0
"""With a depth noise model (`DepthOccupancy(noise_m=...)`): a point is taken for arm, table or
target where moving it this many standard deviations along its ray would make it one."""
ARM_REACH_M = 1.2
"""Farther than any point of the arm gets from the base (UR5 reach 0.85 m, and the gripper)."""
SHADOW_GEOMS = ("wrist_3", "gripper", "suction_cup")
"""The geoms `ArmShadow` keeps out of the space the arm hides: the hand, which hides the most
right where it moves next."""
SHADOW_SPACING_M = 0.015
"""Spacing of the points on those geoms' surfaces that `ArmShadow` checks."""
SHADOW_TOLERANCE_M = 0.01
"""A point less than this behind the deepest depth seen at its pixel counts as seen (the
stored depth's step is 8.6 mm)."""
_SHADOW_TOLERANCE = np.float32(SHADOW_TOLERANCE_M)  # (added to float32 depths)
HIDDEN_CLEARANCE_M = -0.01
"""The clearance `DepthClearance` gives a configuration that reaches into hidden space."""
DEPTH_OF_CODE = uint8_to_depth(np.arange(256, dtype=np.uint8))
"""Metric depth of each stored depth code (the same values as `uint8_to_depth`, looked up)."""
_FAR_CLIP = np.float32(FAR_CLIP_M)
_ABOVE_TABLE_Z = np.float32(C.TABLE_TOP_Z_M + ABOVE_TABLE_M)
"""The lift's thresholds in float32, as its depths and heights (`lift_pixels`)."""
_TOLD_ABOVE_TABLE_Z = C.TABLE_TOP_Z_M + ABOVE_TABLE_M
"""The same in float64, as the told table test compares."""
GRID_LOW_M = np.array([-1.0, -1.0, C.TABLE_TOP_Z_M])
GRID_HIGH_M = np.array([1.5, 1.0, 1.2])
"""The voxel grid's bounds (the table's top and the workspace above it); points outside are
not kept."""


_warmed_up = False


def warm_up() -> None:
    """Load the compiled kernels the shield and its planner call, once per process, so that
    the first act of the first episode does not (numba loads each kernel from its on-disk
    cache at its first call, after starting itself: 0.2-0.4 s on these CPUs). Each kernel is
    called on empty inputs of the exact types the shield passes it (numba keeps one machine
    code per argument types; a test checks that shielded episodes add none), so nothing is
    computed."""
    global _warmed_up
    if _warmed_up:
        return
    nothing = np.empty((0, 3))
    box = np.zeros((1, 3))
    any_in_boxes(nothing, box, box)
    # The arm's capsules: batched configurations (strided views of one array), and one
    # configuration (contiguous).
    axes = np.zeros((1, 2, 2, 3))
    capsule_clearances(axes[:, :, 0], axes[:, :, 1], np.zeros(2), nothing, 0.0)
    capsule_clearances(np.zeros((1, 2, 3)), np.zeros((1, 2, 3)), np.zeros(2), nothing, 0.0)
    within_capsules(nothing, box, box, np.zeros(1))
    rays_within_capsules(nothing, nothing, box, box, np.zeros(1))  # with a noise model
    supported(nothing, nothing, _SUPPORT_REACH)
    told_off_table_and_target(
        nothing, np.empty(0, np.int64), np.zeros((1, 3), np.float32), box, box, 1, 0.0,
        NOISE_SIGMAS, _TOLD_ABOVE_TABLE_Z, np.zeros(3), TARGET_REACH_M,
    )  # fmt: skip
    frames = _frames(ur5.HOME_JOINTS)
    flat = np.zeros((1, 3), np.float32)
    lift_pixels(
        np.zeros(1, np.uint8), np.empty(0, np.int64), DEPTH_OF_CODE, flat, flat, _FAR_CLIP,
        _ABOVE_TABLE_Z,
    )  # fmt: skip
    cells = np.ones(3, np.int64)
    surface_candidates(
        nothing, np.zeros(3), TARGET_REACH_M**2, PEDESTAL_RADIUS_M**2, PEDESTAL_TOP_M,
        GRID_LOW_M, 1.0 / VOXEL_M, cells, np.zeros(1, bool),
    )  # fmt: skip
    # `ArmShadow._views()` and `_filled()`'s types: a camera that has seen nothing.
    views = (
        np.zeros((1, 3)), np.zeros((1, 3, 3)), np.ones((1, 4)), 1, 1,
        np.zeros(1, np.float32), np.zeros(1, bool), _SHADOW_TOLERANCE,
    )  # fmt: skip
    filled = (nothing, nothing, np.empty(0), GRID_LOW_M, VOXEL_M, cells)
    shell_group = np.empty(0, np.int64)
    hidden_configurations(
        frames[:0, :1], nothing, shell_group, np.zeros(1), nothing, 0.05, views, filled
    )
    _warmed_up = True


def _in_boxes(points: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Whether each of `points` (P, 3) lies strictly between `low` and `high`: (P,) for one box
    ((3,) bounds), (P, B) for B boxes ((B, 3) bounds). One coordinate at a time: numpy's
    `all` over a last axis of three costs more than the comparisons themselves."""
    inside = None
    for axis in range(3):
        column = points[:, axis, None] if np.ndim(low) == 2 else points[:, axis]
        this = (column > low[..., axis]) & (column < high[..., axis])
        inside = this if inside is None else inside & this
    return inside


def _frames(joints: np.ndarray) -> np.ndarray:
    """DH frames 1..6 (B, 6, 4, 4) at joints (B, 6) or (6,) (compiled: `dh_frames`)."""
    joints = np.asarray(joints, np.float64).reshape(-1, ur5.NUM_JOINTS)
    return dh_frames(joints, ur5.DH_D, ur5.DH_A, ur5.DH_ALPHA)


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
        frames = _frames(joints)[:, self._frame]  # B, G
        ends = self._local[None] @ frames[..., :3, :3].transpose(0, 1, 3, 2)  # B, G, 2, 3
        ends = ends + frames[..., None, :3, 3]
        return ends[:, :, 0], ends[:, :, 1]

    def clearances(self, joints: np.ndarray, points: np.ndarray, cap: float) -> np.ndarray:
        """`clearance` at each of joints (B, 6), capped at `cap`: (B,) (the points by
        `capsule_clearances`, which measures only the pairs of a point and a geom whose box
        holds the point: the rest are farther than `cap`)."""
        starts, ends = self.segments_many(joints)  # B, G, 3
        lowest = np.minimum(starts[..., 2], ends[..., 2]) - self.radii
        out = np.minimum(cap, (lowest[:, self.touch_table] - C.TABLE_TOP_Z_M).min(axis=1))
        if len(points) == 0:
            return out
        return np.minimum(out, capsule_clearances(starts, ends, self.radii, points, cap))

    def near(self, points: np.ndarray, starts: np.ndarray, ends: np.ndarray, reach: float):
        """Indices of `points` in the box around the arm's segments widened by its largest
        radius and `reach`: the only ones that can lie within `reach` of its surface."""
        reach = self.radii.max() + reach
        low = np.minimum(starts, ends).min(axis=0) - reach
        high = np.maximum(starts, ends).max(axis=0) + reach
        return np.flatnonzero(_in_boxes(points, low, high))

    def clearance(self, joints: np.ndarray, points: np.ndarray, cap: float = np.inf) -> float:
        """Distance (m) of the arm at `joints` to the nearest of `points` (P, 3) or to the table
        (negative: touching), or `cap` when both are farther."""
        starts, ends = self.segments(joints)
        lowest = np.minimum(starts[:, 2], ends[:, 2]) - self.radii
        table = min(cap, float((lowest[self.touch_table] - C.TABLE_TOP_Z_M).min()))
        if len(points) == 0:
            return table
        surface = capsule_clearances(starts[None], ends[None], self.radii, points, cap)[0]
        return min(table, float(surface))


class DepthOccupancy:
    """Obstacle surface points seen so far in an episode, from RGBD views of the fixed cameras.

    `num_views`, `height`, `width`: the observation's views (the first `num_views` cameras of
    `constants.CAMERAS`) and image size. `extrude_m`: the hidden side of each seen surface is
    taken as filled this deep. `bridge_m`: a new obstacle point and a pixel neighbour's up to
    this far apart are joined by surface (a side seen at a grazing angle leaves its pixels'
    points centimetres apart; farther apart, the neighbour is an edge in front of something
    behind). Measured on 1-view validation tasks with 0.05 m: no change in collisions
    (`results/stage2/shield/README.md`). 0 turns either off. `noise_m` > 0: the depth
    camera's noise model, sd `noise_m * z**2` along each ray at depth z (m; `ReachEnv`'s
    `depth_noise_m`): a point within `NOISE_SIGMAS` sds along its ray of the arm or the table
    or the target is taken for it (`_off_table_and_target`). The filters are set for exact
    depth otherwise.
    """

    def __init__(
        self,
        num_views: int,
        height: int,
        width: int,
        arm: ArmCapsules | None = None,
        extrude_m: float = 0.0,
        bridge_m: float = 0.0,
        noise_m: float = 0.0,
    ):
        if not 0 <= bridge_m < float("inf"):
            raise ValueError(f"bridge_m must be a number >= 0, got {bridge_m}")
        if not 0 <= noise_m < float("inf"):
            raise ValueError(f"noise_m must be a number >= 0, got {noise_m}")
        self.arm = arm if arm is not None else ArmCapsules()
        self.extrude_m = extrude_m
        self.bridge_m = bridge_m
        self.noise_m = noise_m
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
        # Per view, the optical axis (the camera looks along its -z): a point's depth z.
        axes = -scene.data.cam_xmat[scene.camera_ids[:num_views]].reshape(-1, 3, 3)[:, :, 2]
        self._view_origins = origins.astype(np.float64)
        self._view_axes = np.ascontiguousarray(axes)
        self.shape = (num_views, height, width)
        self._dims = np.ceil((GRID_HIGH_M - GRID_LOW_M) / VOXEL_M).astype(np.int64)
        self._grid = np.zeros(int(np.prod(self._dims)), bool)
        self._strides = np.array([self._dims[1] * self._dims[2], self._dims[2], 1])
        self._cells = np.empty(0, np.int64)
        self.points = np.empty((0, 3))
        self._last_depth: np.ndarray | None = None
        # Per pixel, the obstacle point it showed (NaN: none yet), for `bridge_m`; and its four
        # neighbours in the same view, right, below, left and above (-1: off the image).
        self._pixel_points = np.full((num_views * height * width, 3), np.nan)
        pixel = np.arange(num_views * height * width).reshape(num_views, height, width)
        right, below = np.full_like(pixel, -1), np.full_like(pixel, -1)
        right[:, :, :-1], below[:, :-1] = pixel[:, :, 1:], pixel[:, 1:]
        left, above = np.full_like(pixel, -1), np.full_like(pixel, -1)
        left[:, :, 1:], above[:, 1:] = pixel[:, :, :-1], pixel[:, :-1]
        self._neighbours = np.stack([right, below, left, above], -1).reshape(-1, 4)

    def reset(self) -> None:
        self._last_depth = None
        self._pixel_points[:] = np.nan
        self._grid[self._cells] = False
        self._cells = np.empty(0, np.int64)
        self.points = np.empty((0, 3))

    def lift(
        self,
        images: np.ndarray,
        changed_only: bool = False,
        with_rays: bool = False,
        with_pixels: bool = False,
    ) -> np.ndarray | tuple[np.ndarray, ...]:
        """World points (N, 3) of the views' depth pixels that are not background and lie
        above the table; with `changed_only`, of those whose depth grew since the last call.
        Only these can show static surface not yet looked at: a pixel that shows the same
        depth shows the same point, and one whose depth shrank shows the arm (the rest of
        the scene stands still, so a nearer surface where there was none is the arm that
        moved in front; quantising depth keeps the order). With `with_rays`, also their unit
        viewing directions (N, 3); with `with_pixels`, also their flat pixel indices (N,)."""
        images = np.asarray(images)
        if images.shape[0] != self.shape[0] or images.shape[2:] != self.shape[1:]:
            raise ValueError(
                f"expected images of shape (V, 4 or 1, H, W) with (V, H, W) = {self.shape}, "
                f"got {images.shape}"
            )
        codes = images[:, -1].reshape(-1)  # RGBD or depth alone: depth comes last
        if changed_only and self._last_depth is not None:
            pixels = np.flatnonzero(codes > self._last_depth)
        else:
            pixels = np.arange(len(codes))
        points, keep = lift_pixels(
            codes, pixels, DEPTH_OF_CODE, self.origins, self.rays, _FAR_CLIP, _ABOVE_TABLE_Z
        )
        if changed_only:
            self._last_depth = codes.copy()
        extras = ([self.directions[keep]] if with_rays else []) + ([keep] if with_pixels else [])
        return (points, *extras) if extras else points

    def voxels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The grid indices (N, 3) of the voxels holding `points` (N, 3), and which of them
        lie inside the grid (N,)."""
        voxels = np.floor((points - GRID_LOW_M) * (1.0 / VOXEL_M)).astype(np.int64)
        return voxels, _in_boxes(voxels, np.full(3, -1), self._dims)

    def voxel_centres(self, cells: np.ndarray) -> np.ndarray:
        return GRID_LOW_M + (np.stack(np.unravel_index(cells, self._dims), axis=1) + 0.5) * VOXEL_M

    def new_obstacle_cells(
        self, images: np.ndarray, joints: np.ndarray, goal: np.ndarray
    ) -> np.ndarray:
        """Voxels (flat indices) of obstacle surface in `images` not yet kept: lifted points
        above the table, off the target, the pedestal and the arm at `joints`, with another
        such point near."""
        points, *directions, pixels = self.lift(
            images, changed_only=True, with_rays=self.extrude_m > 0, with_pixels=True
        )
        goal = np.asarray(goal, np.float64)
        sigma = None
        if self.noise_m > 0:
            points, pixels, directions, sigma = self._off_table_and_target(
                points, pixels, directions, goal
            )
        index, cells, new = surface_candidates(
            points,
            goal,
            TARGET_REACH_M**2,
            PEDESTAL_RADIUS_M**2,
            PEDESTAL_TOP_M,
            GRID_LOW_M,
            1.0 / VOXEL_M,
            self._dims,
            self._grid,
        )  # the lifted points still in question: off the pedestal and target, in the grid
        if self.bridge_m > 0:  # points on surface already kept can be bridged to
            self._pixel_points[pixels[index[~new]]] = points[index[~new]]
        index, cells = index[new], cells[new]
        if len(index):
            off_arm = self._off_arm(
                points[index], joints, pixels[index], None if sigma is None else sigma[index]
            )
            index, cells = index[off_arm], cells[off_arm]
        if len(index):
            mine = points[index]
            low, high = mine.min(axis=0) - SUPPORT_RADIUS_M, mine.max(axis=0) + SUPPORT_RADIUS_M
            kept = self.points[_in_boxes(self.points, low, high)]  # (farther out: none near)
            # Another point within the radius (strictly: the largest float below it,
            # inclusive), on a grid: the steps with many new points have thousands.
            near = supported(mine, kept, _SUPPORT_REACH)
            index, cells = index[near], cells[near]
        if len(index) == 0:
            return cells
        if self.extrude_m > 0:
            behind = self._behind(points[index], directions[0][index], joints)
            cells = np.concatenate([cells, behind])
        if self.bridge_m > 0:
            cells = np.concatenate([cells, self._bridges(points[index], pixels[index], goal)])
        return np.unique(cells)

    def _bridges(self, points: np.ndarray, pixels: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Cells on the straight segments between each new obstacle point and its pixel
        neighbours' obstacle points up to `bridge_m` away (taken as one surface: between
        pixel centres the camera sees no sample of it), voxel-spaced, off the target."""
        self._pixel_points[pixels] = points
        neighbours = self._neighbours[pixels]  # N, 4
        other = self._pixel_points[np.where(neighbours >= 0, neighbours, 0)]  # N, 4, 3
        gap = np.linalg.norm(other - points[:, None], axis=-1)
        near = (neighbours >= 0) & (gap > VOXEL_M) & (gap <= self.bridge_m)  # NaN: False
        if not near.any():
            return np.empty(0, np.int64)
        starts, ends = np.broadcast_to(points[:, None], other.shape)[near], other[near]
        steps = int(np.ceil(self.bridge_m / VOXEL_M))
        along = np.arange(1, steps) / steps  # interior points, at most a voxel apart
        between = (starts[:, None] + along[None, :, None] * (ends - starts)[:, None]).reshape(-1, 3)
        off_target = between - np.asarray(goal)
        between = between[np.einsum("ij,ij->i", off_target, off_target) > TARGET_REACH_M**2]
        voxels, inside = self.voxels(between)
        return voxels[inside] @ self._strides

    def _off_arm(
        self,
        points: np.ndarray,
        joints: np.ndarray,
        pixels: np.ndarray | None = None,
        sigma: np.ndarray | None = None,
    ) -> np.ndarray:
        """Which of `points` lie farther than `ARM_FILTER_M` from the arm at `joints` (the test
        runs on every pixel the arm's motion changed: compiled, `within_capsules`); with a
        noise model, given their `pixels` and noise sds `sigma` (`_off_table_and_target`), at
        every point up to `NOISE_SIGMAS` sds along their rays."""
        starts, ends = self.arm.segments(joints)
        reach = self.arm.radii + ARM_FILTER_M
        if self.noise_m <= 0 or sigma is None:
            return ~within_capsules(points, starts, ends, reach)
        shifts = NOISE_SIGMAS * sigma[:, None] * self.rays[pixels]  # P, 3
        return ~rays_within_capsules(points, shifts, starts, ends, reach)

    def _off_table_and_target(
        self, points: np.ndarray, pixels: np.ndarray, directions: list, goal: np.ndarray
    ):
        """`points`, `pixels` and `directions` but those that `NOISE_SIGMAS` sds along their
        rays would put on the table (less than `ABOVE_TABLE_M` above its top) or on the target
        (within `TARGET_REACH_M` of `goal`, tested along the ray as the arm filter is:
        `rays_within_capsules`, the target a capsule of no length), and the kept points' noise
        sds (`noise_m` times their view depth squared: a depth error d moves a point by d times
        its pixel's `rays`), in one compiled pass (`told_off_table_and_target`)."""
        keep, sigma = told_off_table_and_target(
            points,
            pixels,
            self.rays,
            self._view_origins,
            self._view_axes,
            self.shape[1] * self.shape[2],
            self.noise_m,
            NOISE_SIGMAS,
            _TOLD_ABOVE_TABLE_Z,
            goal,
            TARGET_REACH_M,
        )
        return points[keep], pixels[keep], [d[keep] for d in directions], sigma

    def _behind(self, points: np.ndarray, directions: np.ndarray, joints: np.ndarray):
        """Cells up to `extrude_m` behind surface points along their viewing rays (an obstacle
        is at least that thick: the side hidden from the cameras is taken as filled), off the
        arm."""
        steps = np.arange(1, round(self.extrude_m / VOXEL_M) + 1) * VOXEL_M
        behind = (points[:, None] + steps[None, :, None] * directions[:, None]).reshape(-1, 3)
        voxels, inside = self.voxels(behind)
        behind, voxels = behind[inside], voxels[inside]
        return (voxels @ self._strides)[self._off_arm(behind, joints)]

    def update(self, obs: Mapping[str, np.ndarray], key: str = "images") -> np.ndarray:
        """Add the obstacle surface seen in `obs[key]` (the RGBD views, or `fine_depth`) to
        the episode's voxels; all voxel centres."""
        joints = np.asarray(obs["observation"], np.float64)[: ur5.NUM_JOINTS]
        cells = self.new_obstacle_cells(obs[key], joints, obs["desired_goal"])
        if len(cells):
            self._grid[cells] = True
            self._cells = np.concatenate([self._cells, cells])
            self.points = np.concatenate([self.points, self.voxel_centres(cells)])
        return self.points


class ArmShadow:
    """The space the arm has hidden from every camera since the episode began (beyond the
    paper's method, like the rest of this module).

    A camera sees nothing behind the arm: an obstacle right behind the gripper leaves no
    pixel, and a policy from one view walks the gripper into it (most of the depth shield's
    collisions with one view). Per pixel, the deepest depth seen in the episode bounds the
    space seen free along its ray (the scene stands still; only the arm moves, in front of
    it). A point is *hidden* when every view that frames it shows something nearer, and in
    one of them that nearer surface is the arm's, that is, the arm has been in front of it
    ever since the episode began. Space the arm itself has filled is free. `hidden` tells
    which configurations would put the distal geoms (`SHADOW_GEOMS`) into hidden space within
    `near_m` of obstacle surface seen so far; the depth shield refuses such steps
    (`DepthClearance`), so the hand moves into what it hid only once a camera has seen it.
    With `behind_surfaces`, any surface seen hides what lies behind it (the far sides of
    obstacles too), not only the arm. (`hides`: per pixel, whether the deepest surface seen
    there hides the space behind it.)
    """

    def __init__(
        self, occupancy: DepthOccupancy, near_m: float = 0.05, behind_surfaces: bool = False
    ) -> None:
        if not 0 < near_m < float("inf"):
            raise ValueError(f"near_m must be a number > 0, got {near_m}")
        self.occupancy = occupancy
        self.near_m = near_m
        self.behind_surfaces = behind_surfaces
        arm = occupancy.arm
        scene = arm.scene
        views, height, width = occupancy.shape
        cameras = scene.camera_ids[:views]
        self.rotations = scene.data.cam_xmat[cameras].reshape(-1, 3, 3).copy()
        self.positions = scene.data.cam_xpos[cameras].copy()
        self.intrinsics = np.array(
            [camera_intrinsics(scene.model, c, height, width) for c in cameras]
        )  # V, (fx, fy, cx, cy)
        names = [scene.model.geom(int(g)).name for g in arm.geoms]
        self.geoms = np.array([names.index(name) for name in SHADOW_GEOMS])
        # The geoms' surface points, fixed in the DH frames of their links (as ArmCapsules
        # keeps its axes), so that one batched kinematics call places them.
        starts, ends = arm.segments(ur5.HOME_JOINTS)
        home_frames = forward_kinematics(ur5.HOME_JOINTS)
        shells = []
        for g in self.geoms:
            shell = _capsule_shell(arm.radii[g], arm.half_lengths[g])
            axis = (ends[g] - starts[g]) / np.linalg.norm(ends[g] - starts[g])
            world = 0.5 * (starts[g] + ends[g]) + shell @ _frames_along(axis[None])[0].T
            inverse = np.linalg.inv(home_frames[arm._frame[g]])
            shells.append(world @ inverse[:3, :3].T + inverse[:3, 3])
        self._shell = np.concatenate(shells)  # P, 3
        shell_frame = np.concatenate(
            [
                np.full(len(shell), arm._frame[g])
                for g, shell in zip(self.geoms, shells, strict=True)
            ]
        )
        # The frames that carry shell points (the hand's geoms share one link), and per point
        # its frame's place among them.
        self._group_frames, self._shell_group = np.unique(shell_frame, return_inverse=True)
        # Per group, how far its shell points lie from their frame's origin (a box around the
        # origins widened by this holds every shell point).
        distance = np.linalg.norm(self._shell, axis=1)
        self._group_radii = np.array(
            [distance[self._shell_group == g].max() for g in range(len(self._group_frames))]
        )
        self._reach = arm.radii[self.geoms] + 0.5 * np.sqrt(3.0) * VOXEL_M
        self.deepest = np.full(views * height * width, -np.inf, np.float32)
        self._deepest_code = np.full(views * height * width, -1, np.int16)  # (-1: none yet)
        self.hides = np.zeros(views * height * width, bool)
        self.reset()

    def reset(self) -> None:
        self.deepest[:] = -np.inf
        self._deepest_code[:] = -1
        self.hides[:] = False
        # The distal geoms' axes at every configuration seen this episode: the space they
        # filled (voxels whose centre lies within a half diagonal of a geom) is free.
        self._filled_starts: list[np.ndarray] = []
        self._filled_ends: list[np.ndarray] = []
        self._filled_segments: tuple | None = None  # (their concatenation, once a step)

    def update(self, images: np.ndarray, joints: np.ndarray) -> None:
        """Deepen each pixel's seen depth with `images` (taken at `joints`) and take the space
        the distal geoms fill as free."""
        occupancy = self.occupancy
        code = np.asarray(images)[:, -1].reshape(-1)
        deeper = np.flatnonzero(code > self._deepest_code)  # depth grows with its code
        self._deepest_code[deeper] = code[deeper]
        depth = DEPTH_OF_CODE[code[deeper]]
        self.deepest[deeper] = depth
        if self.behind_surfaces:  # any surface seen hides what lies behind it
            self.hides[deeper] = depth < FAR_CLIP_M
        else:  # only the arm does
            points = occupancy.origins[deeper] + depth[:, None] * occupancy.rays[deeper]
            self.hides[deeper] = ~occupancy._off_arm(points, joints)
        starts, ends = occupancy.arm.segments(joints)
        starts, ends = starts[self.geoms], ends[self.geoms]
        if (
            self._filled_starts
            and np.array_equal(starts, self._filled_starts[-1])
            and np.array_equal(ends, self._filled_ends[-1])
        ):
            return  # the arm stood still (pressed against an obstacle): nothing newly filled
        self._filled_starts.append(starts)
        self._filled_ends.append(ends)
        self._filled_segments = None

    def _views(self) -> tuple:
        """The cameras and what each pixel has seen, for the compiled tests."""
        _, height, width = self.occupancy.shape
        return (
            self.positions,
            self.rotations,
            self.intrinsics,
            height,
            width,
            self.deepest,
            self.hides,
            _SHADOW_TOLERANCE,
        )

    def _filled(self) -> tuple:
        """The segments the hand filled (its geoms' axes at every configuration seen) with
        their reach, and the voxel grid, for the compiled tests."""
        if self._filled_segments is None:
            starts = np.concatenate(self._filled_starts or [np.empty((0, 3))])
            ends = np.concatenate(self._filled_ends or [np.empty((0, 3))])
            reach = np.tile(self._reach, len(self._filled_starts))
            self._filled_segments = (starts, ends, reach)
        dims = self.occupancy._dims
        return (*self._filled_segments, GRID_LOW_M, VOXEL_M, dims)

    def hidden(self, joints: np.ndarray, obstacle: np.ndarray) -> np.ndarray:
        """Whether the distal geoms at each of joints (B, 6) reach into hidden space within
        `near_m` of a point of `obstacle` (P, 3) seen so far: (B,)."""
        frames = _frames(joints)
        # Compiled: the obstacle points near the hand's frames, then per configuration its
        # shell points in the box around those, behind a hiding surface in the views, near
        # seen obstacle surface, not filled by the hand before (stopping at the first).
        return hidden_configurations(
            frames[:, self._group_frames],
            self._shell,
            self._shell_group,
            self._group_radii + self.near_m + SHADOW_SPACING_M,
            obstacle,
            self.near_m,
            self._views(),
            self._filled(),
        )

    def hidden_points(self, points: np.ndarray) -> np.ndarray:
        """Which of `points` (P, 3) are hidden: no view has seen them free, and one has had a
        hiding surface (the arm, or with `behind_surfaces` any) in front of them since the
        episode began (space the hand filled is free)."""
        points = np.asarray(points, np.float64)
        return hidden_points(points, self._views(), self._filled())


def _capsule_shell(radius: float, half_length: float) -> np.ndarray:
    """Points (P, 3) on a capsule's surface about `SHADOW_SPACING_M` apart, its axis along z."""
    rings = max(2, int(np.ceil(2 * half_length / SHADOW_SPACING_M)) + 1)
    around = max(6, int(np.ceil(2 * np.pi * radius / SHADOW_SPACING_M)))
    angle = np.arange(around) * 2 * np.pi / around
    circle = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)
    points = [
        np.concatenate([circle, np.full((around, 1), z)], 1)
        for z in np.linspace(-half_length, half_length, rings)
    ]
    caps = np.array([[0.0, 0.0, -half_length - radius], [0.0, 0.0, half_length + radius]])
    return np.concatenate([*points, caps])


def _frames_along(axes: np.ndarray) -> np.ndarray:
    """Rotations (B, 3, 3) whose third column is each unit axis (B, 3)."""
    helper = np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    first = np.cross(axes, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.cross(axes, first)
    return np.stack([first, second, axes], axis=2)


class DepthClearance:
    """`clamgen.experiments.shield.choose_action`'s checker on the depth shield's points."""

    def __init__(self, arm: ArmCapsules, margin_m: float, shadow: ArmShadow | None = None) -> None:
        self.arm = arm
        self.margin_m = margin_m
        self.shadow = shadow
        self.points = np.empty((0, 3))

    def clearance(self, joints: np.ndarray, cap: float | None = None) -> float:
        """The arm's clearance at `joints` to the kept points and the table, capped at `cap`
        (the margin by default); `HIDDEN_CLEARANCE_M` when it reaches into hidden space."""
        cap = self.margin_m if cap is None else cap
        value = self.arm.clearance(joints, self.points, cap=cap)
        if self.shadow is not None and self.shadow.hidden(joints, self.points)[0]:
            return min(value, HIDDEN_CLEARANCE_M)
        return value

    def clearances(
        self, joints: np.ndarray, visible: bool = False, hidden: np.ndarray | None = None
    ) -> np.ndarray:
        """`clearance` at each of joints (B, 6); `visible`: none of them is known to reach
        into hidden space (the test is skipped); `hidden`: which of them do, when the caller
        has tested it already."""
        values = self.arm.clearances(joints, self.points, cap=self.margin_m)
        if self.shadow is not None and not visible:
            if hidden is None:
                hidden = self.shadow.hidden(joints, self.points)
            values = np.where(hidden, np.minimum(values, HIDDEN_CLEARANCE_M), values)
        return values

    def step_clearance(self, joints: np.ndarray, action: np.ndarray) -> float:
        """`shield.step_clearance`, with a shortcut for the usual step far from everything:
        when no kept point lies in the box around any of the arm's geoms at both ends of the
        step, and the arm's lowest point at both ends is well above the table, every check
        along the step would return the margin. (Between its ends a point of the arm strays
        from the straight line by at most R theta^2 / 8, R its distance from the base and
        theta the joints' summed change: about 3 mm for a typical step; the boxes are widened
        by that bound.) Otherwise the step's checks are built once and tested in one batch."""
        target = step_target(joints, action)
        theta = float(np.abs(target - joints).sum())
        reach = self.margin_m + ARM_REACH_M * theta * theta / 8.0
        starts, ends = self.arm.segments_many(np.stack([joints, target]))  # 2, G, 3 each
        axes = np.concatenate([starts, ends])  # 4, G, 3
        lowest = axes[:, :, 2].min(axis=0) - self.arm.radii
        if lowest[self.arm.touch_table].min() < C.TABLE_TOP_Z_M + reach:
            return float(self.clearances(checks_to(joints, target)).min())
        visible = False  # True once no check of the step is known to reach into hidden space
        checks = None
        if len(self.points) and self.shadow is not None:
            # The hand reaches into hidden space only near a kept point: within `near_m` of
            # its surface along the step.
            hand = self.shadow.geoms
            widen = self.arm.radii[hand] + self.shadow.near_m + reach
            low = (axes[:, hand].min(axis=0) - widen[:, None]).min(axis=0)
            high = (axes[:, hand].max(axis=0) + widen[:, None]).max(axis=0)
            if any_in_boxes(self.points, low[None], high[None]):
                checks = checks_to(joints, target)
                hidden = self.shadow.hidden(checks, self.points)
                if hidden.any():
                    return float(self.clearances(checks, hidden=hidden).min())
                visible = True
        if len(self.points):
            # Per geom, the box around its axis at both ends widened by its radius and reach.
            widen = (self.arm.radii + reach)[:, None]
            if any_in_boxes(self.points, axes.min(axis=0) - widen, axes.max(axis=0) + widen):
                checks = checks_to(joints, target) if checks is None else checks
                return float(self.clearances(checks, visible).min())
        return self.margin_m

    def step_clearances(
        self, joints: np.ndarray, actions: np.ndarray, visible: bool = False
    ) -> np.ndarray:
        """`shield.step_clearance` of each of actions (A, 6), all checks in one batch: (A,);
        `visible` as for `clearances`."""
        checks, starts = step_checks_many(joints, actions)
        return np.minimum.reduceat(self.clearances(checks, visible), starts)


class DepthShield:
    """Any vision policy acting through the depth shield (a `Policy`).

    `policy`: a `Policy` observing images (and joints and goal); `num_views`, `image_size`:
    its observation's; `fine_depth_size` > 0: the shield reads the views' depth at this size
    from the observation's `fine_depth` instead (`ReachEnv(fine_depth_size=...)`, a finer
    depth camera at the same poses; the policy still acts on its own images); `extrude_m`:
    the hidden side of each seen surface is taken as filled this deep (`DepthOccupancy`);
    `shadow`: the hand keeps out of the space the arm has hidden since the episode began
    (`ArmShadow`); `bridge_m`: neighbouring pixels' obstacle points up to this far apart are
    joined by surface (`DepthOccupancy`); `noise_m`: the depth camera's noise model
    (`DepthOccupancy`). Counts `num_shielded` of `num_steps`.
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
        shadow_m: float | None = None,
        shadow_behind_surfaces: bool = False,
        bridge_m: float = 0.0,
        fine_depth_size: int = 0,
        noise_m: float = 0.0,
    ) -> None:
        from clamgen.experiments.shield import perturbations

        if not 0 <= margin_m < float("inf"):
            raise ValueError(f"margin_m must be a number >= 0, got {margin_m}")
        if fine_depth_size < 0:
            raise ValueError(f"fine_depth_size must be >= 0, got {fine_depth_size}")
        warm_up()
        self.policy = policy
        self.depth_key = "fine_depth" if fine_depth_size else "images"
        size = fine_depth_size or image_size
        arm = ArmCapsules()
        self.occupancy = DepthOccupancy(num_views, size, size, arm, extrude_m, bridge_m, noise_m)
        self.shadow = None
        if shadow_m is not None:
            self.shadow = ArmShadow(self.occupancy, shadow_m, shadow_behind_surfaces)
        self.checker = DepthClearance(arm, margin_m, self.shadow)
        self.perturbations = perturbations(seed)
        self.sliding = sliding
        self.num_steps = 0
        self.num_shielded = 0

    @property
    def agent(self):
        return getattr(self.policy, "agent", None)

    def reset(self, env: Any | None = None) -> None:
        self.occupancy.reset()
        if self.shadow is not None:
            self.shadow.reset()
        self.policy.reset(env)

    def act(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        joints = self.observe(obs)  # (first: a policy inside may read the map, e.g. escapes)
        return self.shield(joints, np.asarray(self.policy.act(obs), np.float64))

    def observe(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Add what `obs` shows to the obstacle map; the arm's joints."""
        self.checker.points = self.occupancy.update(obs, self.depth_key)
        joints = np.asarray(obs["observation"], np.float64)[: ur5.NUM_JOINTS]
        if self.shadow is not None:
            self.shadow.update(obs[self.depth_key], joints)
        return joints

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
