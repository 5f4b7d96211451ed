"""Gather: what the virtual lights bring each gather point past one shadow ray each.

Every gather point x sums E = sum_j Phi_j f_j cos_j cos_x / max(r^2, clamp^2) over the virtual lights it
sees, and the glossy term sum_j E_j pi f_x. Interleaved sampling (Keller and Heidrich 2001): the lights are
split into interleave^2 stratified subsets and neighbouring gather points take different subsets, so each point
pays for 1 / interleave^2 of the shadow rays; Russian roulette skips most rays of lights that bring a point
little (`_roulette`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.render.embree import EmbreeMesh
from pipeline.render.indirect.grid import CHANNELS
from pipeline.render.indirect.light_paths import SURFACE_OFFSET, VirtualLights
from pipeline.render.indirect.sampling import widened_alpha
from pipeline.render.material import TABLE_SIZE, ReflectionTables, glossy_brdf

# Russian roulette on shadow rays: a pair bringing less than this many times its gather point's mean
# contribution keeps its ray with probability contribution / (ROULETTE_BELOW mean), weighted 1 / p (unbiased).
# Far and grazing lights bring little: at 2304 lights per bounce 35 % of the rays are cast, which pays for
# 2.25x the lights of 1024 (fewer of the blotches a light leaves where it lands near a surface: +0.5 dB).
ROULETTE_BELOW = 2.0


def gather_lights(mesh: EmbreeMesh, tables: ReflectionTables, clamp_distance: float, seed: int, points: np.ndarray,
                  normals: np.ndarray, eyes: np.ndarray, depth: np.ndarray, row_offset: int, interleave: int,
                  lights: VirtualLights, starts: np.ndarray, out: np.ndarray) -> None:
    """Add to `out` (rows, columns, 6) what the lights of each point's subset bring it past the shadow rays
    (lights sorted by subset: subset g is starts[g]..starts[g + 1]; `row_offset`: the grid row of row 0)."""
    shadow = _shadow_rays(points, normals, eyes, depth, row_offset, interleave, lights.positions, lights.normals,
                          lights.incoming, lights.flux, lights.coloured_flux, starts, np.float32(clamp_distance ** 2),
                          np.float32(SURFACE_OFFSET), tables.diffuse, tables.energy, tables.alpha, tables.ior,
                          np.float32(ROULETTE_BELOW), np.uint64(seed))
    cells, contributions, ray_origins, ray_directions = shadow
    blocked = np.empty(len(cells), np.bool_)
    mesh.occluded(ray_origins, ray_directions, np.full(1, 1.0 - SURFACE_OFFSET, np.float32), blocked)
    _accumulate(cells, contributions, blocked, out)


@numba.njit(nogil=True, cache=True, inline="always")
def _entry(mu):  # pragma: no cover (compiled)
    """The material tables' entry of a cosine in [0, 1]."""
    return np.int32(min(mu, np.float32(1.0)) * np.float32(TABLE_SIZE - 1) + np.float32(0.5))


@numba.njit(nogil=True, cache=True, inline="always")
def _glossy(nx, ny, nz, ax, ay, az, bx, by, bz, cos_a, cos_b, energy, alpha, ior):  # pragma: no cover (compiled)
    """The lobe f(a, b) / E_ss(cos_b) of a surface of normal n between unit directions a and b (0 for IOR 1)."""
    if ior == 1.0:
        return np.float32(0.0)
    hx, hy, hz = ax + bx, ay + by, az + bz
    length = np.sqrt(hx * hx + hy * hy + hz * hz)
    if length <= np.float32(1e-6):
        return np.float32(0.0)
    cos_h = (nx * hx + ny * hy + nz * hz) / length
    cos_bh = (bx * hx + by * hy + bz * hz) / length
    if cos_h <= 0 or cos_bh <= 0:
        return np.float32(0.0)
    return np.float32(glossy_brdf(cos_h, cos_a, cos_b, cos_bh, alpha, ior)) * energy[_entry(cos_b)]


