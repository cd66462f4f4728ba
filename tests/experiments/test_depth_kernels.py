"""The depth shield's compiled loops against the array formulas they replace."""

from __future__ import annotations

import numpy as np
import pytest

from clamgen.experiments import depth_kernels as K
from clamgen.experiments.depth_shield import (
    DEPTH_OF_CODE,
    GRID_LOW_M,
    VOXEL_M,
    _in_boxes,
)


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


def _capsules_and_points(seed, num_points, count=8):
    """A random generator, `count` capsules (axis starts and ends, reach; the first a sphere)
    and `num_points` points around them."""
    rng = np.random.default_rng(seed)
    starts = rng.uniform(-0.5, 0.5, (count, 3))
    ends = starts + rng.normal(0.0, 0.1, (count, 3))
    ends[0] = starts[0]  # a degenerate segment (a sphere)
    reach = rng.uniform(0.02, 0.1, count)
    return rng, starts, ends, reach, rng.uniform(-0.7, 0.7, (num_points, 3))


@pytest.mark.parametrize("seed", range(5))
def test_within_capsules_matches_distances(seed):
    _, starts, ends, reach, points = _capsules_and_points(seed, 3000)
    gap = _segment_distance(points, starts, ends) - reach
    expected = (gap <= 0).any(axis=1)
    decided = np.abs(gap).min(axis=1) > 1e-9  # (rounding may decide a point on a surface)
    got = K.within_capsules(points, starts, ends, reach)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(got[decided], expected[decided])


@pytest.mark.parametrize("seed", range(5))
def test_rays_within_capsules_match_densely_sampled_segments(seed):
    rng, starts, ends, reach, points = _capsules_and_points(seed, 2000)
    shifts = rng.normal(0.0, 0.05, (2000, 3))
    shifts[:100] = 0.0  # no uncertainty: the points' own test
    # Dense samples along each segment; a margin either side of the reach for what they miss.
    along = np.linspace(-1.0, 1.0, 401)
    gaps = np.stack([_segment_distance(points + t * shifts, starts, ends) - reach for t in along])
    gap = gaps.min(axis=0)  # P, G: the nearest sample's gap to each capsule
    step = 2.0 * np.linalg.norm(shifts, axis=1) / (len(along) - 1)
    decided = (np.abs(gap).min(axis=1) > step + 1e-9) | (gap <= 0).any(axis=1)
    got = K.rays_within_capsules(points, shifts, starts, ends, reach)
    expected = (gap <= 0).any(axis=1)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(got[decided], expected[decided])
    np.testing.assert_array_equal(got[:100], K.within_capsules(points[:100], starts, ends, reach))


@pytest.mark.parametrize("seed", range(5))
def test_capsule_clearances_match_distances(seed):
    rng = np.random.default_rng(seed)
    configs, geoms, cap = 6, 5, 0.08
    starts = rng.uniform(-0.4, 0.4, (configs, geoms, 3))
    ends = starts + rng.normal(0.0, 0.1, (configs, geoms, 3))
    radii = rng.uniform(0.02, 0.06, geoms)
    points = rng.uniform(-0.6, 0.6, (500, 3))
    expected = np.array(
        [
            min(cap, (_segment_distance(points, starts[b], ends[b]) - radii).min())
            for b in range(configs)
        ]
    )
    got = K.capsule_clearances(starts, ends, radii, points, cap)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert (got < cap).any() and (got < 0).any()
    empty = K.capsule_clearances(starts, ends, radii, np.empty((0, 3)), cap)
    np.testing.assert_array_equal(empty, np.full(configs, cap))


def test_lift_pixels_matches_the_array_formula():
    rng = np.random.default_rng(0)
    count = 4000
    codes = rng.integers(0, 256, count).astype(np.uint8)
    last = rng.integers(0, 256, count).astype(np.uint8)
    origins = rng.uniform(-1, 1, (count, 3)).astype(np.float32)
    rays = rng.normal(0, 1, (count, 3)).astype(np.float32)
    far, low = np.float32(1.5), np.float32(0.1)
    for changed in (codes > last, np.ones(count, bool)):
        depth = DEPTH_OF_CODE[codes]
        height = origins[:, 2] + depth * rays[:, 2]
        keep = np.flatnonzero(changed & (depth < far) & (height > low))
        expected = (origins[keep] + depth[keep, None] * rays[keep]).astype(np.float64)
        pixels = np.flatnonzero(changed)
        points, kept = K.lift_pixels(codes, pixels, DEPTH_OF_CODE, origins, rays, far, low)
        np.testing.assert_array_equal(kept, keep)
        np.testing.assert_array_equal(points, expected)


