"""The previous winners' pass of the z-buffer (raster._draw's first phase): its buffers and its own pixel loop."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.render.raster import ClusteredMesh, Rasterizer, _triangle_index_type
from pipeline.render.raycaster import Camera


def test_winners_are_int32_and_a_mesh_beyond_int32_indices_is_refused_in_one_line() -> None:
    """The winners (and the hints gathered from them) are int32: half the bytes every pass and the resolve move.
    A mesh whose triangle indices int32 cannot hold is refused before any buffer is made, in one line naming its
    size and the fix."""
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


def test_the_winners_pass_draws_what_the_general_draw_does_without_culls_and_flags_no_tile() -> None:
    """`_draw_previous_winner` against `_draw_triangle` without culls, on random triangles (slivers, degenerate ones,
    corners behind the camera or across its plane, ties and near-ties of depth, exact copies under other indices
    and clusters of other ranks, drawn in a shuffled order, in a band and in the whole frame): the same inverse
    depths and winners bit for bit after every triangle, and no tile flagged dirty (the general draw flags some)."""
    from pipeline.render.raster import (CLUSTER_SIZE, GEOMETRY_ROWS, _draw_previous_winner, _draw_triangle, _gather,
                                        _prepare)
    from tests.render.test_bulk_proofs import CAMERA, _origin_and_focal, _random_triangles, _tiles

    rng = np.random.default_rng(11)
    corners = _random_triangles(rng, 5 * CLUSTER_SIZE)
    corners[CLUSTER_SIZE:2 * CLUSTER_SIZE] = corners[:CLUSTER_SIZE]  # copies: ties at every pixel they cover
    corners[3 * CLUSTER_SIZE:4 * CLUSTER_SIZE:2] = corners[2 * CLUSTER_SIZE:3 * CLUSTER_SIZE:2]
    mesh = ClusteredMesh(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3))
    rank = rng.permutation(len(mesh.starts) - 1)
    pixel_x, pixel_y = CAMERA.pixel_axes()
    for row_start, row_stop in ((0, CAMERA.height), (13, 37)):
        depths = [np.zeros((CAMERA.height, CAMERA.width), np.float32) for _ in range(2)]
        winners = [np.full((CAMERA.height, CAMERA.width), -1, np.int32) for _ in range(2)]
        flags = [_tiles()[1] for _ in range(2)]
        tiles = _tiles()[0]
        order = rng.permutation(len(corners)).astype(np.int32)
        batch, geometry = np.empty(9 * CLUSTER_SIZE, np.float32), np.empty(GEOMETRY_ROWS * CLUSTER_SIZE)
        for start in range(0, len(order), CLUSTER_SIZE):
            triangles = order[start:start + CLUSTER_SIZE]
            _gather(mesh.lanes, triangles, batch)
            _prepare(batch, 0, len(triangles), np.eye(4), *_origin_and_focal(), geometry)
            for slot, triangle in enumerate(triangles):
                rect = (0, CAMERA.height - 1, 0, CAMERA.width - 1)
                _draw_triangle(geometry, slot, triangle, rect, pixel_x, pixel_y, CAMERA.fx, CAMERA.fy, row_start,
                               row_stop, depths[0], winners[0], tiles, flags[0], rank, False)
                _draw_previous_winner(geometry, slot, triangle, rect, pixel_x, pixel_y, CAMERA.fx, row_start,
                                      row_stop, depths[1], winners[1], flags[1], rank)
                assert np.array_equal(depths[0].view(np.int32), depths[1].view(np.int32))
                assert np.array_equal(winners[0], winners[1])
        assert flags[0].any() and not flags[1].any()
        drawn = winners[0][row_start:row_stop] >= 0
        assert drawn.mean() > 0.3 and (winners[0] >= CLUSTER_SIZE).any()
        assert (winners[0][:row_start] == -1).all() and (winners[0][row_stop:] == -1).all()