@numba.njit(nogil=True, cache=True)
def _shadow_rays(points, point_normals, eyes, point_depth, row_offset, interleave, positions, normals, incoming, flux,
                 coloured_flux, starts, clamp2, offset, base, energy, alpha, ior, roulette_below,
                 seed):  # pragma: no cover (compiled)
    """Every (gather point, light of its subset) pair that faces each other: the cell, the unshadowed
    contribution (irradiance RGB, glossy term RGB) and the shadow ray (origin off the surface, direction to
    the light: t in [0, 1)). A light at y lit from w_i sends the point x the irradiance
    Phi f_y(w_i, y->x) cos_y cos_x / max(r^2, clamp^2), f = base rho / pi + lobe (material.py); x's own lobe
    reflects pi f_x(x->y, x->eye) times that towards the eye (the glossy term)."""
    rows, columns = point_depth.shape
    largest = 0
    for group in range(len(starts) - 1):
        largest = max(largest, starts[group + 1] - starts[group])
    # Sized by the points with a surface: the grid of orphan blocks (`_fill_orphans`) has few among many cells.
    most = np.count_nonzero(np.isfinite(point_depth)) * largest
    cells = np.empty(most, np.int64)
    contributions = np.empty((most, CHANNELS), np.float32)
    origins = np.empty((most, 3), np.float32)
    directions = np.empty((most, 3), np.float32)
    lights = np.empty(most, np.int64)
    # Per pair until the roulette has chosen: the irradiance in float64 (the glossy term multiplies it before it is
    # rounded), the distance to the light (`directions` holds the unit direction) and the roulette's weight.
    received = np.empty((most, 3), np.float64)
    distances = np.empty(most, np.float32)
    weights = np.empty(most, np.float32)
    n = 0
    inverse_pi, pi = np.float32(1.0 / math.pi), np.float32(math.pi)
    for i in range(rows):
        for k in range(columns):
            z = point_depth[i, k]
            if not np.isfinite(z):
                continue
            group = ((i + row_offset) % interleave) * interleave + k % interleave
            lift = offset * (np.float32(1.0) + z)
            nx, ny, nz = point_normals[i, k, 0], point_normals[i, k, 1], point_normals[i, k, 2]
            ex, ey, ez = eyes[i, k, 0], eyes[i, k, 1], eyes[i, k, 2]
            cos_eye = nx * ex + ny * ey + nz * ez
            px, py, pz = points[i, k, 0] + nx * lift, points[i, k, 1] + ny * lift, points[i, k, 2] + nz * lift
            first = n
            for j in range(starts[group], starts[group + 1]):
                dx, dy, dz = positions[j, 0] - px, positions[j, 1] - py, positions[j, 2] - pz
                r2 = dx * dx + dy * dy + dz * dz
                if r2 <= np.float32(0.0):
                    continue
                r = np.sqrt(r2)
                dx, dy, dz = dx / r, dy / r, dz / r
                cos_x = nx * dx + ny * dy + nz * dz
                mx, my, mz = normals[j, 0], normals[j, 1], normals[j, 2]
                cos_j = -(mx * dx + my * dy + mz * dz)
                if cos_x <= 0 or cos_j <= 0:
                    continue
                geometry = cos_x * cos_j / max(r2, clamp2)
                wx, wy, wz = incoming[j, 0], incoming[j, 1], incoming[j, 2]
                cos_in = mx * wx + my * wy + mz * wz
                lobe = 0.0
                if cos_in > 0:
                    widened = widened_alpha(alpha, cos_x)
                    lobe = _glossy(mx, my, mz, wx, wy, wz, -dx, -dy, -dz, cos_in, cos_j, energy, widened, ior)
                diffuse = base[_entry(cos_j)] * inverse_pi
                cells[n] = i * columns + k
                for c in range(3):
                    received[n, c] = (coloured_flux[j, c] * diffuse + flux[j, c] * lobe) * geometry
                    contributions[n, c] = received[n, c]
                origins[n, 0], origins[n, 1], origins[n, 2] = px, py, pz
                directions[n, 0], directions[n, 1], directions[n, 2] = dx, dy, dz
                distances[n] = r
                lights[n] = j
                n += 1
            n = _roulette(first, n, (i + row_offset) * columns + k, seed, roulette_below, lights, cells, contributions,
                          origins, directions, received, distances, weights)
            # The glossy term only for the pairs the roulette kept (it does not enter the roulette's choice): x's
            # lobe is the dearest part of a pair, and about two thirds of the pairs are dropped.
            for q in range(first, n):
                dx, dy, dz = directions[q, 0], directions[q, 1], directions[q, 2]
                seen = 0.0
                if cos_eye > 0:
                    cos_x = nx * dx + ny * dy + nz * dz
                    seen = pi * _glossy(nx, ny, nz, dx, dy, dz, ex, ey, ez, cos_x, cos_eye, energy, alpha, ior)
                weight = weights[q]
                for c in range(3):
                    contributions[q, c] = np.float32(received[q, c]) * weight
                    contributions[q, 3 + c] = np.float32(received[q, c] * seen) * weight
                r = distances[q]
                directions[q, 0], directions[q, 1], directions[q, 2] = dx * r, dy * r, dz * r
    return cells[:n], contributions[:n], origins[:n], directions[:n]


