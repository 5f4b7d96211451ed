"""Illumination: ambient is the albedo; spot follows I cos / d^2 with the cone and one exposure per job."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.config import Illumination, Job
from pipeline.render import lighting
from pipeline.render.lighting import (REFERENCE_DISTANCE_M, Shader, cone_falloff, cone_solid_angle, job_exposure,
                                      linear_to_srgb, srgb_to_linear)
from pipeline.render.raycaster import RayHits
from pipeline.render.renderer import VideoRenderer
from tests.render.tiny_scenes import embodiment, plane_scene


def _linear_centre(power: float, distance: float, exposure: float) -> float:
    body = embodiment(light=Illumination(kind="spot", power=power))
    rgb = VideoRenderer(plane_scene(distance), body, exposure).render(np.eye(4)).rgb
    return float(srgb_to_linear(rgb[23:25, 31:33, 0] / 255.0).mean())


def test_ambient_frame_is_the_surface_colour() -> None:
    rgb = VideoRenderer(plane_scene(2.0), embodiment(), exposure=1.0).render(np.eye(4)).rgb
    assert np.all(rgb == 200)


def test_ten_times_the_power_is_ten_times_the_linear_brightness() -> None:
    exposure = 1.0  # 200 W at 3 m: linear ~0.65, below clipping
    dim, bright = _linear_centre(20.0, 3.0, exposure), _linear_centre(200.0, 3.0, exposure)
    assert 0.02 < dim < bright < 1.0
    assert abs(bright / dim - 10.0) < 0.3  # 8-bit quantisation of the dim value


def test_spot_brightness_falls_with_the_square_of_distance_and_matches_the_model() -> None:
    exposure = 0.5
    near, far = _linear_centre(20.0, 1.5, exposure), _linear_centre(20.0, 3.0, exposure)
    assert abs(near / far - 4.0) < 0.15
    # Absolute value: albedo 200 -> rho = srgb_to_linear(200/255); on axis, cos = 1, cone factor 1:
    # L = rho * (P / 2 pi) / d^2 / pi, pixel linear = exposure * L.
    rho = float(srgb_to_linear(np.array(200 / 255.0)))
    expected = exposure * rho * (20.0 / (2 * math.pi)) / 1.5**2 / math.pi
    assert abs(near - expected) / expected < 0.02


def test_derived_exposure_is_fixed_per_job_by_its_brightest_light() -> None:
    job = Job(name="j", scenes={"procedural": {}}, embodiments=[
        embodiment(name="dim", light=Illumination(kind="spot", power=20.0)),
        embodiment(name="bright", light=Illumination(kind="spot", power=200.0)),
    ])
    # White on axis at the reference distance under the 200 W light is full scale.
    radiance = 200.0 / cone_solid_angle(180.0) / (math.pi * REFERENCE_DISTANCE_M**2)
    assert math.isclose(job_exposure(job), 1.0 / radiance)
    given = job.model_copy(update={"render": job.render.model_copy(update={"exposure": 3.0})})
    assert job_exposure(given) == 3.0


def test_cone_falloff_is_one_inside_and_zero_outside() -> None:
    light = Illumination(kind="spot", power=1.0, cone=60.0, blend=0.5)
    cosines = np.cos(np.radians([0.0, 10.0, 29.0, 31.0, 80.0]))
    falloff = cone_falloff(cosines, light)
    assert falloff[0] == 1.0 and falloff[1] == 1.0  # inside the unblended core
    assert 0.0 < falloff[2] < 1.0                 # inside the blend band near the edge
    assert falloff[3] == 0.0 and falloff[4] == 0.0  # outside the 30-degree half angle
    hard = cone_falloff(cosines, Illumination(kind="spot", power=1.0, cone=60.0, blend=0.0))
    assert hard.tolist() == [1.0, 1.0, 1.0, 0.0, 0.0]


def test_spot_light_outside_a_narrow_cone_is_black() -> None:
    body = embodiment(hfov=90.0, light=Illumination(kind="spot", power=200.0, cone=20.0, blend=0.0))
    rgb = VideoRenderer(plane_scene(1.0), body, exposure=0.5).render(np.eye(4)).rgb
    assert rgb[24, 32].max() > 0 and rgb[0, 0].max() == 0


def test_srgb_round_trip() -> None:
    values = np.linspace(0, 1, 11)
    assert np.allclose(linear_to_srgb(srgb_to_linear(values)), values, atol=1e-5)


def test_vertex_colours_are_interpolated_across_a_triangle() -> None:
    scene = plane_scene(2.0, half_size=2.0)
    x = scene.vertices[:, 0]
    # Red ramps from 0 at x = -2 to 200 at x = +2 (corner colours differ, so the fast flat path is off).
    scene.vertex_colors = np.stack([np.rint((x + 2.0) / 4.0 * 200), np.full_like(x, 50), np.full_like(x, 50)],
                                   axis=1).astype(np.uint8)
    camera_body = embodiment(width=64, height=48, hfov=90.0)
    rgb = VideoRenderer(scene, camera_body, exposure=1.0).render(np.eye(4)).rgb
    # The camera looks along +z with world +Y up as image down (identity pose): image column u sees
    # x = (u + 0.5 - 32) / 32 * 2 m; the interpolated red is linear in x (the plane is fronto-parallel).
    columns = np.arange(64)
    expected = ((columns + 0.5 - 32) / 32 * 2.0 + 2.0) / 4.0 * 200
    assert np.abs(rgb[24, :, 0].astype(float) - expected).max() <= 1.0
    assert np.all(rgb[..., 1] == 50)


def test_textures_are_sampled_at_the_nearest_texel() -> None:
    scene = plane_scene(2.0, half_size=2.0)
    # A 2 x 2 texture over the quad: u along +x, v along +y (image rows go down the texture).
    corners = scene.vertices[scene.faces][..., :2]
    scene.face_uvs = ((corners + 2.0) / 4.0).astype(np.float32)
    scene.face_material = np.zeros(len(scene.faces), np.uint16)
    scene.textures = [np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 0]]], np.uint8)]
    scene.vertex_colors = None
    rgb = VideoRenderer(scene, embodiment(width=64, height=48, hfov=90.0), exposure=1.0).render(np.eye(4)).rgb
    # Image row v looks at world y = (v + 0.5 - 24) / 32 * 2: top rows see y < 0, i.e. texture v < 0.5,
    # which is the bottom texture row (row 1); left columns see x < 0 -> texture column 0.
    assert rgb[2, 2].tolist() == [0, 0, 255]
    assert rgb[2, 61].tolist() == [255, 255, 0]
    assert rgb[45, 2].tolist() == [255, 0, 0]
    assert rgb[45, 61].tolist() == [0, 255, 0]


def _random_hits(seed: int, faces: int = 50, shape: tuple[int, int] = (37, 53)) -> tuple[np.ndarray, RayHits]:
    """Per-face colour records and hits of random faces in runs of 4 along rows (some misses: face == faces),
    with random geometry."""
    rng = np.random.default_rng(seed)
    corners = rng.integers(0, 256, (faces, 3, 3), dtype=np.uint8)
    records = np.zeros((faces + 1, 16), np.uint8)
    records[:-1, :9] = corners.reshape(faces, 9)
    # Runs of one face along rows (as rendered frames have; the loops take a face's terms once per run).
    face = np.repeat(rng.integers(0, faces + 1, (shape[0], shape[1] // 4 + 1)), 4, axis=1)[:, :shape[1]].astype(np.intp)
    face[rng.random(shape) < 0.2] = faces  # and misses inside runs
    hit = face < faces
    barycentric = rng.uniform(0.0, 0.5, (*shape, 2)).astype(np.float32)
    normal = rng.normal(size=(*shape, 3)).astype(np.float32) * hit[..., None]
    direction = np.concatenate([rng.uniform(-0.7, 0.7, (*shape, 2)), np.ones((*shape, 1))], -1).astype(np.float32)
    depth = np.where(hit, rng.uniform(0.05, 8.0, shape), np.inf).astype(np.float32)
    return records, RayHits(depth, face, barycentric, normal, direction, hit)


@pytest.mark.parametrize("kind", ["ambient", "spot"])
def test_the_loops_of_the_common_frames_equal_the_general_loop(kind: str) -> None:
    # Ambient and direct diffuse spot frames of vertex-coloured scenes are shaded by a loop of their own
    # (_vertex_colour_pixels): the same bytes as the general loop with those modes set.
    for seed in range(4):
        records, hits = _random_hits(seed)
        shader = Shader(Illumination(kind=kind, power=20.0), 0.5 + seed, np.linalg.norm(hits.direction, axis=-1))
        spot = kind == "spot"
        scale = shader._spot_scale_steps if spot else lighting._NO_SCALE
        fast = lighting._shade(hits, records=records, interpolate=True, scale_steps=scale if spot else None,
                               decode=shader._decode, encode=shader._encode)
        general = np.empty_like(fast)
        lighting._shade_pixels(records, lighting._NO_PLANES, True, True, spot, hits.face, hits.barycentric, hits.normal,
                               hits.direction, hits.depth, scale, shader._decode, shader._encode, general, False,
                               lighting._NO_TABLE, lighting._NO_TABLE, False, lighting._NO_INDIRECT, np.float32(1.0), 0,
                               lighting.INDIRECT_BLOCK)
        assert np.array_equal(fast, general)
        assert len(np.unique(fast)) > 50  # the frames are not trivially equal (all black or one colour)
