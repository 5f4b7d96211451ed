"""Ray caster: exact planar depth, pixel-centre rays, misses."""

from __future__ import annotations

import numpy as np

from pipeline.config import Sensor
from pipeline.render.raycaster import Camera, SceneRaycaster
from pipeline.render.renderer import VideoRenderer
from tests.render.tiny_scenes import embodiment, plane_scene


def test_fronto_parallel_plane_depth_is_exact_to_one_millimetre() -> None:
    distance = 2.3456  # metres; planar depth must be 2346 mm at every pixel, including the corners
    renderer = VideoRenderer(plane_scene(distance), embodiment(hfov=90.0), exposure=1.0)
    frame = renderer.render(np.eye(4))
    assert frame.depth.dtype == np.uint16
    assert np.all(frame.depth == 2346)
    assert np.all(frame.panoptic == 5)


def test_tilted_plane_depth_matches_the_analytic_planar_depth() -> None:
    # Plane z = 3 + 0.5 x (world = camera frame). A ray (x', y', 1) t hits it at t = 3 / (1 - 0.5 x'),
    # and t is the planar depth because the ray's z component is 1.
    scene = plane_scene(3.0)
    scene.vertices[:, 2] += 0.5 * scene.vertices[:, 0]
    camera = Camera(64, 48, 40.0, 40.0, 32.0, 24.0)
    hits = SceneRaycaster(scene).cast(camera, np.eye(4))
    x = camera.directions()[..., 0]
    expected_mm = np.rint(3.0 / (1.0 - 0.5 * x) * 1000.0)
    assert np.abs(hits.depth * 1000.0 - expected_mm).max() <= 1.0


def test_rays_go_through_pixel_centres() -> None:
    camera = Camera(4, 2, 2.0, 2.0, 2.0, 1.0)
    directions = camera.directions()
    # With cx = W/2 the axis passes between the two middle columns: symmetric +-0.25, +-0.75.
    assert np.allclose(directions[0, :, 0], [-0.75, -0.25, 0.25, 0.75])
    assert np.allclose(directions[:, 0, 1], [-0.25, 0.25])
    assert np.all(directions[..., 2] == 1.0)


def test_misses_and_far_clip_are_void_with_zero_depth() -> None:
    sensor_far = Sensor(width=64, height=48, far=2.0)
    body = embodiment().model_copy(update={"sensor": sensor_far})
    # The plane at 3 m lies beyond the 2 m far clip: nothing is seen.
    frame = VideoRenderer(plane_scene(3.0), body, exposure=1.0).render(np.eye(4))
    assert np.all(frame.depth == 0) and np.all(frame.panoptic == 0) and np.all(frame.rgb == 0)
    # Looking away from the plane: every ray misses.
    backwards = np.diag([-1.0, 1.0, -1.0, 1.0])
    frame = VideoRenderer(plane_scene(1.0), embodiment(), exposure=1.0).render(backwards)
    assert np.all(frame.depth == 0) and np.all(frame.panoptic == 0)


def test_depth_beyond_uint16_range_is_zero_not_saturated() -> None:
    frame = VideoRenderer(plane_scene(70.0, half_size=500.0), embodiment(), exposure=1.0).render(np.eye(4))
    assert np.all(frame.depth == 0)
    assert np.all(frame.panoptic == 5)  # still labelled: the surface is seen, only its depth cannot be stored


def test_rays_are_the_camera_directions_rotated_into_the_world() -> None:
    camera = Camera(8, 6, 5.0, 4.0, 3.7, 3.1)
    angle = np.radians(30.0)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]]
    pose[:3, 3] = [1.0, -2.0, 0.5]
    hits = SceneRaycaster(plane_scene(1.0)).cast(camera, pose)
    expected = camera.directions() @ pose[:3, :3].T
    assert hits.direction.shape == (6, 8, 3) and hits.direction.dtype == np.float32
    assert np.abs(hits.direction - expected).max() < 1e-6


def test_threads_trace_the_same_hits_as_one_thread() -> None:
    scene = plane_scene(2.0, half_size=0.8)  # smaller than the view: the border rays miss
    scene.vertices[:, 2] += 0.3 * scene.vertices[:, 1]  # tilted: depth varies by row, across the bands
    camera = Camera(37, 29, 20.0, 20.0, 18.1, 14.3)  # odd sizes: partial packets at the right and bottom
    one, three = (SceneRaycaster(scene, threads=threads).cast(camera, np.eye(4)) for threads in (1, 3))
    for name in ("depth", "face", "barycentric", "normal", "direction", "hit"):
        assert np.array_equal(getattr(one, name), getattr(three, name)), name
    assert one.hit.any() and not one.hit.all()