@numba.njit(nogil=True, cache=True)
def _roulette(first, end, cell, seed, roulette_below, lights, cells, contributions, origins, directions, received,
              distances, weights):  # pragma: no cover (compiled)
    """Russian roulette on the pairs first..end of one gather point: a pair bringing c < roulette_below times the
    point's mean keeps its shadow ray with probability c / (roulette_below mean) and then counts 1 / p times (an
    unbiased estimate); the rest are dropped. The draw hashes (seed, cell, light): a still camera draws alike.
    Returns the new end of the kept pairs (compacted in place, each with its weight in `weights`; the caller
    scales their contributions)."""
    total = np.float32(0.0)
    for q in range(first, end):
        total += contributions[q, 0] + contributions[q, 1] + contributions[q, 2]
    if total <= 0:
        return first  # nothing to bring: no rays
    if roulette_below <= 0:
        weights[first:end] = 1.0
        return end
    threshold = roulette_below * total / np.float32(end - first)
    kept = first
    for q in range(first, end):
        value = contributions[q, 0] + contributions[q, 1] + contributions[q, 2]
        weight = np.float32(1.0)
        if value < threshold:
            chance = value / threshold
            if _hash_uniform(seed, cell, lights[q]) >= chance:
                continue
            weight = np.float32(1.0) / chance
        cells[kept], distances[kept], weights[kept] = cells[q], distances[q], weight
        for c in range(3):
            received[kept, c] = received[q, c]
        for axis in range(3):
            origins[kept, axis], directions[kept, axis] = origins[q, axis], directions[q, axis]
        kept += 1
    return kept


@numba.njit(nogil=True, cache=True, inline="always")
def _hash_uniform(seed, cell, light):  # pragma: no cover (compiled)
    """A uniform number in [0, 1) from (seed, cell, light) (splitmix64 of their combination)."""
    z = (seed * np.uint64(0x100000001B3)) ^ (np.uint64(cell) << np.uint64(24)) ^ np.uint64(light)
    z += np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z ^= z >> np.uint64(31)
    return np.float32((z >> np.uint64(40)) * np.float64(1.0 / 16777216.0))


@numba.njit(nogil=True, cache=True)
def _accumulate(cells, contributions, blocked, gathered):  # pragma: no cover (compiled)
    """Sum the unshadowed contributions per gather point, in ray order (deterministic)."""
    columns, channels = gathered.shape[1], gathered.shape[2]
    for n in range(len(cells)):
        if blocked[n]:
            continue
        i, k = cells[n] // columns, cells[n] % columns
        for c in range(channels):
            gathered[i, k, c] += contributions[n, c]
