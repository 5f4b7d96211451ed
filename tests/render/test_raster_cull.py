"""The clusters a frame draws and their order (`Rasterizer.visible_clusters`): the culled ones, nearest first."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.render.raster import _cull_clusters, _visible_order


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
    order = _visible_order(low, high, pose, pixel_x, pixel_y, 50.0, 50.0, rects, nearest, rank)

    expected_rects, expected_nearest = np.zeros((count, 4), np.int64), np.zeros(count)
    inside = _cull_clusters(low, high, pose, pixel_x, pixel_y, 50.0, 50.0, expected_rects, expected_nearest)
    expected = inside[np.argsort(expected_nearest[inside], kind="stable")]
    assert 100 < len(expected) < count and len(np.unique(expected_nearest[inside])) < len(inside)  # (ties, culls)
    np.testing.assert_array_equal(order, expected)
    expected_rank = np.full(count, -1)
    expected_rank[expected] = np.arange(len(expected))
    np.testing.assert_array_equal(rank, expected_rank)
    np.testing.assert_array_equal(rects[inside], expected_rects[inside])
    np.testing.assert_array_equal(nearest[inside], expected_nearest[inside])