def _both_casts(scene, camera: Camera, pose: np.ndarray) -> tuple:
    """The hits of the z-buffer and of the Embree packets (copies: each caster reuses its buffers)."""
    casts = []
    for rasterize in (True, False):
        hits = SceneRaycaster(scene, threads=2, rasterize=rasterize).cast(camera, pose)
        casts.append({name: getattr(hits, name).copy() for name in ("depth", "face", "barycentric", "normal",
                                                                      "direction", "hit")})
    return casts[0], casts[1]


def test_the_z_buffer_finds_the_hits_of_the_ray_cast() -> None:
    from tests.render.tiny_scenes import look_at, room_scene

    scene, camera = room_scene(), Camera(96, 71, 60.0, 60.0, 47.3, 35.9)
    for position, target in (([0.3, 1.0, -1.5], [0.5, 0.7, 1.0]), ([-1.0, 1.6, 1.0], [1.0, 0.2, -1.0]),
                             ([0.0, 0.05, 0.0], [0.0, 1.0, 2.0])):  # the last one grazes the floor
        raster, rays = _both_casts(scene, camera, look_at(np.array(position), np.array(target)))
        assert np.array_equal(raster["hit"], rays["hit"]) and raster["hit"].any()
        same = raster["face"] == rays["face"]
        assert same.mean() >= 0.999  # the rest: ties on shared edges
        both = same & rays["hit"]
        for name, tolerance in (("depth", 1e-5), ("barycentric", 1e-4), ("normal", 1e-6)):
            assert np.abs(raster[name][both] - rays[name][both]).max() <= tolerance, name
        assert np.array_equal(raster["direction"], rays["direction"])


def _bare_test_winners(vertices: np.ndarray, faces: np.ndarray, camera: Camera, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rasterizer's winners of one pose and what the bare test gives: every triangle at every pixel (edge
    values with the sign of det(a, b, c) all >= 0, the largest float32 1 / t, ties to the first in the
    drawing order), in the rasterizer's float64 arithmetic (corners relative to the camera, camera frame)."""
    from pipeline.render.raster import ClusteredMesh, Rasterizer

    rasterizer = Rasterizer(ClusteredMesh(vertices, faces), *camera.pixel_axes(), camera.fx, camera.fy)
    rasterizer.visible_clusters(pose)
    rasterizer.draw_band(slice(0, camera.height), pose)
    mesh = rasterizer.mesh
    order = np.concatenate([np.arange(mesh.starts[c], mesh.starts[c + 1]) for c in rasterizer.order])

    def to_camera(k: int) -> np.ndarray:
        p = mesh.corners[order, k].astype(np.float64) - pose[:3, 3]
        return np.stack([pose[0, i] * p[:, 0] + pose[1, i] * p[:, 1] + pose[2, i] * p[:, 2] for i in range(3)], 1)

    a, b, c = to_camera(0), to_camera(1), to_camera(2)
    pixel_x, pixel_y = camera.pixel_axes()
    x, y = pixel_x[None, :, None], pixel_y[:, None, None]  # (rows, columns, triangles) below
    normal = np.cross(b, c)
    det = normal[:, 0] * a[:, 0] + normal[:, 1] * a[:, 1] + normal[:, 2] * a[:, 2]
    inside = np.ones((camera.height, camera.width, len(order)), bool)
    total = 0.0
    for p, q in ((a, b), (b, c), (c, a)):
        edge = np.cross(p, q)
        value = edge[:, 0] * x + (edge[:, 1] * y + edge[:, 2])
        inside &= value * np.sign(det) >= 0.0
        total = total + value
    depth = np.where(inside & (det != 0.0), (total * (1.0 / det)).astype(np.float32), np.float32(0.0))
    best = depth.max(axis=-1)
    first = np.argmax((depth == best[..., None]) & (best[..., None] > 0.0), axis=-1)
    assert (det > 0.0).any() and (det < 0.0).any()  # both facings are exercised
    return rasterizer.winner, np.where(best > 0.0, order[first], -1)


