"""Filter: each gather point takes the light of the interleave x interleave block of points around it (every subset of
the lights once), weighted by how alike the surfaces are (normal, plane distance, distance): not their mean but the
value at the point of the weighted least-squares plane through them (`interleave_filter`)."""

from __future__ import annotations

import numba
import numpy as np

from pipeline.render.indirect.grid import CHANNELS
from pipeline.render.indirect.sampling import normal_frame

# Geometric weights of the filter: cos^8 of the angle between normals (fixed in `similarity`) times
# 1 - (plane distance / tolerance)^2, the tolerance being this fraction of the depth.
PLANE_TOLERANCE = 0.05
# ... and, in the interleave filter, 1 - (distance / reach)^2 with the reach this fraction of the depth: a block
# of 8 x 8 gather points spans metres along a wall seen at a grazing angle (a corridor), over which the
# bounced light changes several-fold; without it the far end of a corridor took the light of its near end.
FILTER_REACH = 0.3
# The plane fit's ridge, a fraction of the block's weight added to its spread along each tangent: it pulls the slope
# towards 0 (the weighted mean) where the block's points give little hold on it (a strip of wall one point wide, a few
# noisy points). Median PSNR against the reference at seeds 0 / 1 / 2: 35.96 / 35.77 / 34.53 dB with the mean,
# 36.09 / 35.77 / 35.00 with ridge 0.1 (0.02: 36.03 at seed 0, noisier; 0.3: 36.09).
FIT_RIDGE = 0.1


@numba.njit(nogil=True, cache=True, inline="always")
def similarity(px, py, pz, nx, ny, nz, tolerance, points, point_normals, point_depth, i, k):  # pragma: no cover
    """Geometric weight in [0, 1] of gather point (i, k) for a surface at p with normal n; `tolerance`: (plane
    tolerance, its inverse) at the surface's depth (`plane_tolerance`, once per surface rather than a division
    per point)."""
    if not np.isfinite(point_depth[i, k]):
        return np.float32(0.0)
    cosine = nx * point_normals[i, k, 0] + ny * point_normals[i, k, 1] + nz * point_normals[i, k, 2]
    if cosine <= 0:
        return np.float32(0.0)
    plane = abs((px - points[i, k, 0]) * point_normals[i, k, 0] + (py - points[i, k, 1]) * point_normals[i, k, 1]
                + (pz - points[i, k, 2]) * point_normals[i, k, 2])
    if plane >= tolerance[0]:
        return np.float32(0.0)
    plane *= tolerance[1]
    cosine *= cosine  # cos^8 by squaring (a float power costs more than the rest of the weight)
    cosine *= cosine
    cosine *= cosine
    return cosine * (np.float32(1.0) - plane * plane)


@numba.njit(nogil=True, cache=True, inline="always")
def plane_tolerance(depth):  # pragma: no cover
    """(PLANE_TOLERANCE x depth, its inverse): `similarity`'s tolerance for a surface at `depth`."""
    tolerance = np.float32(PLANE_TOLERANCE) * depth
    return tolerance, np.float32(1.0) / tolerance


