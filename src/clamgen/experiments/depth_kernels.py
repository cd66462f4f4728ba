"""Compiled loops for the depth shield's per-step geometry (numba).

The shield tests every depth pixel the arm's motion changed (about 1400 a step for three
128-pixel views) against the arm's capsules, every configuration it checks against the
obstacle points seen, the points of the hand's shell against the unseen space behind
seen surfaces (placing them by the arm's DH frames, `dh_frames`), and each new obstacle point
for a neighbour that supports it (`supported`, on a grid, in place of a k-d tree). In numpy
each test is a dozen passes over (geoms, points) arrays, most of them spent on points already
decided; these loops decide each point at its first geom within reach and skip the rest.
They compute the same distances (in float64, point minus the nearest point of the segment, not
an expanded square), so the shield's decisions are those of the array code except within
rounding of a threshold.

Compiled on first use (about a second each) and cached beside this file.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _in_box(points: np.ndarray, i: int, low: np.ndarray, high: np.ndarray) -> bool:
    """Whether point i of `points` lies strictly between `low` and `high` (3,)."""
    for k in range(3):
        if not low[k] < points[i, k] < high[k]:
            return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _distance2(points: np.ndarray, i: int, others: np.ndarray, j: int) -> float:
    """Squared distance of point i of `points` to point j of `others`, summed over x, y, z in
    order."""
    d0 = points[i, 0] - others[j, 0]
    d1 = points[i, 1] - others[j, 1]
    d2 = points[i, 2] - others[j, 2]
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, nogil=True, inline="always")
def _segment_distance2(
    points: np.ndarray, i: int, start: np.ndarray, axis: np.ndarray, length2: float
) -> float:
    """Squared distance of point i of `points` to the segment from `start` along `axis` (3,),
    |axis|^2 = `length2`."""
    dx, dy, dz = points[i, 0] - start[0], points[i, 1] - start[1], points[i, 2] - start[2]
    t = 0.0
    if length2 > 0.0:
        t = min(max((dx * axis[0] + dy * axis[1] + dz * axis[2]) / length2, 0.0), 1.0)
    dx -= t * axis[0]
    dy -= t * axis[1]
    dz -= t * axis[2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True)
def within_capsules(
    points: np.ndarray, starts: np.ndarray, ends: np.ndarray, reach: np.ndarray
) -> np.ndarray:
    """Whether each of `points` (P, 3) lies within `reach[g]` of some segment g from
    `starts[g]` to `ends[g]` (G, 3): (P,) bool."""
    axes = ends - starts
    length2 = (axes * axes).sum(axis=1)
    # Per geom, the box that holds every point within reach of it.
    low = np.minimum(starts, ends) - reach.reshape(-1, 1)
    high = np.maximum(starts, ends) + reach.reshape(-1, 1)
    out = np.zeros(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        for g in range(starts.shape[0]):
            if not _in_box(points, i, low[g], high[g]):
                continue
            if _segment_distance2(points, i, starts[g], axes[g], length2[g]) <= reach[g] ** 2:
                out[i] = True
                break
    return out


@njit(cache=True, nogil=True, inline="always")
def _segments_distance2(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> float:
    """Squared distance between the segments from `p1` along `d1` and from `p2` along `d2`
    (3,): the closest points' parameters clamped to both segments (Ericson, Real-Time Collision
    Detection, 5.1.9)."""
    r0, r1, r2 = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
    a = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]
    e = d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2]
    f = d2[0] * r0 + d2[1] * r1 + d2[2] * r2
    s = t = 0.0
    if a <= 1e-18 and e > 1e-18:
        t = min(max(f / e, 0.0), 1.0)
    elif a > 1e-18:
        c = d1[0] * r0 + d1[1] * r1 + d1[2] * r2
        if e <= 1e-18:
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
            denom = a * e - b * b
            if denom > 0.0:
                s = min(max((b * f - c * e) / denom, 0.0), 1.0)
            t = (b * s + f) / e
            if t < 0.0:
                t, s = 0.0, min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    x = r0 + s * d1[0] - t * d2[0]
    y = r1 + s * d1[1] - t * d2[1]
    z = r2 + s * d1[2] - t * d2[2]
    return x * x + y * y + z * z


@njit(cache=True, nogil=True)
def rays_within_capsules(
    points: np.ndarray, shifts: np.ndarray, starts: np.ndarray, ends: np.ndarray, reach: np.ndarray
) -> np.ndarray:
    """Whether some point of each segment from `points[i] - shifts[i]` to `points[i] +
    shifts[i]` (P, 3) lies within `reach[g]` of some segment g from `starts[g]` to `ends[g]`
    (G, 3): (P,) bool (a noisy depth pixel's point anywhere along its ray's uncertainty)."""
    axes = ends - starts
    low = np.minimum(starts, ends) - reach.reshape(-1, 1)
    high = np.maximum(starts, ends) + reach.reshape(-1, 1)
    out = np.zeros(points.shape[0], np.bool_)
    start = np.empty(3)
    along = np.empty(3)
    for i in range(points.shape[0]):
        for k in range(3):
            start[k] = points[i, k] - shifts[i, k]
            along[k] = 2.0 * shifts[i, k]
        for g in range(starts.shape[0]):
            apart = False
            for k in range(3):  # the segments' boxes apart: too far
                lo, hi = min(start[k], start[k] + along[k]), max(start[k], start[k] + along[k])
                if hi < low[g, k] or lo > high[g, k]:
                    apart = True
                    break
            if apart:
                continue
            if _segments_distance2(start, along, starts[g], axes[g]) <= reach[g] ** 2:
                out[i] = True
                break
    return out


@njit(cache=True, nogil=True)
def told_off_table_and_target(
    points: np.ndarray,
    pixels: np.ndarray,
    rays: np.ndarray,
    view_origins: np.ndarray,
    view_axes: np.ndarray,
    pixels_per_view: int,
    noise_m: float,
    sigmas: float,
    min_height_m: float,
    goal: np.ndarray,
    reach: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Of `points` (N, 3) seen at `pixels` (N,; flat indices into `rays`, the world offset per
    metre of depth of every pixel, views one after another, `pixels_per_view` each) by
    cameras at `view_origins` looking along `view_axes` (V, 3), those that no point within
    `sigmas` sds of the depth noise along their ray (sd `noise_m` times the depth squared)
    puts lower than `min_height_m` or within `reach` of `goal`: their indices (M,) and sds
    (M,). The arithmetic of the array code it replaces (each point's depth along its view's
    axis, the table test, `rays_within_capsules` on a capsule of no length), in one pass."""
    keep = np.empty(points.shape[0], np.int64)
    sigma = np.empty(points.shape[0])
    start = np.empty(3)
    along = np.empty(3)
    no_length = np.zeros(3)  # the target as a capsule
    count = 0
    for i in range(points.shape[0]):
        view = pixels[i] // pixels_per_view
        depth = 0.0
        for k in range(3):
            depth += (points[i, k] - view_origins[view, k]) * view_axes[view, k]
        sd = noise_m * depth * depth
        spread = sigmas * sd
        if not points[i, 2] - spread * abs(np.float64(rays[pixels[i], 2])) > min_height_m:
            continue
        apart = False
        for k in range(3):
            shift = spread * np.float64(rays[pixels[i], k])
            start[k] = points[i, k] - shift
            along[k] = 2.0 * shift
            lo, hi = min(start[k], start[k] + along[k]), max(start[k], start[k] + along[k])
            if hi < goal[k] - reach or lo > goal[k] + reach:  # the boxes apart: too far
                apart = True
        if not apart and _segments_distance2(start, along, goal, no_length) <= reach**2:
            continue
        keep[count] = i
        sigma[count] = sd
        count += 1
    return keep[:count], sigma[:count]