def test_the_z_buffer_winner_is_that_of_testing_every_triangle_at_every_pixel() -> None:
    """The pixel spans, the occlusion culling and the second pass for facing-away triangles only skip work:
    each pixel's winner is the bare test's. Random triangles with slivers, coincident pairs of opposite
    facing and corners behind the camera."""
    rng = np.random.default_rng(7)
    centres = rng.uniform([-2.0, -1.5, 0.5], [2.0, 1.5, 6.0], (150, 1, 3))
    corners = centres + rng.normal(0.0, 0.4, (150, 3, 3))
    corners[:30, 2] = corners[:30, 0] + (corners[:30, 1] - corners[:30, 0]) * rng.uniform(0.0, 1.0, (30, 1)) + 1e-4
    corners = np.concatenate([corners, corners[-20:, ::-1]])  # the last 20 again, facing the other way
    vertices, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    winner, expected = _bare_test_winners(vertices, faces, Camera(48, 36, 30.0, 30.0, 23.5, 17.5), np.eye(4))
    assert (expected >= 0).mean() > 0.3
    assert np.array_equal(winner, expected)


def test_the_z_buffer_winner_of_pixel_sized_triangles_is_the_bare_tests() -> None:
    """Triangles of a few pixels down to slivers between pixel centres (their own box test, their
    pixel-by-pixel path, the facing told from their plane), seen from a turned camera off the origin:
    layers of them in front of each other, coincident pairs of opposite facing among them."""
    from tests.render.tiny_scenes import look_at

    rng = np.random.default_rng(11)
    centres = rng.uniform([-1.0, -0.8, 1.0], [1.0, 0.8, 1.6], (6000, 1, 3))
    corners = centres + rng.normal(0.0, 0.025, (6000, 3, 3))  # ~0.2-4 pixels across at 1-1.6 m
    corners[:200] = centres[:200] + rng.normal(0.0, 0.004, (200, 3, 3))  # mostly between pixel centres
    corners = np.concatenate([corners, corners[-300:, ::-1]])  # coincident, facing the other way
    vertices, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    pose = look_at(np.array([0.05, -0.03, -0.2]), np.array([0.0, 0.0, 1.3]))
    winner, expected = _bare_test_winners(vertices, faces, Camera(64, 48, 40.0, 40.0, 31.7, 23.2), pose)
    assert (expected >= 0).mean() > 0.4
    assert np.array_equal(winner, expected)


