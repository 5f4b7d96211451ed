"""Gather: what the virtual lights bring each gather point past one shadow ray each.

Every gather point x sums E = sum_j Phi_j f_j cos_j cos_x / max(r^2, clamp^2) over the virtual lights it
sees, and the glossy term sum_j E_j pi f_x. Interleaved sampling (Keller and Heidrich 2001): the lights are
split into interleave^2 stratified subsets and neighbouring gather points take different subsets, so each point
pays for 1 / interleave^2 of the shadow rays; Russian roulette skips most rays of lights that bring a point
little (`ROULETTE_BELOW`). A point's pairs are valued in float32 on SIMD lanes before the roulette picks
(`_value_pairs`).
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
                  lights: np.ndarray, starts: np.ndarray, out: np.ndarray) -> None:
    """Add to `out` (rows, columns, 6) what the lights (`light_rows`) of each point's subset bring it past the
    shadow rays (lights sorted by subset: subset g is starts[g]..starts[g + 1]; `row_offset`: the grid row of
    row 0)."""
    shadow = _shadow_rays(points, normals, eyes, depth, row_offset, interleave, lights, starts,
                          np.float32(clamp_distance ** 2), np.float32(SURFACE_OFFSET), tables.diffuse, tables.energy,
                          np.float32(tables.alpha), np.float32(tables.ior), np.float32(ROULETTE_BELOW), np.uint64(seed))
    cells, contributions, ray_origins, ray_directions = shadow
    blocked = np.empty(len(cells), np.bool_)
    mesh.occluded(ray_origins, ray_directions, np.full(1, 1.0 - SURFACE_OFFSET, np.float32), blocked)
    _accumulate(cells, contributions, blocked, out)


def light_rows(lights: VirtualLights) -> np.ndarray:
    """(16, n) float32: the lights one quantity a row, so the pair loop reads consecutive lights from
    consecutive addresses (it runs on SIMD lanes): position (3), normal (3), direction back to where the light came
    from (3), the cosine of that direction to the normal, flux times albedo (3), flux (3)."""
    cos_in = np.sum(lights.normals * lights.incoming, axis=1, dtype=np.float32)[:, None]
    return np.ascontiguousarray(np.concatenate([lights.positions, lights.normals, lights.incoming, cos_in,
                                                lights.coloured_flux, lights.flux], axis=1).T, np.float32)


@numba.njit(nogil=True, cache=True, inline="always")
def _entry(mu):  # pragma: no cover (compiled)
    """The material tables' entry of a cosine, clipped to [0, 1] (NaN, from a pair the caller masks, reads entry 0)."""
    place = mu * np.float32(TABLE_SIZE - 1) + np.float32(0.5)
    place = place if place >= np.float32(0.0) else np.float32(0.0)
    return np.int32(min(place, np.float32(TABLE_SIZE - 1)))


@numba.njit(nogil=True, cache=True, inline="always", error_model="numpy")
def _glossy(cos_h, cos_a, cos_b, cos_bh, length, energy, alpha, ior):  # pragma: no cover (compiled)
    """The lobe f(a, b) M(cos_b) of a surface between unit directions a and b at cos_a, cos_b to its normal, from
    their unnormalised half vector (its cosines cos_h to the normal and cos_bh to b, both times `length`, its
    length); 0 outside the lobe's domain or for IOR 1. float32 and branch-free (a select), so pair loops vectorise."""
    cos_h, cos_bh = cos_h / length, cos_bh / length
    inside = (ior != np.float32(1.0)) & (cos_a > 0) & (cos_b > 0) & (length > np.float32(1e-6)) & (cos_h > 0) & (
        cos_bh > 0)
    value = glossy_brdf(cos_h, cos_a, cos_b, cos_bh, alpha, ior, np.float32) * energy[_entry(cos_b)]
    return value if inside else np.float32(0.0)


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _shadow_rays(points, point_normals, eyes, point_depth, row_offset, interleave, rows_of_lights, starts, clamp2,
                 offset, base, energy, alpha, ior, roulette_below, seed):  # pragma: no cover (compiled)
    """Every (gather point, light of its subset) pair that faces each other and the roulette keeps: the cell, the
    contribution (irradiance RGB, glossy term RGB) and the shadow ray (origin off the surface, direction to the
    light: t in [0, 1)). A light at y lit from w_i sends the point x the irradiance
    Phi f_y(w_i, y->x) cos_y cos_x / max(r^2, clamp^2), f = base rho / pi + lobe (material.py); x's own lobe
    reflects pi f_x(x->y, x->eye) times that towards the eye (the glossy term). `rows_of_lights`: `light_rows`.
    Each point's pairs are first valued all at once (`_value_pairs`, float32 on SIMD lanes), then the roulette
    picks and the kept pairs are written out."""
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
    pairs = np.empty((PAIR_ROWS, largest), np.float32)  # one point's pairs (`_value_pairs`)
    n = 0
    pi = np.float32(math.pi)
    for i in range(rows):
        for k in range(columns):
            z = point_depth[i, k]
            if not np.isfinite(z):
                continue
            group = ((i + row_offset) % interleave) * interleave + k % interleave
            first, count = starts[group], starts[group + 1] - starts[group]
            lift = offset * (np.float32(1.0) + z)
            nx, ny, nz = point_normals[i, k, 0], point_normals[i, k, 1], point_normals[i, k, 2]
            ex, ey, ez = eyes[i, k, 0], eyes[i, k, 1], eyes[i, k, 2]
            cos_eye = nx * ex + ny * ey + nz * ez
            px, py, pz = points[i, k, 0] + nx * lift, points[i, k, 1] + ny * lift, points[i, k, 2] + nz * lift
            _value_pairs(px, py, pz, nx, ny, nz, rows_of_lights, first, count, clamp2, base, energy, alpha, ior, pairs)
            cell = i * columns + k
            # Russian roulette: a pair bringing c < roulette_below times the point's mean keeps its shadow ray with
            # probability c / (roulette_below mean) and then counts 1 / p times (unbiased); the draw hashes
            # (seed, cell, light), so a still camera draws alike.
            total, facing = np.float32(0.0), 0
            for q in range(count):
                if pairs[_GEOMETRY, q] > 0:
                    total += pairs[_VALUE, q]
                    facing += 1
            if total <= 0:
                continue  # nothing to bring: no rays
            threshold = roulette_below * total / np.float32(facing)
            for q in range(count):
                if pairs[_GEOMETRY, q] <= 0:
                    continue
                value, weight = pairs[_VALUE, q], np.float32(1.0)
                if roulette_below > 0 and value < threshold:
                    chance = value / threshold
                    if _hash_uniform(seed, (i + row_offset) * columns + k, first + q) >= chance:
                        continue
                    weight = np.float32(1.0) / chance
                j = first + q
                dx, dy, dz = rows_of_lights[0, j] - px, rows_of_lights[1, j] - py, rows_of_lights[2, j] - pz
                r = np.sqrt(dx * dx + dy * dy + dz * dz)
                # x's own lobe only for the pairs kept: about two thirds are dropped.
                seen = np.float32(0.0)
                if cos_eye > 0:
                    cos_x = (nx * dx + ny * dy + nz * dz) / r
                    hx, hy, hz = dx / r + ex, dy / r + ey, dz / r + ez
                    length = np.sqrt(hx * hx + hy * hy + hz * hz)
                    seen = pi * _glossy(nx * hx + ny * hy + nz * hz, cos_x, cos_eye, ex * hx + ey * hy + ez * hz,
                                        length, energy, alpha, ior)
                cells[n] = cell
                for c in range(3):
                    received = pairs[_RECEIVED + c, q]
                    contributions[n, c] = received * weight
                    contributions[n, 3 + c] = received * seen * weight
                origins[n, 0], origins[n, 1], origins[n, 2] = px, py, pz
                directions[n, 0], directions[n, 1], directions[n, 2] = dx, dy, dz
                n += 1
    return cells[:n], contributions[:n], origins[:n], directions[:n]


