"""The z-buffer's proofs in bulk (raster._hide_prepared, _defer + _hide_deferred): a triangle they drop as hidden
would win no pixel if it were drawn, and they do drop the triangles that lie behind what is drawn."""

from __future__ import annotations

import numpy as np

from pipeline.render.raycaster import Camera

CAMERA = Camera(64, 48, 60.0, 60.0, 31.5, 23.5)


def _random_triangles(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3, 3) corners of small triangles in front of, at and behind the walls of `_z_buffer`, some
    crossing the camera plane, some behind the camera, some degenerate, some pixel-wide, some many tiles wide."""
    depth = rng.choice([0.05, 0.9, 1.0, 1.5, 2.0, 2.5, 4.0, -1.0], size=count)
    depth *= 1.0 + rng.choice([0.0, 0.0, 1e-7, -1e-7, 1e-5, -1e-5, 1e-3, 0.2], size=count)  # ties, near-ties
    centre = np.stack([rng.uniform(-0.6, 0.6, count) * np.abs(depth), rng.uniform(-0.45, 0.45, count) * np.abs(depth),
                       depth], axis=1)
    size = rng.choice([0.002, 0.01, 0.03, 0.1, 0.6], size=count)[:, None, None] * np.abs(depth)[:, None, None]
    corners = centre[:, None, :] + rng.normal(size=(count, 3, 3)) * size * [1.0, 1.0, 0.2]
    corners[::17, 2] = corners[::17, 0]  # degenerate
    corners[::23, :, 2] = rng.uniform(-0.3, 0.3, size=(len(corners[::23]), 3))  # across the camera plane
    return corners.astype(np.float32)


def _z_buffer() -> tuple[np.ndarray, np.ndarray]:
    """The inverse depths and winners that fronto-parallel walls at 1, 1.5 and 2 m leave, drawn by the
    z-buffer's own arithmetic, with a gap through which nothing is seen; every winner is triangle 10**6 - 1, which
    comes after the triangles tested in the drawing order (so a tie with it would change a winner)."""
    from pipeline.render.raster import CLUSTER_SIZE, GEOMETRY_ROWS, ClusteredMesh, _draw_triangle, _prepare

    walls = []
    for depth, (x0, x1, y0, y1) in ((2.0, (-1.0, 0.3, -1.0, 1.0)), (1.5, (0.1, 1.2, -1.0, 0.2)),
                                    (1.0, (-0.2, 0.25, -0.1, 0.3))):
        walls += [[[x0, y0, depth], [x1, y1, depth], [x1, y0, depth]],
                  [[x0, y0, depth], [x0, y1, depth], [x1, y1, depth]]]
    walls = np.array(walls, np.float32)
    mesh = ClusteredMesh(walls.reshape(-1, 3), np.arange(walls.size // 3).reshape(-1, 3))
    inverse_depth = np.zeros((CAMERA.height, CAMERA.width), np.float32)
    winner = np.full(inverse_depth.shape, -1, np.int64)
    geometry = np.empty(GEOMETRY_ROWS * CLUSTER_SIZE)
    _prepare(mesh.lanes, 0, len(walls), np.eye(4), *_origin_and_focal(), geometry)
    tiles, dirty = _tiles()
    for slot in range(len(walls)):
        _draw_triangle(geometry, slot, slot, _whole(), *CAMERA.pixel_axes(), CAMERA.fx, CAMERA.fy, 0, CAMERA.height,
                       inverse_depth, winner, tiles, dirty, np.zeros(1, np.int64), False)
    assert (inverse_depth == 0).sum() > 100 and len(np.unique(inverse_depth)) > 3
    return inverse_depth, np.where(winner >= 0, 10**6 - 1, -1)


def _origin_and_focal() -> tuple[float, float, float, float]:
    pixel_x, pixel_y = CAMERA.pixel_axes()
    return pixel_x[0], pixel_y[0], CAMERA.fx, CAMERA.fy


def _whole() -> tuple[int, int, int, int]:
    return 0, CAMERA.height - 1, 0, CAMERA.width - 1


def _tiles() -> tuple[np.ndarray, np.ndarray]:
    from pipeline.render.raster import TILE

    shape = (-(-CAMERA.height // TILE), -(-CAMERA.width // TILE))
    return np.zeros(shape, np.float32), np.zeros(shape, np.bool_)


def _refreshed(inverse_depth: np.ndarray, band: tuple[int, int] = (0, CAMERA.height)) -> tuple[np.ndarray, np.ndarray]:
    """The occlusion tiles and the fine tiles of the rows `band` (by default the whole frame as one band), refreshed."""
    from pipeline.render.raster import FINE_TILE, TILE, _refresh_tiles

    rows = band[1] - band[0]
    tiles = np.zeros((-(-rows // TILE), -(-CAMERA.width // TILE)), np.float32)
    dirty = np.ones(tiles.shape, np.bool_)
    fine = np.full((-(-rows // FINE_TILE), -(-CAMERA.width // FINE_TILE)), np.nan, np.float32)
    _refresh_tiles(*band, inverse_depth, tiles, dirty, fine)
    assert not dirty.any()
    return tiles, fine


def _changes_the_frame(geometry: np.ndarray, slot: int, inverse_depth: np.ndarray, winner: np.ndarray,
                       band: tuple[int, int] = (0, CAMERA.height)) -> bool:
    """Whether drawing the prepared triangle of `slot` into the rows `band` (before the z-buffer's owner in the
    drawing order), without any occlusion test, changes a pixel's inverse depth or winner."""
    from pipeline.render.raster import _draw_triangle

    depth, won = inverse_depth.copy(), winner.copy()
    tiles, dirty = _tiles()
    _draw_triangle(geometry, slot, 0, _whole(), *CAMERA.pixel_axes(), CAMERA.fx, CAMERA.fy, *band, depth, won, tiles,
                   dirty, np.zeros(1, np.int64), False)
    return not (np.array_equal(depth, inverse_depth) and np.array_equal(won, winner))