def test_the_z_buffer_sees_triangles_reaching_behind_the_camera_and_nearer_than_near() -> None:
    # A floor under the camera reaches 5 m behind it (the z-buffer clips nothing), and a small square 5 mm in
    # front of the camera is hit as the ray cast hits it (VideoRenderer.trace then makes it a miss).
    from pipeline.scenes.scene import Scene, SceneObject

    low, high, floor = -0.001, 0.002, 5.0
    vertices = np.array([[low, low, 0.005], [high, low, 0.005], [high, high, 0.005],
                         [low, high, 0.005], [-floor, 0.5, -floor], [floor, 0.5, -floor], [floor, 0.5, floor],
                         [-floor, 0.5, floor]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.int32)
    scene = Scene("near", vertices, faces, np.array([5, 5, 7, 7], np.uint32),
                  {5: SceneObject(5, "square", 39), 7: SceneObject(7, "floor", 2)},
                  vertex_colors=np.full((8, 3), 200, np.uint8))
    raster, rays = _both_casts(scene, Camera(64, 48, 30.0, 30.0, 31.7, 23.2), np.eye(4))
    assert np.array_equal(raster["face"], rays["face"]) and np.array_equal(raster["hit"], rays["hit"])
    assert set(np.unique(rays["face"])) == {0, 1, 2, 3, 4}  # both squares' triangles, both floor's, misses
    hit = rays["hit"]
    assert np.abs(raster["depth"][hit] - rays["depth"][hit]).max() <= 1e-5


def test_z_buffer_bands_of_any_split_give_the_same_hits() -> None:
    from pipeline.render.raster import ClusteredMesh, Rasterizer
    from tests.render.tiny_scenes import look_at, room_scene

    scene, camera = room_scene(), Camera(96, 71, 60.0, 60.0, 47.3, 35.9)
    pose = look_at(np.array([0.3, 1.0, -1.5]), np.array([0.5, 0.7, 1.0]))
    rasterizer = Rasterizer(ClusteredMesh(scene.vertices, scene.faces), *camera.pixel_axes(), camera.fx, camera.fy)
    rasterizer.visible_clusters(pose)
    winners = []
    for split in ([slice(0, 20), slice(20, 71)], [slice(0, 71)], [slice(0, 35), slice(35, 71)]):  # reused starts
        for band in split:
            rasterizer.draw_band(band, pose)
        winners.append(rasterizer.winner.copy())
    assert (winners[0] >= 0).all() and all(np.array_equal(winners[0], other) for other in winners[1:])


def test_of_two_triangles_at_equal_depth_the_first_wins_whichever_faces_the_camera() -> None:
    """The z-buffer draws triangles facing away from the camera last; a tie must still go to the triangle
    first in the mesh, as in one pass. Dyadic corners and pixel rays make both depths exactly equal."""
    from pipeline.render.raster import ClusteredMesh, Rasterizer

    vertices = np.array([[-1.0, -1.0, 4.0], [1.0, -1.0, 4.0], [0.0, 1.0, 4.0]])
    away, facing = [0, 1, 2], [0, 2, 1]  # det(a, b, c) > 0: normal (b - a) x (c - a) points away from the camera
    camera = Camera(8, 8, 8.0, 8.0, 4.5, 4.5)  # pixel rays (u - 4) / 8: exact
    for faces in ([away, facing], [facing, away]):
        rasterizer = Rasterizer(ClusteredMesh(vertices, np.array(faces)), *camera.pixel_axes(), camera.fx, camera.fy)
        rasterizer.visible_clusters(np.eye(4))
        rasterizer.draw_band(slice(0, 8), np.eye(4))
        covered = rasterizer.winner >= 0
        assert covered.sum() >= 4
        assert (rasterizer.mesh.face_ids[rasterizer.winner[covered]] == 0).all()


def test_closest_hits_within_a_reach_are_those_without_it_and_farther_ones_are_misses() -> None:
    from pipeline.render.embree import EmbreeMesh
    from tests.render.tiny_scenes import room_scene

    scene = room_scene()
    mesh = EmbreeMesh(scene.vertices, scene.faces)
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(4000, 3)).astype(np.float32)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    origins = np.repeat(np.array([[0.3, 1.2, -0.4]], np.float32), len(directions), 0)
    hits = []
    for reach in (np.inf, 1.8):
        out = (np.empty(len(origins), np.float32), np.empty(len(origins), np.int64),
               np.empty((len(origins), 2), np.float32), np.empty((len(origins), 3), np.float32))
        mesh.intersect(origins, directions, 0.0, out, reach)
        hits.append(out)
    (t, face, barycentric, normal), (t_near, face_near, barycentric_near, normal_near) = hits
    within = t < 1.8
    assert 0.1 < within.mean() < 0.9  # the reach cuts the room's rays both ways
    for everywhere, reached in ((t, t_near), (face, face_near), (barycentric, barycentric_near), (normal, normal_near)):
        assert np.array_equal(everywhere[within], reached[within])
    assert (face_near[~within] == -1).all() and np.isinf(t_near[~within]).all()


def _sheet(low: tuple[float, float], high: tuple[float, float], depth: float, cells: int, facing: bool,
           hole: tuple[float, float] | None = None) -> np.ndarray:
    """(T, 3, 3) triangle corners of a grid of cells x cells squares at planar depth `depth`, facing the
    camera at the origin (or away from it), without the squares whose centres lie within `hole` of x, y."""
    xs, ys = np.linspace(low[0], high[0], cells + 1), np.linspace(low[1], high[1], cells + 1)
    triangles = []
    for i in range(cells):
        for j in range(cells):
            centre = ((xs[i] + xs[i + 1]) / 2, (ys[j] + ys[j + 1]) / 2)
            if hole is not None and all(hole[0] < value < hole[1] for value in centre):
                continue
            p, q, r, s = ([xs[i], ys[j], depth], [xs[i + 1], ys[j], depth], [xs[i + 1], ys[j + 1], depth],
                          [xs[i], ys[j + 1], depth])
            # (b - a) x (c - a) along +z points away from a camera looking down +z.
            triangles += [[p, r, q], [p, s, r]] if facing else [[p, q, r], [p, r, s]]
    return np.array(triangles)


