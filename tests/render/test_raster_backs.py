"""The facing-away pass's proofs (raster._covered_tiles_behind): a triangle proved hidden by the fine tiles its
edges reach and its plane's depth over them would win no pixel if it were drawn (ties included), and the proof
holds where the box tests fail: slanted triangles and pixel boxes reaching past a silhouette."""

from __future__ import annotations

import numpy as np

from tests.render.test_bulk_proofs import (CAMERA, _changes_the_frame, _origin_and_focal, _random_triangles, _refreshed,
                                          _whole, _z_buffer)


def _prepared_clusters(corners: np.ndarray) -> tuple[np.ndarray, object]:
    """`_prepare`'s set-up of the triangles `corners` seen from the origin, (clusters, GEOMETRY_ROWS CLUSTER_SIZE),
    and their ClusteredMesh (whose order the slots follow)."""
    from pipeline.render.raster import CLUSTER_SIZE, GEOMETRY_ROWS, ClusteredMesh, _prepare

    mesh = ClusteredMesh(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3))
    geometry = np.empty((len(mesh.starts) - 1, GEOMETRY_ROWS * CLUSTER_SIZE))
    for cluster in range(len(geometry)):
        _prepare(mesh.lanes, cluster * CLUSTER_SIZE * 9, mesh.starts[cluster + 1] - mesh.starts[cluster], np.eye(4),
                 *_origin_and_focal(), geometry[cluster])
    return geometry, mesh


