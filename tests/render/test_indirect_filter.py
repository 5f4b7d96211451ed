"""The interleave filter of the indirect light (pipeline/render/indirect/filter.py): a gradient of light across a
surface is taken at the gather point, not at the centre of the block of points around it."""

from __future__ import annotations

import numpy as np

from pipeline.render.indirect.filter import FILTER_REACH, interleave_filter
from pipeline.render.indirect.grid import CHANNELS

DEPTH = 2.0  # metres from the camera to the wall of gather points
SPACING = 0.05  # metres between neighbouring gather points (stride 12 at 2 m is ~0.05 m)
INTERLEAVE = 8


def _wall(rows: int, columns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gather points on a wall facing the camera (normal -z) at DEPTH: positions, normals, depth."""
    y, x = np.meshgrid(np.arange(rows) * SPACING, np.arange(columns) * SPACING, indexing="ij")
    points = np.stack([x, y, np.full_like(x, DEPTH)], -1).astype(np.float32)
    normals = np.zeros_like(points)
    normals[..., 2] = -1.0
    return points, normals, np.full((rows, columns), DEPTH, np.float32)


def _filtered(light: np.ndarray, points: np.ndarray, normals: np.ndarray, depth: np.ndarray) -> np.ndarray:
    out = np.zeros_like(light)
    interleave_filter(light, points, normals, depth, INTERLEAVE, slice(0, len(depth)), out)
    return out


def _block_mean(light: np.ndarray, points: np.ndarray, i: int, k: int) -> np.ndarray:
    """The weighted mean of the block the filter takes for point (i, k) at the grid's top-left corner (the block is
    shifted inside the grid: rows and columns 0..INTERLEAVE-1), weights 1 - (distance / reach)^2 on a plane."""
    reach = FILTER_REACH * DEPTH
    block = points[:INTERLEAVE, :INTERLEAVE] - points[i, k]
    weights = np.maximum(1.0 - np.sum(block**2, -1) / reach**2, 0.0)
    return np.tensordot(weights, light[:INTERLEAVE, :INTERLEAVE], axes=([0, 1], [0, 1])) / weights.sum()


def test_a_gradient_at_the_border_of_the_grid_is_taken_at_the_point_not_at_its_blocks_centre() -> None:
    # Light rising along the wall: the corner point's block lies wholly on one side of it, so its mean is
    # brighter than the light at the point (the old filter's value there).
    points, normals, depth = _wall(12, 12)
    light = np.repeat((1.0 + 4.0 * points[..., :1]), CHANNELS, axis=-1).astype(np.float32)
    out = _filtered(light, points, normals, depth)
    truth, mean = light[0, 0, 0], _block_mean(light, points, 0, 0)[0]
    assert mean - truth > 0.2  # the case is a real one: the mean is far off
    # The fit's ridge (FIT_RIDGE) pulls the slope towards the mean: a quarter of the bias goes here, not all.
    assert abs(out[0, 0, 0] - truth) < 0.8 * (mean - truth)
    assert np.all(out[..., 0] >= light[..., 0].min()) and np.all(out[..., 0] <= light[..., 0].max())


def test_flat_light_stays_flat_and_every_channel_is_filtered_alike() -> None:
    points, normals, depth = _wall(10, 14)
    rng = np.random.default_rng(3)
    light = np.full((10, 14, CHANNELS), 0.25, np.float32)
    light[..., 3:] = 0.5
    points += rng.normal(0.0, 0.002, points.shape).astype(np.float32)  # bumps well within the plane tolerance
    out = _filtered(light, points, normals, depth)
    np.testing.assert_allclose(out[..., :3], 0.25, rtol=1e-5)
    np.testing.assert_allclose(out[..., 3:], 0.5, rtol=1e-5)


def test_points_without_a_surface_stay_dark_and_lend_nothing() -> None:
    points, normals, depth = _wall(9, 9)
    depth[4, :] = np.inf  # a row of gather points that hit nothing
    light = np.ones((9, 9, CHANNELS), np.float32)
    light[4] = 100.0  # what such a point holds must never reach its neighbours
    out = _filtered(light, points, normals, depth)
    assert np.all(out[4] == 0.0)
    np.testing.assert_allclose(np.delete(out, 4, axis=0), 1.0, rtol=1e-5)