def test_facing_away_triangles_win_where_nothing_nearer_covers_them() -> None:
    """An open mesh seen from behind: a sheet facing away seen through a hole in a wall that faces the camera,
    and another one facing away in front of that wall. The second pass must still draw them where they
    are the nearest (through the hole, and over the wall), as the bare test finds."""
    from pipeline.render.raster import ClusteredMesh

    wall = _sheet((-1.2, -1.2), (1.2, 1.2), 1.5, 12, facing=True, hole=(-0.45, 0.45))
    behind = _sheet((-3.0, -3.0), (3.0, 3.0), 3.0, 10, facing=False)  # seen through the wall's hole
    corners = np.concatenate([wall, behind, _sheet((-1.0, -0.9), (-0.5, 0.9), 1.0, 4, facing=False)])
    vertices, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    winner, expected = _bare_test_winners(vertices, faces, Camera(48, 36, 30.0, 30.0, 23.5, 17.5), np.eye(4))
    assert np.array_equal(winner, expected)
    face_ids = ClusteredMesh(vertices, faces).face_ids
    won = face_ids[expected[expected >= 0]]  # mesh indices of the pixels' triangles
    assert (won < len(wall)).sum() > 100
    assert ((won >= len(wall)) & (won < len(wall) + len(behind))).sum() > 30  # through the hole
    assert (won >= len(wall) + len(behind)).sum() > 30  # nearer than the wall


def _hits_of(caster: SceneRaycaster, camera: Camera, pose: np.ndarray) -> dict[str, np.ndarray]:
    hits = caster.cast(camera, pose)
    return {name: getattr(hits, name).copy() for name in ("depth", "face", "barycentric", "normal", "direction")}


def test_a_frame_drawn_after_others_is_the_frame_drawn_first() -> None:
    """The z-buffer draws the previous frame's winners first (frame-to-frame coherence): a frame must come out
    bit for bit the same whatever was drawn before it: the previous pose of a walk, a pose far away, or
    nothing (the first frame of a video, a rerun from its middle); with one band and with two."""
    from tests.render.tiny_scenes import look_at, room_scene

    scene, camera = room_scene(), Camera(96, 71, 60.0, 60.0, 47.3, 35.9)
    walk = [look_at(np.array([0.3 + 0.05 * k, 1.0, -1.5 + 0.04 * k]), np.array([0.5 - 0.1 * k, 0.7, 1.0]))
            for k in range(6)]
    far = look_at(np.array([-1.0, 1.6, 1.0]), np.array([1.0, 0.2, -1.0]))
    for threads in (1, 2):
        warm = SceneRaycaster(scene, threads=threads)
        warm_frames = [_hits_of(warm, camera, pose) for pose in [*walk, far, walk[2]]]
        cold_frames = [_hits_of(SceneRaycaster(scene, threads=threads), camera, pose) for pose in [*walk, far, walk[2]]]
        for warm_frame, cold_frame in zip(warm_frames, cold_frames):
            for name in warm_frame:
                assert np.array_equal(warm_frame[name], cold_frame[name], equal_nan=True), name
        assert (warm_frames[0]["face"] != warm_frames[-3]["face"]).mean() > 0.05  # the walk does change the frame


def test_the_z_buffer_winner_is_the_bare_tests_whatever_winners_it_holds_before() -> None:
    """Any triangles left in the winner buffer (here random ones, coincident pairs of opposite facing among
    them, and the later of a tie) are drawn first and culled nothing they should not: the winners are the
    bare test's, ties to the first in this frame's drawing order."""
    from pipeline.render.raster import ClusteredMesh, Rasterizer
    from tests.render.tiny_scenes import look_at

    rng = np.random.default_rng(5)
    centres = rng.uniform([-1.0, -0.8, 1.0], [1.0, 0.8, 1.6], (3000, 1, 3))
    corners = centres + rng.normal(0.0, 0.03, (3000, 3, 3))
    corners = np.concatenate([corners, corners[-300:, ::-1]])  # coincident, facing the other way
    vertices, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    camera = Camera(64, 48, 40.0, 40.0, 31.7, 23.2)
    pose = look_at(np.array([0.05, -0.03, -0.2]), np.array([0.0, 0.0, 1.3]))
    _, expected = _bare_test_winners(vertices, faces, camera, pose)
    mesh = ClusteredMesh(vertices, faces)
    twin = np.argsort(mesh.face_ids)  # reordered index of each mesh triangle
    later_of_ties = twin[np.arange(len(corners) - 300, len(corners))]
    for history in (rng.integers(-1, len(corners), (48, 64)), np.resize(later_of_ties, (48, 64)),
                    np.where(expected >= 0, twin[len(corners) - 1 - mesh.face_ids[np.maximum(expected, 0)]], -1)):
        rasterizer = Rasterizer(mesh, *camera.pixel_axes(), camera.fx, camera.fy)
        rasterizer.winner[:] = history
        rasterizer.visible_clusters(pose)
        for band in (slice(0, 20), slice(20, 48)):
            rasterizer.draw_band(band, pose)
        assert np.array_equal(rasterizer.winner, expected)