def _drawn(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse depths and winners that the triangles `corners` (camera frame) leave, drawn by the Rasterizer
    from the origin; every winner is triangle 10**6 - 1, which comes after the triangles tested in the drawing order."""
    from pipeline.render.raster import ClusteredMesh, Rasterizer

    corners = np.asarray(corners, np.float32)
    mesh = ClusteredMesh(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3))
    rasterizer = Rasterizer(mesh, *CAMERA.pixel_axes(), CAMERA.fx, CAMERA.fy)
    rasterizer.visible_clusters(np.eye(4))
    rasterizer.draw_band(slice(0, CAMERA.height), np.eye(4))
    return rasterizer.inverse_depth.copy(), np.where(rasterizer.winner >= 0, 10**6 - 1, -1)


def _slanted_z_buffer() -> tuple[np.ndarray, np.ndarray]:
    """A floor-like plane slanting from 0.6 m to 6 m over the lower half of the frame (nothing above it)."""
    inverse_depth, winner = _drawn([[[-3.0, 0.3, 0.6], [3.0, 0.3, 0.6], [3.0, 0.3, 6.0]],
                                    [[-3.0, 0.3, 0.6], [3.0, 0.3, 6.0], [-3.0, 0.3, 6.0]]])
    assert 0.4 < (inverse_depth > 0).mean() < 0.6
    return inverse_depth, winner


def _floor_triangles(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3, 3) triangles on, just below, below and above the plane of `_slanted_z_buffer`, of sizes from
    under a pixel to most of the frame, some reaching past its edge into the empty upper half."""
    centre = np.stack([rng.uniform(-2.5, 2.5, count), np.full(count, 0.3), rng.uniform(0.8, 5.5, count)], axis=1)
    size = rng.choice([0.005, 0.05, 0.3, 1.5], size=count)[:, None, None]
    corners = centre[:, None, :] + rng.normal(size=(count, 3, 3)) * size * [1.0, 0.0, 1.0]
    below = rng.choice([0.0, 0.0, 1e-7, 1e-6, 1e-3, 0.05, -1e-3], size=count)  # on it (ties), under it, above it
    corners[:, :, 1] += below[:, None]
    tilt = rng.choice([0.0, 0.0, 0.3], size=count)  # some lean up out of the plane (towards the empty half)
    corners[:, :, 1] -= tilt[:, None] * rng.uniform(0, 1, (count, 3))
    return corners.astype(np.float32)


def _proofs(corners: np.ndarray, inverse_depth: np.ndarray, winner: np.ndarray,
            band: tuple[int, int] = (0, CAMERA.height)) -> tuple[np.ndarray, ...]:
    """For each triangle (in the clustered mesh's order, returned last) drawn into the rows `band`: whether
    `_covered_tiles_behind` proves it hidden, whether `_draw_triangle`'s box tests (its nearest corner against every
    pixel of its box) do, and whether drawing it changes the frame."""
    from pipeline.render.raster import CLUSTER_SIZE, _covered_tiles_behind, _pixels_occluded, _prepared

    _, fine = _refreshed(inverse_depth, band)
    geometry, mesh = _prepared_clusters(corners)
    proved, box_proved, changes = [], [], []
    for triangle in range(len(corners)):
        cluster, slot = divmod(triangle, CLUSTER_SIZE)
        proved.append(_covered_tiles_behind(geometry[cluster], slot, _whole(), *band, *CAMERA.pixel_axes(),
                                            inverse_depth, fine))
        a, b, c, _, box = _prepared(geometry[cluster], slot)
        top, bottom = max(band[0], int(box[0])), min(band[1] - 1, int(box[1]))
        left, right = max(0, int(box[2])), min(CAMERA.width - 1, int(box[3]))
        z_min = min(a[2], b[2], c[2])
        box_proved.append(z_min > 1e-6 and (top > bottom or left > right or _pixels_occluded(
            top, bottom, left, right, z_min, inverse_depth)))
        changes.append(_changes_the_frame(geometry[cluster], slot, inverse_depth, winner, band))
    return np.array(proved), np.array(box_proved), np.array(changes), mesh


def test_triangles_proved_hidden_by_their_covered_tiles_would_change_no_pixel() -> None:
    """Random triangles against walls (depth edges, a gap) and against a slanted floor (triangles on it: exact and
    near ties), in the whole frame and in a band of rows: none proved hidden changes a pixel when drawn without a
    test, every one the box tests prove is proved (and more), and most hidden ones in front of the camera are."""
    rng = np.random.default_rng(31)
    for corners, (inverse_depth, winner) in ((_random_triangles(rng, 12 * 64), _z_buffer()),
                                             (_floor_triangles(rng, 12 * 64), _slanted_z_buffer())):
        for band in ((0, CAMERA.height), (13, 37)):
            proved, box_proved, changes, mesh = _proofs(corners, inverse_depth, winner, band)
            assert not (proved & changes).any(), np.flatnonzero(proved & changes)
            assert changes.sum() > 50 and (~changes).sum() > 200  # both kinds are tested
            assert not (box_proved & ~proved).any()  # what the box tests prove, this proves too
            in_front = mesh.corners[:, :, 2].min(axis=1) > 0.01
            assert proved[~changes & in_front].mean() > 0.8 and (proved & ~box_proved).sum() > 20


def test_covered_tiles_prove_slanted_triangles_the_box_tests_cannot() -> None:
    """Just under a slanted floor, a triangle's nearest corner is nearer than the floor at its far pixels, so the
    box tests fail; its plane's depth per tile proves most of those (and wins no pixel)."""
    rng = np.random.default_rng(32)
    corners = _floor_triangles(rng, 8 * 64)
    corners[:, :, 1] = np.float32(0.3 + 0.01)  # 1 cm under the floor, flat: hidden wherever the floor is drawn
    proved, box_proved, changes, _ = _proofs(corners, *_slanted_z_buffer())
    assert not (proved & changes).any()
    hidden_not_by_box = ~changes & ~box_proved
    assert hidden_not_by_box.sum() > 100
    assert proved[hidden_not_by_box].mean() > 0.5
    assert not (box_proved & ~proved).any()  # what the box proves, the covered tiles prove too


def test_a_box_reaching_past_a_silhouette_is_proved_by_the_tiles_its_edges_reach() -> None:
    """A sliver behind a large triangle at 1 m (a wall at 3 m behind both), along and inside its long edge: the
    sliver's pixel box reaches past that edge to the far wall, so the box tests fail, while the tiles its edges
    reach all lie on the near triangle and prove it hidden."""
    def at(depth: float, *rays: tuple[float, float]) -> list[list[float]]:
        return [[x * depth, y * depth, depth] for x, y in rays]

    near = at(1.0, (-0.6, -0.45), (0.6, -0.45), (-0.6, 0.45))
    far = [at(3.0, (-1, -1), (1, -1), (1, 1)), at(3.0, (-1, -1), (1, 1), (-1, 1))]
    inverse_depth, winner = _drawn([near, *far])
    # Points of the long edge pulled a quarter of the way towards the right angle's corner (-0.6, -0.45).
    inner = [(0.75 * x - 0.15, 0.75 * y - 0.1125) for x, y in ((0.45, -0.3375), (-0.45, 0.3375))]
    sliver = at(1.2, inner[0], inner[1], (inner[0][0] - 0.02, inner[0][1]))
    proved, box_proved, changes, _ = _proofs(np.array([sliver], np.float32), inverse_depth, winner)
    assert not changes[0] and not box_proved[0] and proved[0]
    moved_behind_the_far_wall = _proofs(np.array([sliver], np.float32) * np.float32(3.0), inverse_depth, winner)
    assert not moved_behind_the_far_wall[2][0] and moved_behind_the_far_wall[0][0]
    in_front = _proofs(np.array([at(0.9, *[(x, y) for x, y, _ in np.array(sliver) / 1.2])], np.float32),
                       inverse_depth, winner)
    assert in_front[2][0] and not in_front[0][0]  # in front of the near triangle: it wins pixels, never proved
