"""The clusters a frame draws and their order (`Rasterizer.visible_clusters`): the culled ones, nearest first."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.render.raster import CLUSTER_SIZE, ClusteredMesh, _cull_clusters, _stable_order, _visible_order


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_visible_clusters_are_the_culled_ones_in_a_stable_order_of_their_nearest_depth(seed: int) -> None:
    """`_visible_order` gives `_cull_clusters`' clusters sorted by their nearest depth as numpy's stable argsort
    sorts them (of equal depths, the lower index first: many boxes here are copies of others) and each one's
    position in that order as its rank (-1 for a cluster outside the view), whatever ranks were there before."""
    rng = np.random.default_rng(seed)
    count = 3000
    low = rng.uniform(-6.0, 6.0, (count, 3))
    high = low + rng.uniform(0.0, 0.5, (count, 3))
    copies, sources = np.flatnonzero(rng.random(count) < 0.3), rng.integers(0, 100, count)
    low[copies], high[copies] = low[sources[copies]], high[sources[copies]]  # (equal boxes: equal nearest depths)
    pose = np.eye(4)
    pose[:3, 3] = rng.uniform(-0.5, 0.5, 3)
    pixel_x, pixel_y = np.linspace(-0.7, 0.7, 64), np.linspace(-0.5, 0.5, 48)
    rects, nearest = np.zeros((count, 4), np.int64), np.zeros(count)
    rank = rng.integers(-5, count, count)  # (stale ranks of another frame)
    chunks = -(-count // CLUSTER_SIZE)
    order = _visible_order(low, high, *_whole_view(chunks), pose, pixel_x, pixel_y, 50.0, 50.0, rects, nearest, rank)

    expected_rects, expected_nearest = np.zeros((count, 4), np.int64), np.zeros(count)
    inside = _cull_clusters(low, high, *_whole_view(chunks), pose, pixel_x, pixel_y, 50.0, 50.0, expected_rects,
                            expected_nearest)
    expected = inside[np.argsort(expected_nearest[inside], kind="stable")]
    assert 100 < len(expected) < count and len(np.unique(expected_nearest[inside])) < len(inside)  # (ties, culls)
    np.testing.assert_array_equal(order, expected)
    expected_rank = np.full(count, -1)
    expected_rank[expected] = np.arange(len(expected))
    np.testing.assert_array_equal(rank, expected_rank)
    np.testing.assert_array_equal(rects[inside], expected_rects[inside])
    np.testing.assert_array_equal(nearest[inside], expected_nearest[inside])


def _whole_view(chunks: int) -> tuple[np.ndarray, np.ndarray]:
    """Chunk boxes around everything (from -1 to 1 km): no chunk is ever dropped whole."""
    return np.full((chunks, 3), -1e3), np.full((chunks, 3), 1e3)


def _walls(seed: int) -> np.ndarray:
    """Corners of triangles of ~5 cm on the walls of 4 rooms side by side (an occluded scene like the bench house)."""
    rng = np.random.default_rng(seed)
    centres = []
    for room in range(4):
        for axis in range(3):
            for side in (0.0, 3.0):
                points = rng.uniform(0.0, 3.0, (4000, 3))
                points[:, axis] = side
                points[:, 0] += 3.0 * room
                centres.append(points)
    centres = np.concatenate(centres)
    return (centres[:, None, :] + rng.uniform(-0.03, 0.03, (len(centres), 3, 3))).astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_chunks_of_clusters_outside_the_view_are_dropped_whole_as_their_clusters_would_be(seed: int) -> None:
    """The cull with chunks of CLUSTER_SIZE clusters dropped by their box keeps the clusters, pixel rectangles and
    nearest depths of the cull that tests every cluster, from poses inside, at the edge of and outside the rooms,
    looking every way; and it drops chunks (the cheaper test is used)."""
    from pipeline.render.raster import _box_outside_view

    rng = np.random.default_rng(seed)
    corners = _walls(seed)
    mesh = ClusteredMesh(corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3))
    chunk_low, chunk_high = mesh.chunk_low, mesh.chunk_high
    pixel_x, pixel_y = np.linspace(-0.6, 0.6, 64), np.linspace(-0.45, 0.45, 48)
    count, dropped = len(mesh.low), 0
    for _ in range(12):
        pose = np.eye(4)
        pose[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        pose[:3, 3] = rng.uniform([-2.0, -1.0, -1.0], [14.0, 4.0, 4.0])
        found = (np.zeros((count, 4), np.int64), np.zeros(count))
        expected = (np.zeros((count, 4), np.int64), np.zeros(count))
        inside = _cull_clusters(mesh.low, mesh.high, chunk_low, chunk_high, pose, pixel_x, pixel_y, 50.0, 50.0, *found)
        every = _cull_clusters(mesh.low, mesh.high, *_whole_view(len(chunk_low)), pose, pixel_x, pixel_y, 50.0, 50.0,
                               *expected)
        np.testing.assert_array_equal(inside, every)
        np.testing.assert_array_equal(found[0][inside], expected[0][inside])
        np.testing.assert_array_equal(found[1][inside], expected[1][inside])
        dropped += sum(_box_outside_view(low, high, pose, pixel_x[0], pixel_x[-1], pixel_y[0], pixel_y[-1])
                       for low, high in zip(chunk_low, chunk_high))
    assert dropped > 0


@pytest.mark.parametrize("size", [0, 1, 2, 300, 5000])
def test_the_radix_order_of_depths_is_numpy_s_stable_argsort(size: int) -> None:
    """`_stable_order` of non-negative float64 depths (as their bits) is `np.argsort(kind="stable")`: ties (a third
    of the keys copy others), zeros, depths from micrometres to kilometres and keys equal in all but their lowest bit."""
    rng = np.random.default_rng(size)
    depths = np.exp(rng.uniform(np.log(1e-6), np.log(1e3), size))
    depths[rng.random(size) < 0.1] = 0.0
    copies = np.flatnonzero(rng.random(size) < 0.3)
    depths[copies] = depths[rng.integers(0, size, len(copies))]
    if size > 2:
        depths[1] = np.nextafter(depths[0], np.inf)
    np.testing.assert_array_equal(_stable_order(depths.view(np.uint64)), np.argsort(depths, kind="stable"))


def test_a_box_touching_the_camera_plane_at_minus_zero_sorts_with_the_nearest() -> None:
    """A cluster whose box reaches the camera plane has nearest depth max(z, 0.0), which is -0.0 when its corner's z
    is -0.0 (a corner on the plane, every term of its camera-frame z a negative zero): it sorts as 0.0 does (here
    first), although the bits of -0.0 sort after those of every non-negative float64."""
    low = np.array([[-1.0, -1.0, 0.0], [-1.0, -1.0, 0.5], [0.2, 0.2, 2.0]])
    high = low + np.array([[1.5, 1.5, 1.0], [1.5, 1.5, 1.0], [0.5, 0.5, 0.5]])
    pose = np.diag([1.0, -1.0, -1.0, 1.0])  # at the origin, looking down -z: a corner at z = 0 gets camera z -0.0
    low[:, 2], high[:, 2] = -high[:, 2], -low[:, 2]  # (the boxes in front of this camera)
    low[0, 2], high[0, 2] = -1.0, 0.0  # the first box's top face on the camera plane, its corners at x, y < 0
    pixel_x, pixel_y = np.linspace(-0.7, 0.7, 64), np.linspace(-0.5, 0.5, 48)
    rects, nearest, rank = np.zeros((3, 4), np.int64), np.zeros(3), np.full(3, -1)
    order = _visible_order(low, high, *_whole_view(1), pose, pixel_x, pixel_y, 50.0, 50.0, rects, nearest, rank)
    assert np.signbit(nearest[0]) and nearest[0] == 0.0  # (the case: a negative zero)
    inside = np.sort(order)
    np.testing.assert_array_equal(order, inside[np.argsort(nearest[inside], kind="stable")])
    assert len(order) == 3 and order[0] == 0