def test_facing_away_triangles_seen_from_behind_win_in_a_walk() -> None:
    """The open mesh of `test_facing_away_triangles_win_where_nothing_nearer_covers_them` (sheets facing away
    seen through a hole in a wall and in front of it), drawn along a walk by one rasterizer, so each frame
    starts from the last one's winners, facing-away ones among them: every frame's winners are the bare test's."""
    from pipeline.render.raster import ClusteredMesh, Rasterizer

    wall = _sheet((-1.2, -1.2), (1.2, 1.2), 1.5, 12, facing=True, hole=(-0.45, 0.45))
    behind = _sheet((-3.0, -3.0), (3.0, 3.0), 3.0, 10, facing=False)
    corners = np.concatenate([wall, behind, _sheet((-1.0, -0.9), (-0.5, 0.9), 1.0, 4, facing=False)])
    vertices, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    camera = Camera(48, 36, 30.0, 30.0, 23.5, 17.5)
    mesh = ClusteredMesh(vertices, faces)
    rasterizer = Rasterizer(mesh, *camera.pixel_axes(), camera.fx, camera.fy)
    for step in range(5):
        pose = np.eye(4)
        pose[:3, 3] = [-0.04 * step, 0.02 * step, 0.04 * step]
        _, expected = _bare_test_winners(vertices, faces, camera, pose)
        rasterizer.visible_clusters(pose)
        rasterizer.draw_band(slice(0, camera.height), pose)
        assert np.array_equal(rasterizer.winner, expected), step
        won = mesh.face_ids[expected[expected >= 0]]
        assert ((won >= len(wall)) & (won < len(wall) + len(behind))).sum() > 30  # through the hole
        assert (won >= len(wall) + len(behind)).sum() > 30  # nearer than the wall


def test_triangles_just_behind_a_depth_edge_are_culled_by_their_pixels_only_when_behind_them_all() -> None:
    """Sheets of triangles a few tiles across cross the edge of a wall that ends inside an occlusion tile: just
    behind it (5e-5 of the depth), in its plane (ties) and just in front (5e-6). Their tiles straddle the edge,
    so they reach the test of the pixels of their box (PIXEL_BOX), which may cull them only where every pixel
    holds something nearer. Drawn again from the same pose (the wall among the first triangles drawn) and along
    a walk, every frame's winners are the bare test's."""
    from pipeline.render.raster import PIXEL_BOX, SMALL_BOX, ClusteredMesh, Rasterizer

    wall = _sheet((-1.2, -1.2), (0.1, 1.2), 1.5, 6, facing=True)  # its edge: column ~37 of tile 4 (32-39)
    sheets = [_sheet((-0.5, -0.4), (0.5, 0.4), 1.5 * (1 + 5e-5), 6, facing=True),
              _sheet((-0.5, -0.4), (0.5, 0.4), 1.5, 6, facing=True),
              _sheet((-0.5, -0.4), (0.2, 0.0), 1.5 * (1 - 5e-6), 6, facing=True)]  # the lower half, to x = 0.2
    corners = np.concatenate([wall, *sheets, _sheet((-3.0, -3.0), (3.0, 3.0), 3.0, 4, facing=False)])  # (seen from behind)
    vertices, faces = corners.reshape(-1, 3), np.arange(len(corners) * 3).reshape(-1, 3)
    camera = Camera(64, 48, 80.0, 80.0, 31.5, 23.5)
    box = (0.8 / 6 / 1.5 * 80) ** 2  # a sheet triangle's box, pixels (about)
    assert SMALL_BOX < box < PIXEL_BOX
    mesh = ClusteredMesh(vertices, faces)
    rasterizer = Rasterizer(mesh, *camera.pixel_axes(), camera.fx, camera.fy)
    for step in (0, 0, 1, 2, 3):
        pose = np.eye(4)
        pose[:3, 3] = [0.01 * step, -0.005 * step, 0.0]
        _, expected = _bare_test_winners(vertices, faces, camera, pose)
        rasterizer.visible_clusters(pose)
        rasterizer.draw_band(slice(0, camera.height), pose)
        assert np.array_equal(rasterizer.winner, expected), step
        won = mesh.face_ids[expected[expected >= 0]]
        in_front = len(wall) + 2 * len(sheets[0])
        assert ((won >= in_front) & (won < in_front + len(sheets[0]))).sum() > 100  # the sheet just in front
        assert ((won >= len(wall)) & (won < in_front)).sum() > 200  # the other two, right of the wall's edge