@njit(cache=True, nogil=True, inline="always")
def _neighbour_near(
    i: int,
    mine: np.ndarray,
    points: np.ndarray,
    cells: np.ndarray,
    dims: np.ndarray,
    sorted_keys: np.ndarray,
    order: np.ndarray,
    radius: float,
) -> bool:
    """Whether a point of `points` but the i-th lies within `radius` of `mine[i]`, looked for
    in the 27 grid cells around its own (`supported`'s grid: `cells`, `dims`, the cells' keys
    sorted with their points' `order`)."""
    for x in range(max(cells[i, 0] - 1, 0), min(cells[i, 0] + 2, dims[0])):
        for y in range(max(cells[i, 1] - 1, 0), min(cells[i, 1] + 2, dims[1])):
            for z in range(max(cells[i, 2] - 1, 0), min(cells[i, 2] + 2, dims[2])):
                key = (x * dims[1] + y) * dims[2] + z
                j = np.searchsorted(sorted_keys, key)
                while j < sorted_keys.shape[0] and sorted_keys[j] == key:
                    other = order[j]
                    if other != i and _distance2(mine, i, points, other) <= radius * radius:
                        return True
                    j += 1
    return False


@njit(cache=True, nogil=True)
def supported(mine: np.ndarray, kept: np.ndarray, radius: float) -> np.ndarray:
    """Whether each of `mine` (M, 3) has another of `mine`, or one of `kept` (K, 3), within
    `radius` (inclusive): (M,) bool. Points are binned on a grid a little coarser than
    `radius`, so that any two within it lie in neighbouring cells, and each of `mine` looks in
    its 27 cells until it finds one; the squared distance summed over x, y, z in order, as a
    k-d tree's ball query computes it."""
    count = mine.shape[0]
    points = np.concatenate((mine, kept))
    total = points.shape[0]
    out = np.zeros(count, np.bool_)
    if count == 0:
        return out
    low = points[0].copy()
    for i in range(total):
        for k in range(3):
            low[k] = min(low[k], points[i, k])
    scale = 1.0 / (radius * (1.0 + 1e-6))
    cells = np.empty((total, 3), np.int64)
    dims = np.ones(3, np.int64)
    for i in range(total):
        for k in range(3):
            cells[i, k] = int(np.floor((points[i, k] - low[k]) * scale))
            dims[k] = max(dims[k], cells[i, k] + 1)
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    order = np.argsort(keys)
    sorted_keys = keys[order]
    for i in range(count):
        out[i] = _neighbour_near(i, mine, points, cells, dims, sorted_keys, order, radius)
    return out