@numba.njit(nogil=True, cache=True)
def interleave_filter(gathered, points, point_normals, point_depth, interleave, band, out):  # pragma: no cover
    """Each gather point of the rows of `band` (a slice): the light at the point of the weighted least-squares plane
    L(u, v) = c0 + c1 u + c2 v through the interleave x interleave block around it, (u, v) being offsets along the
    point's surface and the weights geometric (points on its plane, within FILTER_REACH of its depth); kept within
    the block's values. The block's mean took a gradient's light from where the block's points lie, not from the
    point: the block is shifted inside the grid at its borders, surfaces end inside it, and along a corridor's wall
    the near side of a block outweighs the far side."""
    rows, columns = point_depth.shape
    low = -((interleave - 1) // 2)
    moments = np.zeros(6, np.float32)  # sums of w, w u, w v, w u u, w u v, w v v
    sums = np.zeros((3, CHANNELS), np.float32)  # sums of w L, w L u, w L v per channel
    bounds = np.zeros((2, CHANNELS), np.float32)  # lowest and highest L per channel
    for i in range(band.start, band.stop):
        for k in range(columns):
            if not np.isfinite(point_depth[i, k]):
                continue
            # Shift the block inside the grid at its borders, so it still holds every subset once.
            top = min(max(i + low, 0), max(rows - interleave, 0))
            left = min(max(k + low, 0), max(columns - interleave, 0))
            _block_sums(gathered, points, point_normals, point_depth, i, k, top, left, interleave, moments, sums, bounds)
            if moments[0] > 0:
                _plane_at_point(moments, sums, bounds, out[i, k])


@numba.njit(nogil=True, cache=True, inline="always")
def _block_sums(gathered, points, point_normals, point_depth, i, k, top, left, interleave, moments, sums,
                bounds):  # pragma: no cover
    """The weighted moments of the block's offsets and light around gather point (i, k), and the light's bounds."""
    depth = point_depth[i, k]
    px, py, pz = points[i, k, 0], points[i, k, 1], points[i, k, 2]
    nx, ny, nz = point_normals[i, k, 0], point_normals[i, k, 1], point_normals[i, k, 2]
    tx, ty, tz, bx, by, bz = normal_frame(nx, ny, nz, np.float32)  # two unit tangents of the point's surface
    reach = np.float32(FILTER_REACH) * depth
    tolerance = plane_tolerance(depth)
    moments[:] = 0.0
    sums[:] = 0.0
    bounds[0, :] = np.inf
    bounds[1, :] = -np.inf
    for a in range(top, min(top + interleave, point_depth.shape[0])):
        for b in range(left, min(left + interleave, point_depth.shape[1])):
            w = similarity(px, py, pz, nx, ny, nz, tolerance, points, point_normals, point_depth, a, b)
            if w <= 0:
                continue
            dx, dy, dz = points[a, b, 0] - px, points[a, b, 1] - py, points[a, b, 2] - pz
            w *= max(np.float32(1.0) - (dx * dx + dy * dy + dz * dz) / (reach * reach), np.float32(0.0))
            if w <= 0:
                continue
            u = (dx * tx + dy * ty + dz * tz) / reach
            v = (dx * bx + dy * by + dz * bz) / reach
            moments[0] += w
            moments[1] += w * u
            moments[2] += w * v
            moments[3] += w * u * u
            moments[4] += w * u * v
            moments[5] += w * v * v
            for c in range(CHANNELS):
                value = gathered[a, b, c]
                sums[0, c] += w * value
                sums[1, c] += w * value * u
                sums[2, c] += w * value * v
                bounds[0, c] = min(bounds[0, c], value)
                bounds[1, c] = max(bounds[1, c], value)


@numba.njit(nogil=True, cache=True, inline="always")
def _plane_at_point(moments, sums, bounds, out):  # pragma: no cover
    """Into `out` (CHANNELS,): c0 of the ridge-regularised weighted plane fit (Cramer's rule on the 3 x 3 normal
    equations), clipped to the block's bounds; the weighted mean if the system is singular."""
    total, su, sv = moments[0], moments[1], moments[2]
    ridge = np.float32(FIT_RIDGE) * total
    suu, suv, svv = moments[3] + ridge, moments[4], moments[5] + ridge
    minor = suu * svv - suv * suv
    det = total * minor - su * (su * svv - suv * sv) + sv * (su * suv - suu * sv)
    solvable = det > np.float32(1e-12) * total * total * total
    for c in range(CHANNELS):
        y0, y1, y2 = sums[0, c], sums[1, c], sums[2, c]
        if solvable:
            value = (y0 * minor - su * (y1 * svv - suv * y2) + sv * (y1 * suv - suu * y2)) / det
            out[c] = min(max(value, bounds[0, c]), bounds[1, c])
        else:
            out[c] = y0 / total