def test_cluster_lanes_hold_each_triangles_corners_in_its_clusters_block() -> None:
    """`ClusteredMesh.lanes` (what the batched set-up reads): triangle t's corner k coordinate j at
    (t // CLUSTER_SIZE) LANE_BLOCK + (3 k + j) CLUSTER_SIZE + t % CLUSTER_SIZE, the last short cluster padded."""
    from pipeline.render.raster import CLUSTER_SIZE, LANE_BLOCK, ClusteredMesh

    rng = np.random.default_rng(3)
    mesh = ClusteredMesh(rng.normal(size=(90, 3)), rng.integers(0, 90, size=(2 * CLUSTER_SIZE + 5, 3)))
    assert mesh.lanes.shape == (3 * LANE_BLOCK,) and mesh.lanes.dtype == np.float32
    blocks = mesh.lanes.reshape(3, 3, 3, CLUSTER_SIZE)  # cluster, corner, coordinate, slot
    triangles = np.arange(len(mesh.corners))
    assert np.array_equal(blocks[triangles // CLUSTER_SIZE, :, :, triangles % CLUSTER_SIZE], mesh.corners)
    assert not blocks[2, :, :, 5:].any()


def test_a_batch_set_up_is_each_triangles_own_arithmetic_bit_for_bit() -> None:
    """`_prepare` sets up a cluster's triangles on vector lanes: the camera-frame corners, det and projected
    pixel box must be the numbers of the scalar formulas, in the same order (a fused multiply-add or a
    reordering would change the last bits and, at a tie, a winner)."""
    from pipeline.render.raster import CLUSTER_SIZE, GEOMETRY_ROWS, SPAN_MARGIN, ClusteredMesh, _prepare

    rng = np.random.default_rng(5)
    mesh = ClusteredMesh(rng.normal(size=(200, 3)) + [0.0, 0.0, 4.0], rng.integers(0, 200, size=(CLUSTER_SIZE, 3)))
    pose = np.eye(4)
    pose[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    pose[:3, 3] = rng.normal(size=3)
    x0, y0, fx, fy = -0.7, -0.5, 457.3, 455.9
    geometry = np.full(GEOMETRY_ROWS * CLUSTER_SIZE, np.nan)
    _prepare(mesh.lanes, 0, CLUSTER_SIZE - 3, pose, x0, y0, fx, fy, geometry)
    rows = geometry.reshape(GEOMETRY_ROWS, CLUSTER_SIZE)[:, :CLUSTER_SIZE - 3]
    relative = mesh.corners[:CLUSTER_SIZE - 3].astype(np.float64) - pose[:3, 3]  # (T, 3 corners, 3)
    x, y, z = (pose[0, k] * relative[..., 0] + pose[1, k] * relative[..., 1] + pose[2, k] * relative[..., 2]
               for k in range(3))
    assert np.array_equal(rows[0:9], np.stack([x, y, z], axis=-1).reshape(-1, 9).T)
    (ax, bx, cx), (ay, by, cy), (az, bz, cz) = x.T, y.T, z.T
    det = ((by * cz - bz * cy) * ax + (bz * cx - bx * cz) * ay + (bx * cy - by * cx) * az)
    assert np.array_equal(rows[9], det)
    u, v = x * (1.0 / z), y * (1.0 / z)
    assert np.array_equal(rows[10], np.ceil((v.min(axis=1) - y0) * fy - SPAN_MARGIN))
    assert np.array_equal(rows[11], np.floor((v.max(axis=1) - y0) * fy + SPAN_MARGIN))
    assert np.array_equal(rows[12], np.ceil((u.min(axis=1) - x0) * fx - SPAN_MARGIN))
    assert np.array_equal(rows[13], np.floor((u.max(axis=1) - x0) * fx + SPAN_MARGIN))
    assert np.isnan(geometry.reshape(GEOMETRY_ROWS, CLUSTER_SIZE)[:, CLUSTER_SIZE - 3:]).all()
