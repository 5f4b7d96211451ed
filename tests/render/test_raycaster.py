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
