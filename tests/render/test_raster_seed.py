"""The previous winners' pass of the z-buffer (raster._draw's first phase): its buffers and how it takes the winners."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.render.raster import ClusteredMesh, Rasterizer
from pipeline.render.raycaster import Camera


def test_winners_are_int32_and_a_mesh_beyond_int32_indices_is_refused_in_one_line() -> None:
    """The winners (and the hints gathered from them) are int32: half the bytes every pass and the resolve move.
    A mesh whose triangle indices int32 cannot hold is refused before any buffer is made, in one line naming its
    size and the fix."""
    from pipeline.render.raster import _triangle_index_type

    assert _triangle_index_type(2**31) is np.int32  # indices 0 .. 2**31 - 1, and -1 for none
    with pytest.raises(ValueError) as refused:
        _triangle_index_type(2**31 + 1)
    message = str(refused.value)
    assert "\n" not in message and "2147483649 triangles" in message and "split" in message
    corners = np.array([[[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]]])
    camera = Camera(16, 12, 10.0, 10.0, 7.5, 5.5)
    rasterizer = Rasterizer(ClusteredMesh(corners.reshape(-1, 3), np.arange(3).reshape(1, 3)),
                            *camera.pixel_axes(), camera.fx, camera.fy)
    assert rasterizer.winner.dtype == np.int32
    rasterizer.visible_clusters(np.eye(4))
    rasterizer.draw_band(slice(0, camera.height), np.eye(4))
    assert rasterizer.winner.dtype == np.int32 and set(np.unique(rasterizer.winner)) == {-1, 0}
    assert all(buffer.dtype == np.int32 for buffer in rasterizer._scratch[(0, camera.height)]
               if buffer.size == camera.height * camera.width)


def _take(winner: np.ndarray, rank: np.ndarray, row_start: int, row_stop: int) -> tuple[list[int], np.ndarray,
                                                                                         np.ndarray]:
    """`_take_previous_winners` on a copy of `winner` (inverse depths all 1): its hints, z-buffer and winners."""
    from pipeline.render.raster import _take_previous_winners

    winner, inverse_depth = winner.copy(), np.ones(winner.shape, np.float32)
    hints = np.empty((row_stop - row_start) * winner.shape[1], winner.dtype)
    drawn = np.zeros(int(winner.max()) + 1, np.bool_)
    count = _take_previous_winners(rank, row_start, row_stop, inverse_depth, winner, hints, drawn)
    assert not drawn.any() or set(np.flatnonzero(drawn)) == set(hints[:count].tolist())
    return hints[:count].tolist(), inverse_depth, winner


def test_the_previous_winners_are_taken_once_each_in_the_order_they_first_appear() -> None:
    """Winners in runs along rows and down columns, none (-1) between them, clusters out of the view (rank -1):
    each triangle in view is taken once, in the order of its first pixel; the band's rows are emptied, the rows
    of other bands (above and below it) left as they were."""
    from pipeline.render.raster import CLUSTER_SIZE

    rng = np.random.default_rng(3)
    triangles = rng.integers(-1, 6 * CLUSTER_SIZE, (13, 11)).repeat(rng.integers(1, 4, 13), axis=0)
    winner = triangles.repeat(rng.integers(1, 5, 11), axis=1).astype(np.int32)
    winner[rng.random(winner.shape) < 0.1] = 7  # scattered pixels of one triangle
    rank = np.array([2, -1, 0, 1, -1, 3])
    for row_start, row_stop in ((0, len(winner)), (3, 9), (5, 6)):
        hints, inverse_depth, emptied = _take(winner, rank, row_start, row_stop)
        band = winner[row_start:row_stop].ravel().tolist()
        expected = [t for i, t in enumerate(band) if t >= 0 and rank[t // CLUSTER_SIZE] >= 0 and t not in band[:i]]
        assert hints == expected and len(expected) > 5
        assert (emptied[row_start:row_stop] == -1).all() and (inverse_depth[row_start:row_stop] == 0.0).all()
        outside = np.ones(len(winner), bool)
        outside[row_start:row_stop] = False
        assert np.array_equal(emptied[outside], winner[outside]) and (inverse_depth[outside] == 1.0).all()


def test_frames_drawn_in_bands_along_random_poses_are_the_bare_tests() -> None:
    """One rasterizer drawn in two bands along random poses (each frame seeded by the last one's winners) among
    random triangles: small and large ones, ones reaching past the image edges and behind the camera, and exact
    copies (ties, won by the first in the drawing order). Every frame's winners are the bare test's and its z-buffer
    is the one a new rasterizer draws in one band, bit for bit: the pixel loop's unsigned indices reach every pixel
    the signed ones did, and no other."""
    from pipeline.render.raster import ClusteredMesh
    from tests.render.test_raycaster import _bare_test_winners
    from tests.render.tiny_scenes import look_at

    rng = np.random.default_rng(29)
    centres = rng.uniform([-1.5, -1.0, -0.5], [1.5, 1.0, 2.5], (1200, 1, 3))
    corners = centres + rng.normal(0.0, 1.0, (1200, 1, 1)) ** 2 * rng.normal(0.0, 0.08, (1200, 3, 3))
    corners = np.concatenate([corners, corners[rng.choice(1200, 150, replace=False)]])  # copies: ties
    vertices, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    camera = Camera(64, 48, 40.0, 40.0, 31.7, 23.2)
    mesh = ClusteredMesh(vertices, faces)
    warm = Rasterizer(mesh, *camera.pixel_axes(), camera.fx, camera.fy)
    for _ in range(5):
        pose = look_at(rng.uniform([-0.8, -0.5, -1.5], [0.8, 0.5, 0.8]), rng.uniform([-1.0, -0.6, 1.0], [1.0, 0.6, 2.5]))
        _, expected = _bare_test_winners(vertices, faces, camera, pose)
        cold = Rasterizer(mesh, *camera.pixel_axes(), camera.fx, camera.fy)
        cold.visible_clusters(pose)
        cold.draw_band(slice(0, camera.height), pose)
        warm.visible_clusters(pose)
        for band in (slice(0, 17), slice(17, camera.height)):
            warm.draw_band(band, pose)
        assert np.array_equal(warm.winner, expected) and np.array_equal(cold.winner, expected)
        assert np.array_equal(warm.inverse_depth.view(np.uint32), cold.inverse_depth.view(np.uint32))
        assert (expected >= 0).mean() > 0.5