# Rows of `_value_pairs`' output: the geometry term cos_x cos_y / max(r^2, clamp^2) (0 where the pair does not
# face each other), the cosine at the light, the light's lobe before its energy factor; the irradiance per channel
# and summed over RGB.
_GEOMETRY, _COS_LIGHT, _LOBE, _RECEIVED, _VALUE = 0, 1, 2, 3, 6
PAIR_ROWS = 7


@numba.njit(nogil=True, cache=True, inline="always", error_model="numpy")
def _value_pairs(px, py, pz, nx, ny, nz, rows_of_lights, first, count, clamp2, base, energy, alpha, ior,
                 pairs):  # pragma: no cover (compiled)
    """Into pairs[:, :count] what lights first..first + count bring the point p of normal n (the rows above).
    Two loops: the first is branch-free float32 arithmetic, one light per SIMD lane (its masks become selects;
    it writes 3 rows only, as the compiler gives up vectorising when the rows read and written need more overlap
    checks); the second reads the material tables (a table read at a computed index would keep the first from
    vectorising: the compiler cannot tell it from the rows written)."""
    zero = np.float32(0.0)
    light = rows_of_lights
    glossy = ior != np.float32(1.0)
    for q in range(count):
        j = first + q
        dx, dy, dz = light[0, j] - px, light[1, j] - py, light[2, j] - pz
        r2 = dx * dx + dy * dy + dz * dz
        r = np.sqrt(r2)
        dx, dy, dz = dx / r, dy / r, dz / r
        mx, my, mz = light[3, j], light[4, j], light[5, j]
        cos_x = nx * dx + ny * dy + nz * dz
        cos_j = -(mx * dx + my * dy + mz * dz)
        facing = (r2 > zero) & (cos_x > zero) & (cos_j > zero)
        # The light's lobe from where its light came (w_i) towards x, widened as Filter Glossy does after x's bounce.
        hx, hy, hz = light[6, j] - dx, light[7, j] - dy, light[8, j] - dz
        length = np.sqrt(hx * hx + hy * hy + hz * hz)
        cos_h, cos_bh = (mx * hx + my * hy + mz * hz) / length, -(dx * hx + dy * hy + dz * hz) / length
        cos_in = light[9, j]
        lobe = glossy_brdf(cos_h, cos_in, cos_j, cos_bh, widened_alpha(alpha, cos_x, np.float32), ior, np.float32)
        inside = glossy & facing & (cos_in > zero) & (length > np.float32(1e-6)) & (cos_h > zero) & (cos_bh > zero)
        pairs[_GEOMETRY, q] = cos_x * cos_j / max(r2, clamp2) if facing else zero
        pairs[_COS_LIGHT, q] = cos_j if facing else zero
        pairs[_LOBE, q] = lobe if inside else zero
    inverse_pi = np.float32(1.0 / math.pi)
    for q in range(count):
        j, entry = first + q, _entry(pairs[_COS_LIGHT, q])
        diffuse, lobe, geometry = base[entry] * inverse_pi, pairs[_LOBE, q] * energy[entry], pairs[_GEOMETRY, q]
        total = zero
        for c in range(3):
            received = (light[10 + c, j] * diffuse + light[13 + c, j] * lobe) * geometry
            pairs[_RECEIVED + c, q] = received
            total += received
        pairs[_VALUE, q] = total


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
