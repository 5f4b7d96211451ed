"""The near field: the light the clamp of the virtual lights leaves out, brought back by rays from each gather point
(Kollig and Keller's bias compensation).

Virtual lights clamp the 1/r^2 of near pairs (`clamp_distance`): a light nearer than that to a gather point counts
as that far. K = NEAR_FIELD_RAYS cosine rays per gather point x find the surfaces y nearer than the clamp; each
brings pi / K L_y (1 - r^2 / clamp^2), L_y being what y reflects towards x.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.config import Illumination
from pipeline.render.embree import EmbreeMesh
from pipeline.render.indirect.grid import CHANNELS
from pipeline.render.indirect.light_paths import SURFACE_OFFSET
from pipeline.render.indirect.sampling import (SEED_STREAM, local_directions, normal_frame, table_entry,
                                               widened_alpha)
from pipeline.render.lighting import LINEAR_OF_LEVEL, SurfaceColors, cone_falloff, radiant_intensity
from pipeline.render.material import ReflectionTables, glossy_brdf

# Rays per gather point that find the surfaces nearer than the clamp distance (bias compensation). 16 rather than 8:
# median PSNR at bench_light's poses, seeds 0 / 1 / 2: 37.10 / 36.64 / 36.84 dB against 36.67 / 36.26 / 36.02 (32
# rays: 37.08 / 36.48 / 36.93) for ~6 ms more per frame. Their noise, not the clamp's bias, held the estimator
# back: converged (every light, 4 seeds, poses 0/2/4/6) it gives 35.28 dB at 8 rays and 39.37 at 64.
NEAR_FIELD_RAYS = 16


def near_directions(seed: int, rows: int, columns: int) -> np.ndarray:
    """(rows, columns, NEAR_FIELD_RAYS, 3) cosine-distributed directions in the frame of a normal (z) of the
    near-field rays of a grid of gather points, stratified per point (fixed per job seed and grid)."""
    rays = NEAR_FIELD_RAYS
    rng = np.random.default_rng([seed, SEED_STREAM, 1])
    strata = (np.arange(rays) + rng.random((rows, columns, rays))) / rays
    cos_theta = np.sqrt(np.maximum(0.0, 1.0 - strata))
    return local_directions(cos_theta.ravel(), rng.random((rows, columns, rays)).ravel()).reshape(rows, columns, rays, 3)


def add_near_field(mesh: EmbreeMesh, colors: SurfaceColors, illumination: Illumination, tables: ReflectionTables,
                   points: np.ndarray, normals: np.ndarray, eyes: np.ndarray, depth: np.ndarray, local: np.ndarray,
                   camera_to_world: np.ndarray, gathered: np.ndarray) -> None:
    """Add to `gathered` the light the clamp of the virtual lights leaves out: K = NEAR_FIELD_RAYS cosine rays per
    gather point x (`local`: their directions in the frame of x's normal); a surface y hit at r < clamp brings
    pi / K L_y (1 - r^2 / clamp^2), L_y being what y reflects towards x: the spot's direct light (one shadow ray
    back to the camera) through the base and the lobe (widened as Filter Glossy does after x's bounce), and, as a
    stand-in for y's own indirect light, x's irradiance through the base and, as light arriving evenly, through
    the lobe's albedo (through the base alone, a 1 m clamp lost 4.5 % of a principled box's irradiance that a
    5 cm clamp keeps; now 2.9 %). The kernels keep the dtypes and the order of the operations of the numpy code
    they replace (float64 mostly), so frames stay the same to the byte."""
    clamp = illumination.indirect.clamp_distance
    camera = np.asarray(camera_to_world, np.float64)[:3, 3].copy()
    cells, origins, directions = _near_rays(points, normals, depth, local, camera, SURFACE_OFFSET)
    if len(cells) == 0:
        return
    count = len(origins)
    t, face = np.empty(count, np.float32), np.empty(count, np.int64)
    barycentric, hit_normals = np.empty((count, 2), np.float32), np.empty((count, 3), np.float32)
    # Only hits nearer than the clamp count: Embree may stop looking a margin beyond it (1 % + 1 mm, far more
    # than float32 rounding puts between t along the unit ray and the distance `_near_hits` tests).
    reach = 1.01 * clamp + 1e-3
    mesh.intersect(origins.astype(np.float32), directions.astype(np.float32), 0.0, (t, face, barycentric, hit_normals),
                   reach)
    axis = np.asarray(camera_to_world, np.float64)[:3, 2].copy()
    near, positions, distance, shadow_origins, shadow_directions, off_axis = _near_hits(
        origins, directions, t, face, hit_normals, camera, axis, clamp, SURFACE_OFFSET)
    if len(near) == 0:
        return
    blocked = np.empty(len(near), np.bool_)
    mesh.occluded(shadow_origins, shadow_directions, np.full(1, 1.0 - SURFACE_OFFSET, np.float32), blocked)
    spot = radiant_intensity(illumination) * cone_falloff(off_axis, illumination)
    rho = LINEAR_OF_LEVEL[colors.albedo_at(face[near], barycentric[near])]
    _near_light(near, cells, directions, positions, hit_normals, distance, rho, spot, blocked, normals, eyes, camera,
                clamp, tables.diffuse, tables.albedo, tables.energy, tables.alpha, tables.ior, gathered)

@numba.njit(nogil=True, cache=True)
def _near_rays(points, normals, depth, local, camera, offset):  # pragma: no cover (compiled)
    """The near-field rays of every gather point with a surface: its cell (flat index), and per ray the origin off
    the surface and the direction `local` turned into the frame of its normal (float64, `normal_frame`)."""
    columns, rays = depth.shape[1], local.shape[2]
    cells = np.flatnonzero(np.isfinite(depth.ravel()))
    origins = np.empty((len(cells) * rays, 3), np.float64)
    directions = np.empty((len(cells) * rays, 3), np.float64)
    x, gap = np.empty(3, np.float64), np.empty(3, np.float64)
    for m in range(len(cells)):
        i, k = cells[m] // columns, cells[m] % columns
        nx, ny, nz = np.float64(normals[i, k, 0]), np.float64(normals[i, k, 1]), np.float64(normals[i, k, 2])
        tx, ty, tz, bx, by, bz = normal_frame(nx, ny, nz, np.float64)
        for axis in range(3):
            x[axis] = points[i, k, axis]
            gap[axis] = x[axis] - camera[axis]
        away = np.sqrt(_dot(gap, gap))
        lift = offset * (1.0 + away)
        for q in range(rays):
            r = m * rays + q
            l0, l1, l2 = local[i, k, q, 0], local[i, k, q, 1], local[i, k, q, 2]
            directions[r, 0] = l0 * tx + l1 * bx + l2 * nx
            directions[r, 1] = l0 * ty + l1 * by + l2 * ny
            directions[r, 2] = l0 * tz + l1 * bz + l2 * nz
            origins[r, 0], origins[r, 1], origins[r, 2] = x[0] + nx * lift, x[1] + ny * lift, x[2] + nz * lift
    return cells, origins, directions


@numba.njit(nogil=True, cache=True)
def _near_hits(origins, directions, t, face, hit_normals, camera, axis, clamp, offset):  # pragma: no cover (compiled)
    """The near-field rays that land nearer than `clamp`: their indices, where they land (float32, as the ray
    arithmetic in float32 puts them), the distance from the ray's origin, and the shadow ray from there back to
    the spot (origin off the surface, direction: t in [0, 1)) with its cosine to the spot's axis. Turns
    `hit_normals` of those rays to the side the ray came from."""
    count = len(face)
    near = np.empty(count, np.int64)
    positions = np.empty((count, 3), np.float32)
    distance = np.empty(count, np.float64)
    m = 0
    for r in range(count):
        if face[r] < 0:
            continue
        squared = 0.0
        for a in range(3):
            positions[m, a] = np.float32(origins[r, a]) + np.float32(directions[r, a]) * t[r]
            gap = np.float64(positions[m, a]) - origins[r, a]
            squared += gap * gap
        distance[m] = np.sqrt(squared)
        if distance[m] < clamp:
            near[m] = r
            m += 1
    shadow_origins = np.empty((m, 3), np.float32)
    shadow_directions = np.empty((m, 3), np.float32)
    off_axis = np.empty(m, np.float64)
    to_light = np.empty(3, np.float64)
    for q in range(m):
        r = near[q]
        facing = (hit_normals[r, 0] * np.float32(directions[r, 0]) + hit_normals[r, 1] * np.float32(directions[r, 1])
                  + hit_normals[r, 2] * np.float32(directions[r, 2]))
        sign = np.float32(-1.0) if facing > 0 else np.float32(1.0)
        for a in range(3):
            hit_normals[r, a] *= sign
            to_light[a] = camera[a] - np.float64(positions[q, a])
        away = np.sqrt(_dot(to_light, to_light))
        lift = offset * (1.0 + away)
        off_axis[q] = -(to_light[0] / away * axis[0] + to_light[1] / away * axis[1] + to_light[2] / away * axis[2])
        for a in range(3):
            shadow_origins[q, a] = np.float32(np.float64(positions[q, a]) + np.float64(hit_normals[r, a]) * lift)
            shadow_directions[q, a] = np.float32(camera[a] - np.float64(shadow_origins[q, a]))
    return near[:m], positions[:m], distance[:m], shadow_origins, shadow_directions, off_axis


@numba.njit(nogil=True, cache=True)
def _near_light(near, cells, directions, positions, hit_normals, distance, rho, spot, blocked, normals, eyes, camera,
                clamp, diffuse, lobe_albedo, energy, alpha, ior, gathered):  # pragma: no cover (compiled)
    """Add to `gathered` what each near hit y brings its gather point x (see `_near_field`): pi / K (1 - r^2 /
    clamp^2) L_y, and x's lobe times that; every L_y reads x's irradiance before any is added."""
    rays, columns = NEAR_FIELD_RAYS, gathered.shape[1]
    contributions = np.empty((len(near), CHANNELS), np.float32)
    vectors = np.empty((8, 3), np.float64)  # scratch, one row per 3-vector (no allocation per ray)
    n, eye, d, y, m, towards_x, to_light, half = (vectors[0], vectors[1], vectors[2], vectors[3], vectors[4],
                                                  vectors[5], vectors[6], vectors[7])
    ray = np.empty(3, np.float32)
    for q in range(len(near)):
        r = near[q]
        cell = cells[r // rays]
        i, k = cell // columns, cell % columns
        for a in range(3):
            n[a], eye[a], d[a] = normals[i, k, a], eyes[i, k, a], directions[r, a]
            y[a], m[a], ray[a] = positions[q, a], hit_normals[r, a], directions[r, a]
            to_light[a] = camera[a] - y[a]
        # The direction back along the ray as the float32 landing computes it.
        length = max(np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2]), np.float32(1e-12))
        for a in range(3):
            towards_x[a] = -ray[a] / length
        away = np.sqrt(_dot(to_light, to_light))
        for a in range(3):
            to_light[a] /= away
        cos_at_x = _dot(n, d)
        direct = 0.0
        if not blocked[q]:
            direct = np.float64(spot[q]) * max(_dot(m, to_light), 0.0) / (away * away)
        base = diffuse[table_entry(_dot(m, towards_x))] / np.float32(math.pi)
        evenly = lobe_albedo[table_entry(_dot(m, towards_x))] / np.float32(math.pi)  # the lobe, light from all sides
        lobe = _lobe(m, to_light, towards_x, widened_alpha(alpha, cos_at_x, np.float64), ior, energy, half)
        seen = math.pi * _lobe(n, d, eye, np.float64(alpha), ior, energy, half)
        falloff = distance[q] / clamp
        for c in range(3):
            radiance = (np.float64(rho[q, c] * base) * (direct + np.float64(gathered[i, k, c])) + lobe * direct
                        + np.float64(evenly) * np.float64(gathered[i, k, c]))
            contribution = math.pi / rays * radiance * (1.0 - falloff * falloff)
            contributions[q, c] = contribution
            contributions[q, 3 + c] = contribution * seen
    for q in range(len(near)):
        cell = cells[near[q] // rays]
        for c in range(CHANNELS):
            gathered[cell // columns, cell % columns, c] += contributions[q, c]


@numba.njit(nogil=True, cache=True, inline="always")
def _dot(a, b):  # pragma: no cover (compiled)
    """The dot product of two 3-vectors, summed in numpy's order (x, then y, then z)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(nogil=True, cache=True)
def _lobe(normal, a, b, alpha, ior, energy, half):  # pragma: no cover (compiled)
    """The lobe f(a, b) M(cos_b) of a surface of `normal` between unit directions a and b (float64 3-vectors;
    `half`: scratch for their half vector)."""
    for axis in range(3):
        half[axis] = a[axis] + b[axis]
    half /= max(np.sqrt(_dot(half, half)), 1e-12)
    cos_a, cos_b, cos_h, cos_bh = _dot(normal, a), _dot(normal, b), _dot(normal, half), _dot(b, half)
    if not (cos_a > 1e-6 and cos_b > 1e-6 and cos_h > 0 and cos_bh > 0):
        return 0.0
    cos_a, cos_b, cos_bh = max(cos_a, 1e-6), max(cos_b, 1e-6), max(cos_bh, 1e-6)
    return glossy_brdf(cos_h, cos_a, cos_b, cos_bh, alpha, ior, np.float64) * np.float64(energy[table_entry(cos_b)])