def test_refreshed_tiles_hold_the_least_inverse_depth_of_their_pixels() -> None:
    from pipeline.render.raster import FINE_TILE, TILE, _refresh_tiles

    inverse_depth = np.random.default_rng(1).random((CAMERA.height, CAMERA.width - 3)).astype(np.float32)
    camera_width = inverse_depth.shape[1]  # 61: a last narrower column of tiles
    tiles = np.zeros((-(-CAMERA.height // TILE), -(-camera_width // TILE)), np.float32)
    dirty = np.ones_like(tiles, np.bool_)
    fine = np.zeros((-(-CAMERA.height // FINE_TILE), -(-camera_width // FINE_TILE)), np.float32)
    _refresh_tiles(0, CAMERA.height, inverse_depth, tiles, dirty, fine)
    for grid, side in ((tiles, TILE), (fine, FINE_TILE)):
        for row, column in np.ndindex(grid.shape):
            block = inverse_depth[side * row:side * (row + 1), side * column:side * (column + 1)]
            assert grid[row, column] == block.min()
    assert not dirty.any()


def test_triangles_proved_hidden_in_bulk_would_change_no_pixel() -> None:
    """Random triangles against a z-buffer of walls: each triangle `_hide_prepared` flags as hidden (not drawn
    before) leaves every pixel as it is when drawn without a test, ties included; it flags the previous winners,
    and most triangles behind the walls."""
    from pipeline.render.raster import CLUSTER_SIZE, GEOMETRY_ROWS, ClusteredMesh, _hide_prepared, _prepare

    rng = np.random.default_rng(7)
    inverse_depth, winner = _z_buffer()
    tiles, fine = _refreshed(inverse_depth)
    corners = _random_triangles(rng, 20 * CLUSTER_SIZE)
    mesh = ClusteredMesh(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3))
    geometry = np.empty(GEOMETRY_ROWS * CLUSTER_SIZE)
    changing, unseen_behind_walls = 0, []
    for cluster in range(len(mesh.starts) - 1):
        _prepare(mesh.lanes, cluster * CLUSTER_SIZE * 9, CLUSTER_SIZE, np.eye(4), *_origin_and_focal(), geometry)
        drawn = np.zeros(CLUSTER_SIZE, np.bool_)
        drawn[::5] = True
        skip = np.zeros(CLUSTER_SIZE, np.bool_)
        _hide_prepared(geometry, CLUSTER_SIZE, _whole(), 0, CAMERA.height, drawn, tiles, fine, skip)
        assert skip[drawn].all()
        for slot in np.flatnonzero(~drawn):
            changes = _changes_the_frame(geometry, slot, inverse_depth, winner)
            assert not (skip[slot] and changes), (cluster, slot)
            changing += changes
            if mesh.corners[cluster * CLUSTER_SIZE + slot, :, 2].min() > 2.01 and not changes:
                unseen_behind_walls.append(skip[slot])
    assert changing > 100  # the test has triangles that win pixels
    assert len(unseen_behind_walls) > 100 and np.mean(unseen_behind_walls) > 0.8  # most hidden ones are proved so


def test_deferred_triangles_proved_hidden_in_bulk_would_change_no_pixel() -> None:
    """The facing-away pass's bulk proofs: `_defer` keeps what `_hide_deferred` tests, drops the triangles that
    draw nothing, and `_hide_deferred` drops (in place, in order, each group's end moved) only triangles whose
    drawing would change no pixel, most of those behind every wall."""
    from pipeline.render.raster import CLUSTER_SIZE, GEOMETRY_ROWS, ClusteredMesh, _defer, _hide_deferred, _prepare

    rng = np.random.default_rng(11)
    inverse_depth, winner = _z_buffer()
    tiles, fine = _refreshed(inverse_depth)
    corners = _random_triangles(rng, 12 * CLUSTER_SIZE)
    mesh = ClusteredMesh(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3))
    clusters = len(mesh.starts) - 1
    geometry = np.empty((clusters, GEOMETRY_ROWS * CLUSTER_SIZE))
    deferred = np.empty(clusters * CLUSTER_SIZE, np.int64)
    closest, boxes = np.empty(len(deferred), np.float32), np.empty((len(deferred), 4), np.int16)
    groups, count, changes = np.empty((clusters, 2), np.int64), 0, {}
    for cluster in range(clusters):
        _prepare(mesh.lanes, cluster * CLUSTER_SIZE * 9, CLUSTER_SIZE, np.eye(4), *_origin_and_focal(),
                 geometry[cluster])
        for slot in range(CLUSTER_SIZE):
            triangle = cluster * CLUSTER_SIZE + slot
            changes[triangle] = _changes_the_frame(geometry[cluster], slot, inverse_depth, winner)
            deferred[count] = triangle
            kept = _defer(geometry[cluster], slot, _whole(), 0, CAMERA.height, closest, boxes, count)
            assert kept or not changes[triangle]
            count += kept
        groups[cluster] = cluster, count
    before = deferred[:count].copy()
    _hide_deferred(deferred, closest, boxes, groups, tiles, fine)
    after = deferred[:groups[-1, 1]]
    assert np.isin(after, before).all() and (np.diff(np.searchsorted(before, after)) > 0).all()  # a subsequence
    assert np.array_equal(groups[:, 0], np.arange(clusters)) and (np.diff(groups[:, 1]) >= 0).all()
    for cluster in range(clusters):
        start = groups[cluster - 1, 1] if cluster else 0
        assert (deferred[start:groups[cluster, 1]] // CLUSTER_SIZE == cluster).all()
    dropped = np.setdiff1d(np.arange(len(mesh.corners)), after)
    assert not any(changes[triangle] for triangle in dropped)
    seen = np.array([changes[triangle] for triangle in range(len(mesh.corners))])
    unseen_behind_walls = (mesh.corners[:, :, 2].min(axis=1) > 2.01) & ~seen
    assert sum(changes.values()) > 50 and unseen_behind_walls.sum() > 100
    assert np.isin(np.flatnonzero(unseen_behind_walls), dropped).mean() > 0.8