@njit(cache=True, nogil=True)
def capsule_clearances(
    starts: np.ndarray, ends: np.ndarray, radii: np.ndarray, points: np.ndarray, cap: float
) -> np.ndarray:
    """Per configuration b, the distance from the surface of capsules (segments from
    `starts[b, g]` to `ends[b, g]`, (B, G, 3), radii (G,)) to the nearest of `points` (P, 3)
    (negative: inside one), or `cap` when every point is farther: (B,)."""
    configs, geoms = starts.shape[0], starts.shape[1]
    out = np.full(configs, cap)
    candidates = np.empty(points.shape[0], np.int64)
    for g in range(geoms):
        # The box over all configurations that holds every point within `cap` of the geom's
        # surface, and the points in it, once.
        low, high = np.full(3, np.inf), np.full(3, -np.inf)
        for b in range(configs):
            for k in range(3):
                low[k] = min(low[k], starts[b, g, k], ends[b, g, k])
                high[k] = max(high[k], starts[b, g, k], ends[b, g, k])
        low -= radii[g] + cap
        high += radii[g] + cap
        count = 0
        for i in range(points.shape[0]):
            if _in_box(points, i, low, high):
                candidates[count] = i
                count += 1
        for b in range(configs):
            axis = ends[b, g] - starts[b, g]
            length2 = (axis * axis).sum()
            best = out[b] + radii[g]  # only a point nearer than this to the axis lowers it
            for j in range(count):
                if best <= 0.0:
                    break
                d2 = _segment_distance2(points, candidates[j], starts[b, g], axis, length2)
                if d2 < best * best:
                    out[b] = min(out[b], np.sqrt(d2) - radii[g])
                    best = out[b] + radii[g]
    return out


@njit(cache=True, nogil=True)
def lift_pixels(
    codes: np.ndarray,
    pixels: np.ndarray,
    depth_of_code: np.ndarray,
    origins: np.ndarray,
    rays: np.ndarray,
    far_m: np.float32,
    min_height_m: np.float32,
) -> tuple[np.ndarray, np.ndarray]:
    """Of `pixels` (flat indices into the depth codes `codes`, flattened over views), those
    nearer than `far_m` whose point lies higher than `min_height_m`: their world points
    (N, 3) and indices (N,). In float32 throughout, as the array code computes it (`far_m`,
    `min_height_m` float32)."""
    keep = np.empty(pixels.shape[0], np.int64)
    count = 0
    for i in pixels:
        depth = depth_of_code[codes[i]]
        if depth < far_m and origins[i, 2] + depth * rays[i, 2] > min_height_m:
            keep[count] = i
            count += 1
    keep = keep[:count]
    points = np.empty((count, 3))
    for j in range(count):
        depth = depth_of_code[codes[keep[j]]]
        for k in range(3):
            points[j, k] = origins[keep[j], k] + depth * rays[keep[j], k]
    return points, keep


