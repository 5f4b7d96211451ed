"""Indirect light of the spot (virtual point lights) and the principled material: energy, zeros, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.config import Illumination, IndirectLight
from pipeline.render.indirect import IndirectGather, shadow_rays
from pipeline.render.indirect.light_paths import SURFACE_OFFSET, _landed as landed
from pipeline.render.indirect.shadow_rays import _accumulate as accumulate
from pipeline.render.lighting import SurfaceColors, srgb_to_linear
from pipeline.render.material import TABLE_SIZE, glossy_brdf, multiscatter_energy, reflection_tables
from pipeline.render.raycaster import SceneRaycaster
from pipeline.render.renderer import VideoRenderer
from tests.render.tiny_scenes import _Builder, embodiment, look_at, room_scene

GREY = 188  # sRGB level whose linear albedo is ~0.50


def _spot(bounces: int, material: str = "diffuse", lights: int = 256, traced: int = 2) -> Illumination:
    return Illumination(kind="spot", power=20.0, material=material, specular=1.0, roughness=0.5,
                        indirect=IndirectLight(bounces=bounces, traced_bounces=traced, virtual_lights=lights,
                                               gather_stride=4, interleave=2, clamp_distance=0.1))


def _box(size: float, colors: dict[int, tuple[int, int, int]] | None = None) -> tuple:
    """A closed cube [-size/2, size/2]^3 seen from inside (six quads), colour per side (default uniform grey)."""
    builder = _Builder()
    h = size / 2
    sides = [[[-h, -h, h], [h, -h, h], [h, h, h], [-h, h, h]], [[-h, -h, -h], [-h, h, -h], [h, h, -h], [h, -h, -h]],
             [[-h, -h, -h], [-h, -h, h], [-h, h, h], [-h, h, -h]], [[h, -h, -h], [h, h, -h], [h, h, h], [h, -h, h]],
             [[-h, h, -h], [-h, h, h], [h, h, h], [h, h, -h]], [[-h, -h, -h], [h, -h, -h], [h, -h, h], [-h, -h, h]]]
    for index, corners in enumerate(sides):
        builder.quad(np.array(corners, np.float32), index + 1, (colors or {}).get(index, (GREY, GREY, GREY)))
    return builder.scene("box"), sides


def _surface_samples(sides: list, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`count` points spread uniformly by area over the box's inside, with normals facing the centre."""
    points, normals = [], []
    for corners in sides:
        a, b, _, d = (np.array(c, float) for c in corners)
        u, v = rng.random((count // 6, 1)), rng.random((count // 6, 1))
        p = a + u * (b - a) + v * (d - a)
        centre = np.mean(np.array(corners, float), axis=0)
        points.append(p)
        normals.append(np.repeat((-centre / np.linalg.norm(centre))[None], len(p), 0))
    return np.concatenate(points), np.concatenate(normals)


def test_ambient_frames_equal_the_albedo_whatever_the_spot_settings() -> None:
    scene = room_scene()
    pose = look_at(np.array([0.0, 1.2, -1.5]), np.array([0.0, 0.5, 1.5]))
    renderer = VideoRenderer(scene, embodiment(), exposure=1.0)
    frame = renderer.render(pose)
    hits = renderer.trace(pose)
    assert np.array_equal(frame.rgb, SurfaceColors(scene).albedo(hits))
    assert frame.rgb[hits.hit].min() < frame.rgb[hits.hit].max()  # the view shows several colours


def test_indirect_light_is_zero_where_nothing_can_bounce() -> None:
    # Only the far wall (in view, flat: it cannot light itself) reflects; every other side is black.
    scene, _ = _box(4.0, colors={k: (0, 0, 0) for k in range(1, 6)} | {0: (200, 200, 200)})
    pose = look_at(np.zeros(3), np.array([0.0, 0.0, 2.0]))
    lit = VideoRenderer(scene, embodiment(light=_spot(bounces=3)), exposure=2.0)
    direct = VideoRenderer(scene, embodiment(light=_spot(bounces=0)), exposure=2.0)
    hits = lit.trace(pose)
    assert np.all(lit.indirect.irradiance(hits, pose) == 0.0)
    assert np.array_equal(lit.render(pose).rgb, direct.render(pose).rgb)
    # The same box with grey sides does bounce light onto the far wall.
    grey, _ = _box(4.0)
    light = VideoRenderer(grey, embodiment(light=_spot(bounces=1)), exposure=2.0).indirect.irradiance(hits, pose)
    assert light.shape == (48, 64, 6)  # one value per pixel of the 64 x 48 frame
    assert light[..., :3].min() > 0.0 and light[..., 3:].max() == 0.0  # diffuse: no glossy term


@pytest.mark.parametrize(("bounces", "traced"), [(1, 1), (2, 2), (8, 8), (8, 2)])
def test_closed_box_mean_radiance_approaches_direct_over_one_minus_albedo(bounces: int, traced: int) -> None:
    """Traced bounces add rho^k each; untraced ones (8, 2) repeat the last traced one times the measured ratio."""
    scene, sides = _box(2.0)
    rho = float(srgb_to_linear(np.array([GREY / 255.0]))[0])
    light = _spot(bounces=bounces, lights=64, traced=traced)
    gather = IndirectGather(SceneRaycaster(scene).mesh, SurfaceColors(scene), light, seed=0)
    pose = look_at(np.zeros(3), np.array([0.3, 0.2, 1.0]))
    points, normals = _surface_samples(sides, 3000, np.random.default_rng(1))
    indirect = gather.irradiance_at(points, normals, pose)[:, 0]
    # Every watt the spot emits lands on the box: the mean direct irradiance over its area is flux / area.
    direct_mean = gather.paths.ray_flux.sum() / (6 * 2.0 * 2.0)
    # Radiance is rho E / pi for direct and indirect alike: total / direct = 1 + rho + ... + rho^bounces.
    ratio = 1.0 + indirect.mean() / direct_mean
    expected = sum(rho**k for k in range(bounces + 1))
    assert ratio == pytest.approx(expected, rel=0.04)
    if bounces == 8:
        assert ratio == pytest.approx(1.0 / (1.0 - rho), rel=0.04)


def test_a_wide_clamp_costs_no_light_in_the_closed_box() -> None:
    """Lights nearer than 1 m count as 1 m away (12 % of the box's light lost); the near-field rays bring it back."""
    scene, sides = _box(2.0)
    rho = float(srgb_to_linear(np.array([GREY / 255.0]))[0])
    light = Illumination(kind="spot", power=20.0, indirect=IndirectLight(
        bounces=8, traced_bounces=8, virtual_lights=64, gather_stride=4, interleave=2, clamp_distance=1.0))
    gather = IndirectGather(SceneRaycaster(scene).mesh, SurfaceColors(scene), light, seed=0)
    points, normals = _surface_samples(sides, 3000, np.random.default_rng(1))
    indirect = gather.irradiance_at(points, normals, look_at(np.zeros(3), np.array([0.3, 0.2, 1.0])))[:, 0]
    ratio = 1.0 + indirect.mean() / (gather.paths.ray_flux.sum() / (6 * 2.0 * 2.0))
    assert ratio == pytest.approx(1.0 / (1.0 - rho), rel=0.04)


def test_russian_roulette_of_shadow_rays_casts_fewer_rays_and_keeps_the_mean(monkeypatch: pytest.MonkeyPatch) -> None:
    scene, sides = _box(2.0)
    gather = IndirectGather(SceneRaycaster(scene).mesh, SurfaceColors(scene), _spot(bounces=2, lights=256), seed=0)
    points, normals = _surface_samples(sides, 3000, np.random.default_rng(1))
    pose = look_at(np.zeros(3), np.array([0.3, 0.2, 1.0]))
    cast = []
    counted = lambda cells, *rest: (cast.append(len(cells)), accumulate(cells, *rest))  # noqa: E731
    monkeypatch.setattr(shadow_rays, "_accumulate", counted)
    with_roulette = gather.irradiance_at(points, normals, pose)
    monkeypatch.setattr(shadow_rays, "ROULETTE_BELOW", 0.0)
    every_ray = gather.irradiance_at(points, normals, pose)
    assert cast[0] < 0.6 * cast[1]
    assert with_roulette[:, 0].mean() == pytest.approx(every_ray[:, 0].mean(), rel=0.01)


def test_the_glossy_term_of_the_pairs_the_roulette_keeps_counts_as_their_irradiance_does(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # The glossy term is computed after the roulette has chosen (it does not enter the choice): it must take the
    # same weight 1 / p as the irradiance of its pair, or its mean drops to ~1/3 (the share of pairs kept).
    scene, sides = _box(2.0)
    gather = IndirectGather(SceneRaycaster(scene).mesh, SurfaceColors(scene),
                            _spot(bounces=2, material="principled", lights=256), seed=0)
    points, normals = _surface_samples(sides, 3000, np.random.default_rng(1))
    pose = look_at(np.zeros(3), np.array([0.3, 0.2, 1.0]))
    with_roulette = gather.irradiance_at(points, normals, pose)
    monkeypatch.setattr(shadow_rays, "ROULETTE_BELOW", 0.0)
    every_ray = gather.irradiance_at(points, normals, pose)
    assert every_ray[:, 3:].mean() > 0.02 * every_ray[:, :3].mean()  # the lobe does reflect some
    for channel in range(6):
        assert with_roulette[:, channel].mean() == pytest.approx(every_ray[:, channel].mean(), rel=0.01)


def _pairs_in_float64(points: np.ndarray, normals: np.ndarray, eyes: np.ndarray, lights, tables, clamp: float
                      ) -> np.ndarray:
    """(n, 6) the gather's sum over every light, pair by pair in float64 (no shadows, no roulette): irradiance
    Phi f_y cos_y cos_x / max(r^2, clamp^2) with f_y = base rho / pi + the light's lobe (widened after x's
    bounce), and x's glossy term pi f_x(to y, to the eye) times it."""
    def lobe(n, a, b, alpha):
        h = (a + b) / np.linalg.norm(a + b)
        cos_a, cos_b = n @ a, n @ b
        if min(cos_a, cos_b, n @ h, b @ h) <= 0:
            return 0.0
        entry = int(round(min(cos_b, 1.0) * (TABLE_SIZE - 1)))
        return glossy_brdf(n @ h, cos_a, cos_b, b @ h, alpha, tables.ior, np.float64) * tables.energy[entry]
    out = np.zeros((len(points), 6))
    lifted = points + normals * SURFACE_OFFSET * 2.0  # off the surface as the shadow rays start (at depth 1)
    for x, n, eye, total in zip(lifted.astype(float), normals.astype(float), eyes.astype(float), out):
        for y, m, w, flux, coloured in zip(*(part.astype(float) for part in (
                lights.positions, lights.normals, lights.incoming, lights.flux, lights.coloured_flux))):
            r = np.linalg.norm(y - x)
            d = (y - x) / r
            cos_x, cos_y = n @ d, -(m @ d)
            if cos_x <= 0 or cos_y <= 0:
                continue
            base = tables.diffuse[int(round(cos_y * (TABLE_SIZE - 1)))] / math.pi
            widened = max(tables.alpha, 0.5 * math.sqrt(max(0.0, 1.0 - cos_x / math.pi)))
            received = (coloured * base + flux * lobe(m, w, -d, widened)) * cos_x * cos_y / max(r * r, clamp * clamp)
            total[:3] += received
            total[3:] += received * math.pi * lobe(n, d, eye, tables.alpha)
    return out


def test_the_pairs_valued_on_simd_lanes_equal_the_sum_in_float64(monkeypatch: pytest.MonkeyPatch) -> None:
    # The pair loop runs branch-free in float32 (its masks are selects, its table reads a second loop): every
    # mask and term must still give the formula's value. Inside a convex box no pair is shadowed.
    scene, sides = _box(2.0)
    light = _spot(bounces=2, material="principled", lights=64)
    gather = IndirectGather(SceneRaycaster(scene).mesh, SurfaceColors(scene), light, seed=0)
    points, normals = _surface_samples(sides, 60, np.random.default_rng(2))
    pose = look_at(np.zeros(3), np.array([0.3, 0.2, 1.0]))
    eyes = (pose[:3, 3] - points) / np.linalg.norm(pose[:3, 3] - points, axis=1, keepdims=True)
    lights = gather.virtual_lights(pose)
    monkeypatch.setattr(shadow_rays, "ROULETTE_BELOW", 0.0)
    out = np.zeros((1, len(points), 6), np.float32)
    shadow_rays.gather_lights(gather.mesh, gather.tables, 0.1, 0, points[None].astype(np.float32),
                              normals[None].astype(np.float32), eyes[None].astype(np.float32),
                              np.ones((1, len(points)), np.float32), 0, 1, shadow_rays.light_rows(lights),
                              np.array([0, len(lights.positions)], np.int64), out)
    expected = _pairs_in_float64(points, normals, eyes, lights, gather.tables, 0.1)
    assert expected[:, 3:].max() > 0.01 * expected[:, :3].max()  # the glossy term is there to check
    np.testing.assert_allclose(out[0], expected, rtol=2e-3, atol=1e-5 * expected.max())


def test_same_seed_same_bytes_and_a_still_camera_does_not_flicker() -> None:
    scene = room_scene()
    pose = look_at(np.array([0.5, 1.0, -1.5]), np.array([0.0, 0.4, 1.5]))
    body = embodiment(light=_spot(bounces=2, material="principled"))
    first = VideoRenderer(scene, body, exposure=2.0, seed=7)
    frames = [first.render(pose).rgb.copy() for _ in range(2)]
    again = VideoRenderer(scene, body, exposure=2.0, seed=7).render(pose).rgb
    other = VideoRenderer(scene, body, exposure=2.0, seed=8).render(pose).rgb
    assert frames[0].tobytes() == frames[1].tobytes() == again.tobytes()
    assert other.tobytes() != again.tobytes()  # the seed does pick the pattern


def test_principled_highlight_at_normal_incidence_matches_the_ggx_lobe() -> None:
    tables = reflection_tables(_spot(bounces=0, material="principled"))
    alpha, f0 = 0.25, 0.08
    # mu = 1: D = 1 / (pi alpha^2), G2 = 1, Fresnel = F0; multiple scattering adds a little (< 1 / E_ss(1)).
    lobe = math.pi * (1.0 / (math.pi * alpha**2)) * f0 / 4.0
    assert lobe < tables.specular[-1] < lobe * 1.05
    # The diffuse base keeps what the lobe does not reflect; more is reflected at grazing angles.
    assert tables.diffuse[-1] == pytest.approx(1.0 - tables.albedo[-1])
    assert 0.07 < tables.albedo[-1] < 0.1 < tables.albedo[100]


def test_multiple_scattering_restores_what_a_mirror_lobe_loses_and_less_for_a_dielectric() -> None:
    single = np.array([0.6, 0.9, 1.0])
    # A perfect mirror (Fresnel 1) keeps every bounce between microfacets: the lobe is divided by its albedo.
    assert multiscatter_energy(single, 0.8, 1.0) == pytest.approx(1.0 / single)
    # A dielectric (average Fresnel 0.1) gets back only what its Fresnel lets through at each further bounce.
    dielectric = multiscatter_energy(single, 0.8, 0.1)
    assert np.all(dielectric[:2] > 1.0) and np.all(dielectric[:2] < 1.0 + 0.1 * (1.0 / single[:2] - 1.0))
    assert dielectric[2] == 1.0


def test_textured_scenes_bounce_their_texture_colours() -> None:
    # A textured room (every face one texel of a 1 x 1 texture): the bounce colours come from the texture.
    scene = room_scene()
    scene.face_uvs = np.zeros((len(scene.faces), 3, 2), np.float32)
    scene.face_material = np.zeros(len(scene.faces), np.uint16)
    scene.textures = [np.array([[[200, 40, 40]]], np.uint8)]
    scene.vertex_colors = None
    pose = look_at(np.array([0.0, 1.2, -1.5]), np.array([0.0, 0.5, 1.5]))
    hits = VideoRenderer(scene, embodiment(), exposure=2.0).trace(pose)
    assert np.all(SurfaceColors(scene).albedo_at(hits.face[hits.hit], hits.barycentric[hits.hit]) == [200, 40, 40])
    light = VideoRenderer(scene, embodiment(light=_spot(bounces=2)), exposure=2.0).indirect.irradiance(hits, pose)
    lit = light[hits.hit]
    assert np.all(lit[:, 0] > lit[:, 1])  # red walls bounce red light


def test_the_compiled_landing_gives_the_bytes_of_the_numpy_arithmetic_it_replaced() -> None:
    """Where rays land, the normal turned to the side the ray came from, the direction back (misses included)."""
    rng = np.random.default_rng(3)
    count = 999
    origins = rng.normal(size=(count, 3)).astype(np.float32)
    directions = rng.normal(size=(count, 3)).astype(np.float32) * np.float32(2.5)
    t = rng.random(count).astype(np.float32) * np.float32(7.0)
    face = np.where(rng.random(count) < 0.2, -1, rng.integers(0, 50, count))
    t[face < 0] = np.inf  # what Embree leaves for a miss
    normal = rng.normal(size=(count, 3)).astype(np.float32)
    expected_normal = normal.copy()
    expected = origins + directions * np.where(face >= 0, t, 0.0)[:, None]
    expected_normal *= np.where(np.sum(expected_normal * directions, axis=1) > 0, -1.0, 1.0)[:, None].astype(np.float32)
    expected_incoming = -directions / np.maximum(np.linalg.norm(directions, axis=1, keepdims=True), 1e-12)
    positions, incoming = landed(origins, directions, t, face, normal)
    assert positions.dtype == incoming.dtype == np.float32
    assert positions.tobytes() == expected.astype(np.float32).tobytes()
    assert normal.tobytes() == expected_normal.tobytes()
    assert incoming.tobytes() == expected_incoming.astype(np.float32).tobytes()


def test_a_wide_clamp_keeps_what_the_near_surfaces_lobes_reflect_in_a_principled_box() -> None:
    """The near field lets a near surface reflect its indirect light through its lobe as well as its base (it
    took the base alone: a 1 m clamp lost 4.5 % of the irradiance and 8.4 % of the glossy term that a 5 cm clamp
    keeps; now 2.9 % and 5.3 %, the rest being the near surfaces' own near field)."""
    scene, sides = _box(2.0)
    points, normals = _surface_samples(sides, 3000, np.random.default_rng(1))
    pose = look_at(np.zeros(3), np.array([0.3, 0.2, 1.0]))
    means = []
    for clamp in (1.0, 0.05):
        light = Illumination(kind="spot", power=20.0, material="principled", specular=1.0, roughness=0.5,
                             indirect=IndirectLight(bounces=8, traced_bounces=8, virtual_lights=256, gather_stride=4,
                                                    interleave=2, clamp_distance=clamp))
        gather = IndirectGather(SceneRaycaster(scene).mesh, SurfaceColors(scene), light, seed=0)
        means.append(gather.irradiance_at(points, normals, pose).mean(axis=0))
    wide, narrow = means
    assert wide[0] == pytest.approx(narrow[0], rel=0.035)  # irradiance
    assert wide[3] == pytest.approx(narrow[3], rel=0.065)  # glossy term


@pytest.mark.parametrize("material", ["diffuse", "principled"])
def test_light_meeting_a_surface_at_a_grazing_angle_bounces_on_forward_only_through_the_lobe(material: str) -> None:
    # A floor (normal +z) lit from the -x side at mu = 0.2: the principled lobe sends the light on forward (+x),
    # the diffuse base spreads it evenly (mean direction straight up).
    scene, _ = _box(2.0)
    light = _spot(bounces=2, material=material)
    gather = IndirectGather(SceneRaycaster(scene).mesh, SurfaceColors(scene), light, seed=0)
    count, mu = 100_000, 0.2
    normals = np.tile([0.0, 0.0, 1.0], (count, 1))
    incoming = np.tile([-math.sqrt(1.0 - mu * mu), 0.0, mu], (count, 1))  # back towards the light
    rho = np.full((count, 3), 0.5)
    directions, weights = gather.paths._scatter(normals, incoming, rho, np.random.default_rng(0).random((count, 3)))
    assert np.all(directions[:, 2][weights[:, 0] > 0] > 0)  # every surviving path leaves above the floor
    forward = np.sum(weights[:, 0] * directions[:, 0]) / np.sum(weights[:, 0])
    reflected = weights[:, 0].mean()
    if material == "diffuse":
        assert abs(forward) < 0.01
        assert reflected == pytest.approx(0.5, rel=1e-6)
    else:
        assert forward > 0.1
        # Base and lobe together reflect about what the tables say, within Cycles' own imbalance (its base
        # keeps 1 - A of the outgoing side, its widened lobes lose a little).
        assert reflected == pytest.approx(gather.paths._reflectance(normals[:1], incoming[:1], rho[:1])[0, 0], rel=0.1)


def _plank_in_a_box() -> tuple[VideoRenderer, np.ndarray]:
    """A plank seen edge-on (3 px wide, no gather point on it) facing the one wall that reflects (the right one;
    the others are black), and the pose that sees it; the box's 12 triangles come first."""
    _, sides = _box(4.0)
    builder = _Builder()
    for index, corners in enumerate(sides):
        builder.quad(np.array(corners, np.float32), index + 1, (230, 230, 230) if index == 3 else (0, 0, 0))
    plank = np.array([[-0.45, -1.0, 1.5], [-0.45, -1.0, 1.9], [-0.45, 1.0, 1.9], [-0.45, 1.0, 1.5]], np.float32)
    builder.quad(plank, 7, (GREY, GREY, GREY))
    light = Illumination(kind="spot", power=20.0, indirect=IndirectLight(
        bounces=1, traced_bounces=1, virtual_lights=1024, gather_stride=12, interleave=2, clamp_distance=0.1))
    renderer = VideoRenderer(builder.scene("box with a plank"), embodiment(light=light), exposure=2.0)
    return renderer, look_at(np.zeros(3), np.array([0.0, 0.0, 2.0]))


def _per_pixel(light: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The indirect light of every pixel, from one value per pixel or per block of pixels."""
    block = -(-shape[0] // light.shape[0])
    return np.repeat(np.repeat(light, block, axis=0), block, axis=1)[:shape[0], :shape[1]]


def test_a_surface_narrower_than_a_gather_cell_gathers_its_own_light() -> None:
    """The plank's pixels get the light of points on the plank, as the estimator finds there."""
    renderer, pose = _plank_in_a_box()
    hits = renderer.trace(pose)
    light = _per_pixel(renderer.indirect.irradiance(hits, pose), hits.depth.shape)
    on_plank = hits.face >= 12
    assert on_plank.sum(axis=1).max() <= 4 and on_plank.sum(axis=0).max() >= 20  # narrow and tall
    points = pose[:3, 3] + hits.depth[on_plank][:, None] * hits.direction[on_plank]
    normals = np.repeat(np.array([[1.0, 0.0, 0.0]]), len(points), 0)
    expected = renderer.indirect.irradiance_at(points, normals, pose)[:, 0].mean()
    assert expected > 0.0
    assert light[on_plank][:, 0].mean() == pytest.approx(expected, rel=0.25)


def test_every_pixel_takes_the_indirect_light_of_its_own_surface() -> None:
    """Indirect light is one value per pixel: a pixel of the plank beside the wall behind it keeps the plank's
    light, where 2 x 2 blocks gave the pixels of a block the light of its first pixel's surface."""
    renderer, pose = _plank_in_a_box()
    hits = renderer.trace(pose)
    light = _per_pixel(renderer.indirect.irradiance(hits, pose), hits.depth.shape)
    on_plank = hits.face >= 12
    plank_light = np.median(light[on_plank][:, 0])
    assert plank_light > 0.0
    # Every plank pixel within 25 % of the plank's median (a block's light from the black-lit wall is far off).
    assert np.all(np.abs(light[on_plank][:, 0] - plank_light) < 0.25 * plank_light), light[on_plank][:, 0]
