"""The cluster pass's bulk proof (raster._hide_prepared): it branches past the window test for the triangles already
decided (drawn before, drawing nothing, holding no pixel centre), and must flag exactly what the branch-free formula
flags, so that the frame is unchanged (random triangles against a z-buffer of walls, as tests/render/test_bulk_proofs)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from tests.render.test_bulk_proofs import CAMERA, _origin_and_focal, _random_triangles, _refreshed, _whole, _z_buffer


def _prepared_clusters(rng: np.random.Generator, clusters: int) -> Iterator[tuple[int, np.ndarray]]:
    """(cluster, its random triangles' set-up by `_prepare`, seen from the origin), for `clusters` clusters."""
    from pipeline.render.raster import CLUSTER_SIZE, GEOMETRY_ROWS, ClusteredMesh, _prepare

    corners = _random_triangles(rng, clusters * CLUSTER_SIZE)
    mesh = ClusteredMesh(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3))
    geometry = np.empty(GEOMETRY_ROWS * CLUSTER_SIZE)
    for cluster in range(clusters):
        _prepare(mesh.lanes, cluster * CLUSTER_SIZE * 9, CLUSTER_SIZE, np.eye(4), *_origin_and_focal(), geometry)
        yield cluster, geometry


def _flagged_by_formula(geometry: np.ndarray, slot: int, drawn: bool, tiles: np.ndarray, fine: np.ndarray) -> bool:
    """Whether the prepared triangle of `slot` is skipped: drawn before, draws nothing (degenerate, edge-on, behind
    the camera), or lies in front of the camera plane with no pixel centre in its clipped box or that box behind its
    window of tiles (`_box_behind`), written out for one triangle as `_hide_prepared` read before it branched."""
    from pipeline.render.raster import _BEHIND, _box_behind, _prepared

    a, b, c, det, box = _prepared(geometry, slot)
    top, bottom, left, right = _whole()
    z_min = min(a[2], b[2], c[2])
    nothing = det == 0.0 or (a[2] <= 0.0 and b[2] <= 0.0 and c[2] <= 0.0)
    if drawn or nothing:
        return True
    if not z_min > _BEHIND:
        return False
    box_top, box_bottom = max(box[0], top), min(box[1], bottom)
    box_left, box_right = max(box[2], left), min(box[3], right)
    if box_top > box_bottom or box_left > box_right:
        return True
    return bool(_box_behind(np.float32(1.0 / z_min * (1.0 + 1e-5)), int(box_top), int(box_bottom), int(box_left),
                            int(box_right), tiles, fine))


def test_hide_prepared_flags_what_the_branch_free_formula_flags() -> None:
    from pipeline.render.raster import CLUSTER_SIZE, _hide_prepared

    rng = np.random.default_rng(31)
    inverse_depth, _ = _z_buffer()
    tiles, fine = _refreshed(inverse_depth)
    flags = []
    for cluster, geometry in _prepared_clusters(rng, 24):
        drawn = rng.random(CLUSTER_SIZE) < 0.2
        skip = np.zeros(CLUSTER_SIZE, np.bool_)
        _hide_prepared(geometry, CLUSTER_SIZE, _whole(), 0, CAMERA.height, drawn, tiles, fine, skip)
        expected = [_flagged_by_formula(geometry, slot, drawn[slot], tiles, fine) for slot in range(CLUSTER_SIZE)]
        assert skip.tolist() == expected, cluster
        flags += expected
    # Both outcomes occur often (the test would notice a proof that flags everything or nothing).
    assert 0.2 < np.mean(flags) < 0.9


def test_culled_triangles_change_no_pixel() -> None:
    """`_draw_triangle`'s culls (pixels alone for a box of at most PIXELS_FIRST_BOX pixels, else the occlusion tiles,
    stale or not, then the pixels) never cull a winner: drawing each random triangle with them leaves the z-buffer
    as drawing it without them does, ties included (boxes of both sizes, some tiles stale and dirty)."""
    from pipeline.render.raster import CLUSTER_SIZE, PIXELS_FIRST_BOX, _draw_triangle

    rng = np.random.default_rng(8)
    inverse_depth, winner = _z_buffer()
    tiles, _ = _refreshed(inverse_depth)
    stale = np.where(rng.random(tiles.shape) < 0.5, tiles * np.float32(0.5), tiles)  # lower: stale, left dirty
    dirty = stale != tiles
    boxes = []
    for cluster, geometry in _prepared_clusters(rng, 16):
        for slot in range(CLUSTER_SIZE):
            frames = []
            for cull in (True, False):
                depth, won = inverse_depth.copy(), winner.copy()
                cull_tiles, cull_dirty = stale.copy(), dirty.copy()
                _draw_triangle(geometry, slot, 0, _whole(), *CAMERA.pixel_axes(), CAMERA.fx, CAMERA.fy, 0,
                               CAMERA.height, depth, won, cull_tiles, cull_dirty, np.zeros(1, np.int64), cull)
                frames.append((depth, won))
            (culled_depth, culled_won), (depth, won) = frames
            assert np.array_equal(culled_depth, depth) and np.array_equal(culled_won, won), (cluster, slot)
            top, bottom, left, right = (geometry[(10 + k) * CLUSTER_SIZE + slot] for k in range(4))
            boxes.append((bottom - top + 1) * (right - left + 1))
    boxes = np.array(boxes)
    assert ((boxes > 4) & (boxes <= PIXELS_FIRST_BOX)).sum() > 50 and (boxes > PIXELS_FIRST_BOX).sum() > 50