@njit(cache=True, nogil=True)
def surface_candidates(
    points: np.ndarray,
    goal: np.ndarray,
    reach2: float,
    pedestal_radius2: float,
    pedestal_top: float,
    low: np.ndarray,
    inverse_voxel: float,
    dims: np.ndarray,
    grid: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of `points` (N, 3), those off the pedestal (radius^2 `pedestal_radius2` up to height
    `pedestal_top`) and farther than sqrt(`reach2`) from `goal`, in the voxel grid (corner
    `low`, `dims` voxels of 1 / `inverse_voxel`, flat occupancy `grid`): their indices, their
    voxels (flat) and whether each voxel is new (not in `grid`)."""
    index = np.empty(points.shape[0], np.int64)
    cells = np.empty(points.shape[0], np.int64)
    new = np.empty(points.shape[0], np.bool_)
    count = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if x * x + y * y <= pedestal_radius2 and z <= pedestal_top:
            continue
        dx, dy, dz = x - goal[0], y - goal[1], z - goal[2]
        if dx * dx + dy * dy + dz * dz <= reach2:
            continue
        cell = 0
        inside = True
        for k in range(3):
            voxel = np.int64(np.floor((points[i, k] - low[k]) * inverse_voxel))
            if voxel <= -1 or voxel >= dims[k]:
                inside = False
                break
            cell = cell * dims[k] + voxel
        if not inside:
            continue
        index[count] = i
        cells[count] = cell
        new[count] = not grid[cell]
        count += 1
    return index[:count], cells[:count], new[:count]


@njit(cache=True, nogil=True)
def any_in_boxes(points: np.ndarray, low: np.ndarray, high: np.ndarray) -> bool:
    """Whether any of `points` (P, 3) lies strictly inside any of the boxes from `low` to
    `high` (B, 3)."""
    for i in range(points.shape[0]):
        for b in range(low.shape[0]):
            if _in_box(points, i, low[b], high[b]):
                return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _behind_hiding_surface(points: np.ndarray, i: int, views: tuple) -> bool:
    """Whether no view has seen point i of `points` free and one has seen only a hiding
    surface in front of it. `views`: the cameras' positions (V, 3), rotations (V, 3, 3) and
    intrinsics (V, 4: fx, fy, cx, cy), the image height and width, and per pixel (flat over
    views) the deepest depth seen (float32), whether that surface hides, and the tolerance
    (float32) within which a point counts as seen."""
    positions, rotations, intrinsics, height, width, deepest, hides, tolerance = views
    behind_hider = False
    for v in range(positions.shape[0]):
        local = np.zeros(3)
        for j in range(3):
            for k in range(3):
                local[j] += (points[i, k] - positions[v, k]) * rotations[v, k, j]
        depth = -local[2]
        if not depth > 0.0:
            continue
        fx, fy, cx, cy = intrinsics[v, 0], intrinsics[v, 1], intrinsics[v, 2], intrinsics[v, 3]
        col = np.int64(np.floor(cx + fx * local[0] / max(depth, 1e-6)))
        row = np.int64(np.floor(cy - fy * local[1] / max(depth, 1e-6)))
        if col < 0 or col >= width or row < 0 or row >= height:
            continue
        pixel = (v * height + row) * width + col
        if depth > deepest[pixel] + tolerance:
            behind_hider = behind_hider or hides[pixel]
        else:
            return False  # seen free in this view
    return behind_hider


@njit(cache=True, nogil=True, inline="always")
def _filled(points: np.ndarray, i: int, filled: tuple) -> bool:
    """Whether point i of `points` lies in a voxel whose centre is within `reach[s]` of a
    segment s the hand filled. `filled`: the segments' starts and ends (S, 3), their reach
    (S,), and the voxel grid's corner (3,), edge and size (3,)."""
    starts, ends, reach, low, voxel, dims = filled
    centre = np.empty(3)
    for k in range(3):
        index = np.int64(np.floor((points[i, k] - low[k]) * (1.0 / voxel)))
        if index <= -1 or index >= dims[k]:
            return False
        centre[k] = low[k] + (index + 0.5) * voxel
    centres = centre.reshape(1, 3)
    for s in range(starts.shape[0]):
        axis = ends[s] - starts[s]
        if _segment_distance2(centres, 0, starts[s], axis, (axis * axis).sum()) <= reach[s] ** 2:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _near_any(points: np.ndarray, i: int, others: np.ndarray, near2: float) -> bool:
    """Whether any of `others` (P, 3) lies nearer than sqrt(`near2`) to point i of `points`."""
    for j in range(others.shape[0]):
        if _distance2(points, i, others, j) < near2:
            return True
    return False


@njit(cache=True, nogil=True)
def hidden_points(points: np.ndarray, views: tuple, filled: tuple) -> np.ndarray:
    """Whether each of `points` (P, 3) is hidden: behind a hiding surface in the views and
    not filled by the hand (`views`, `filled` as for `_behind_hiding_surface`, `_filled`)."""
    out = np.zeros(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        out[i] = _behind_hiding_surface(points, i, views) and not _filled(points, i, filled)
    return out


@njit(cache=True, nogil=True)
def hidden_configurations(
    frames: np.ndarray,
    shell: np.ndarray,
    shell_group: np.ndarray,
    widen: np.ndarray,
    obstacle: np.ndarray,
    near_m: float,
    views: tuple,
    filled: tuple,
) -> np.ndarray:
    """Per configuration b, whether a point of the hand's shell is hidden (`hidden_points`)
    within `near_m` of a point of `obstacle` (P, 3): (B,). The shell: points `shell` (S, 3),
    each fixed in the link frame of its group `shell_group` (S,), placed by `frames` (B,
    groups, 4, 4); `widen[g]`: how far group g's points lie from their frame's origin at
    most, plus `near_m` and an allowance (the box around the origins widened by it holds
    every obstacle point that can be near the shell)."""
    configs, groups = frames.shape[0], frames.shape[1]
    out = np.zeros(configs, np.bool_)
    # Obstacle points that can lie within `near_m` of the shell: those in the box around the
    # frames' origins widened by each group's extent (a superset).
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    for b in range(configs):
        for g in range(groups):
            for k in range(3):
                low[k] = min(low[k], frames[b, g, k, 3] - widen[g])
                high[k] = max(high[k], frames[b, g, k, 3] + widen[g])
    count = 0
    near = np.empty(obstacle.shape[0], np.int64)
    for j in range(obstacle.shape[0]):
        if _in_box(obstacle, j, low, high):
            near[count] = j
            count += 1
    if count == 0:
        return out
    obstacle = obstacle[near[:count]]
    # Only shell points in the box around those points widened by `near_m` (and a rounding
    # allowance) can be near one.
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    for j in range(obstacle.shape[0]):
        for k in range(3):
            low[k] = min(low[k], obstacle[j, k])
            high[k] = max(high[k], obstacle[j, k])
    low -= near_m + 1e-4
    high += near_m + 1e-4
    point = np.empty((1, 3))
    for b in range(configs):
        for i in range(shell.shape[0]):
            frame = frames[b, shell_group[i]]
            for k in range(3):  # rotation times the local point, plus the origin
                total = 0.0
                for j in range(3):
                    total += shell[i, j] * frame[k, j]
                point[0, k] = total + frame[k, 3]
            # The cheap tests first; each configuration stops at its first hidden point.
            if (
                _in_box(point, 0, low, high)
                and _behind_hiding_surface(point, 0, views)
                and _near_any(point, 0, obstacle, near_m * near_m)
                and not _filled(point, 0, filled)
            ):
                out[b] = True
                break
    return out


@njit(cache=True, nogil=True)
def dh_frames(joints: np.ndarray, d: np.ndarray, a: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """DH frames 1..6 at each of `joints` (B, 6), in the base frame: (B, 6, 4, 4), the first six
    of `clamgen.robot.kinematics.forward_kinematics` (the same products of standard DH link
    transforms, to float64 rounding), without numpy's per-call overhead, which the shield pays
    several times a step for a handful of configurations."""
    configs, links = joints.shape
    out = np.empty((configs, links, 4, 4))
    link = np.zeros((4, 4))
    link[3, 3] = 1.0
    for b in range(configs):
        pose = np.eye(4)
        for i in range(links):
            ct, st = np.cos(joints[b, i]), np.sin(joints[b, i])
            ca, sa = np.cos(alpha[i]), np.sin(alpha[i])
            link[0, 0], link[0, 1], link[0, 2], link[0, 3] = ct, -st * ca, st * sa, a[i] * ct
            link[1, 0], link[1, 1], link[1, 2], link[1, 3] = st, ct * ca, -ct * sa, a[i] * st
            link[2, 0], link[2, 1], link[2, 2], link[2, 3] = 0.0, sa, ca, d[i]
            if i == 0:
                pose[:] = link
            else:
                pose = pose @ link
            out[b, i] = pose
    return out
