"""Depth sensor model: noise grows with z^2, dropouts, quantisation, seeded; the clean depth stays."""

from __future__ import annotations

import numpy as np

from pipeline.render.renderer import VideoRenderer
from pipeline.render.sensors import StructuredLightModel, depth_to_millimetres
from tests.render.tiny_scenes import embodiment, plane_scene


def _noisy(distance: float, seed: int, tilt: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    scene = plane_scene(distance)
    scene.vertices[:, 2] += tilt * scene.vertices[:, 0]
    frame = VideoRenderer(scene, embodiment(width=128, height=96, model="structured_light"), 1.0).render(
        np.eye(4), np.random.default_rng(seed))
    assert frame.depth_clean is not None
    return frame.depth, frame.depth_clean


def test_noise_grows_with_the_square_of_depth() -> None:
    near_noisy, near_clean = _noisy(1.0, 0)
    far_noisy, far_clean = _noisy(4.0, 0)
    assert np.all(near_clean == 1000) and np.all(far_clean == 4000)  # the clean depth stays available
    near_sigma = np.std(near_noisy.astype(float) - 1000.0)
    far_sigma = np.std(far_noisy.astype(float) - 4000.0)
    model = StructuredLightModel()
    expected_far = 1000 * (model.noise_a_m + model.noise_b_per_m * (4.0 - model.noise_z0_m) ** 2)  # ~25.8 mm
    assert far_sigma > 8 * near_sigma
    assert abs(far_sigma - expected_far) / expected_far < 0.2  # quantisation adds a little


def test_dropouts_beyond_the_working_range_and_at_grazing_angles() -> None:
    noisy, clean = _noisy(6.0, 0)
    assert np.all(clean == 6000) and np.all(noisy == 0)  # beyond 4.5 m
    noisy, clean = _noisy(0.3, 0)
    assert np.all(noisy == 0)  # nearer than 0.4 m
    # A plane tilted 60 degrees: incidence varies across the image (about 26 to 94 degrees); exactly the
    # pixels beyond 75 degrees drop out.
    slope = np.tan(np.radians(60.0))
    noisy, clean = _noisy(2.0, 0, tilt=slope)
    camera = VideoRenderer(plane_scene(1.0), embodiment(width=128, height=96), 1.0).camera
    directions = camera.directions()
    normal = np.array([-slope, 0.0, 1.0]) / np.linalg.norm([-slope, 0.0, 1.0])
    incidence = np.degrees(np.arccos(np.abs(directions @ normal) / np.linalg.norm(directions, axis=-1)))
    in_range = (clean > 450) & (clean < 4400)
    assert np.all(noisy[in_range & (incidence > 75.5)] == 0)
    assert np.all(noisy[in_range & (incidence < 74.5)] > 0)
    assert (in_range & (incidence > 75.5)).sum() > 100 and (in_range & (incidence < 74.5)).sum() > 100


def test_quantisation_follows_disparity_steps() -> None:
    model = StructuredLightModel()
    noisy, _ = _noisy(3.0, 1)
    values = np.unique(noisy[noisy > 0]) / 1000.0
    # Every reported depth is f b / (k / subpixel) for an integer k.
    steps = model.focal_px * model.baseline_m * model.subpixel / values
    assert np.allclose(steps, np.rint(steps), atol=0.02)


def test_noise_is_seeded() -> None:
    first, _ = _noisy(2.0, 7)
    again, _ = _noisy(2.0, 7)
    other, _ = _noisy(2.0, 8)
    assert np.array_equal(first, again) and not np.array_equal(first, other)


def test_depth_to_millimetres_clips() -> None:
    depth = np.array([np.inf, 0.005, 0.5, 1.2344, 1.2346, 65.535, 65.6, 900.0])
    assert depth_to_millimetres(depth, near=0.01, far=100.0).tolist() == [0, 0, 500, 1234, 1235, 65535, 0, 0]