def test_surface_candidates_match_the_array_formula():
    rng = np.random.default_rng(1)
    points = rng.uniform(-1.2, 1.6, (5000, 3))
    points[:50, :2] *= 0.01  # some on the pedestal
    goal = np.array([0.4, 0.2, 0.3])
    points[50:100] = goal + rng.normal(0, 0.02, (50, 3))  # some on the target
    dims = np.array([250, 200, 120])
    grid = rng.random(int(dims.prod())) < 0.3
    reach2, pedestal2, top = 0.05**2, 0.09**2, 0.01
    index, cells, new = K.surface_candidates(
        points, goal, reach2, pedestal2, top, GRID_LOW_M, 1.0 / VOXEL_M, dims, grid
    )
    keep = ((points[:, :2] ** 2).sum(1) > pedestal2) | (points[:, 2] > top)
    keep &= ((points - goal) ** 2).sum(1) > reach2
    voxels = np.floor((points - GRID_LOW_M) * (1.0 / VOXEL_M)).astype(np.int64)
    keep &= _in_boxes(voxels, np.full(3, -1), dims)
    expected = np.flatnonzero(keep)
    expected_cells = voxels[expected] @ np.array([dims[1] * dims[2], dims[2], 1])
    assert 0 < len(expected) < len(points)
    np.testing.assert_array_equal(index, expected)
    np.testing.assert_array_equal(cells, expected_cells)
    np.testing.assert_array_equal(new, ~grid[expected_cells])


def test_any_in_boxes_matches_the_array_test():
    rng = np.random.default_rng(2)
    low = rng.uniform(-1, 0.8, (6, 3))
    high = low + rng.uniform(0.0, 0.2, (6, 3))
    for _ in range(50):
        points = rng.uniform(-1, 1, (rng.integers(0, 40), 3))
        expected = bool(_in_boxes(points, low, high).any()) if len(points) else False
        assert K.any_in_boxes(points, low, high) == expected


def test_told_off_table_and_target_matches_the_array_formula():
    """The told map's table and target tests in one pass: the same points kept and the same
    sds, bit for bit, as the array code (the noise's sd from each point's view depth, the
    table test along the ray, `rays_within_capsules` on the target as a capsule of no
    length)."""
    rng = np.random.default_rng(3)
    views, per_view = 3, 400
    rays = rng.normal(0, 1, (views * per_view, 3)).astype(np.float32)
    origins = rng.uniform(-1, 1, (views, 3))
    axes = rng.normal(0, 1, (views, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    pixels = np.sort(rng.choice(views * per_view, 900, replace=False))
    points = rng.uniform(-0.6, 0.6, (900, 3)) + np.array([0.3, 0.0, 0.3])
    goal = np.array([0.4, 0.1, 0.3])
    points[:150] = goal + rng.normal(0, 0.04, (150, 3))  # some on or near the target
    noise_m, sigmas, table, reach = 0.01, 3.0, 0.05, 0.03
    keep, sigma = K.told_off_table_and_target(
        points, pixels, rays, origins, axes, per_view, noise_m, sigmas, table, goal, reach
    )
    view = pixels // per_view
    depth = ((points - origins[view]) * axes[view]).sum(axis=1)
    sd = noise_m * depth * depth
    off_table = points[:, 2] - sigmas * sd * np.abs(rays[pixels, 2]) > table
    shifts = sigmas * sd[:, None] * rays[pixels]
    centre = goal[None]
    on_target = K.rays_within_capsules(points, shifts, centre, centre, np.array([reach]))
    expected = np.flatnonzero(off_table & ~on_target)
    assert 0 < len(expected) < len(points) and on_target[:150].sum() > 10
    np.testing.assert_array_equal(keep, expected)
    np.testing.assert_array_equal(sigma, sd[expected])


def test_supported_matches_a_kd_tree_ball_query():
    """The support test on a grid: the same answer as a k-d tree's ball query (itself and
    another within the radius, inclusive), duplicates and pairs at the radius included."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(4)
    radius = float(np.nextafter(0.03, 0.0))
    for _ in range(100):
        mine = rng.uniform(-0.5, 0.5, (rng.integers(5, 300), 3)) * rng.uniform(0.05, 1.0)
        kept = np.round(rng.uniform(-0.5, 0.5, (rng.integers(0, 300), 3)) / VOXEL_M) * VOXEL_M
        mine[1] = mine[0]  # a duplicate
        mine[3] = mine[2] + np.array([0.03, 0.0, 0.0])  # the radius apart: not within
        mine[4] = mine[2] + np.array([radius, 0.0, 0.0])
        near = cKDTree(np.concatenate([mine, kept])).query_ball_point(
            mine, radius, return_length=True
        )
        np.testing.assert_array_equal(K.supported(mine, kept, radius), near >= 2)
    assert not K.supported(np.zeros((1, 3)), np.empty((0, 3)), radius).any()  # alone
