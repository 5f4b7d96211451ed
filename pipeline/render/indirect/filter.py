"""Filter: each gather point takes the geometry-weighted mean of the interleave x interleave block of points around
it (every subset of the lights once), weighted by how alike the surfaces are (normal, plane distance, distance)."""

from __future__ import annotations

import numba
import numpy as np

from pipeline.render.indirect.grid import CHANNELS

# Geometric weights of the filter: cos^8 of the angle between normals (fixed in `similarity`) times
# 1 - (plane distance / tolerance)^2, the tolerance being this fraction of the depth.
PLANE_TOLERANCE = 0.05
# ... and, in the interleave filter, 1 - (distance / reach)^2 with the reach this fraction of the depth: a block
# of 8 x 8 gather points spans metres along a wall seen at a grazing angle (a corridor), over which the
# bounced light changes several-fold; without it the far end of a corridor took the light of its near end.
FILTER_REACH = 0.3


@numba.njit(nogil=True, cache=True, inline="always")
def similarity(px, py, pz, nx, ny, nz, depth, points, point_normals, point_depth, i, k):  # pragma: no cover
    """Geometric weight in [0, 1] of gather point (i, k) for a surface at p with normal n and depth."""
    if not np.isfinite(point_depth[i, k]):
        return np.float32(0.0)
    cosine = nx * point_normals[i, k, 0] + ny * point_normals[i, k, 1] + nz * point_normals[i, k, 2]
    if cosine <= 0:
        return np.float32(0.0)
    plane = abs((px - points[i, k, 0]) * point_normals[i, k, 0] + (py - points[i, k, 1]) * point_normals[i, k, 1]
                + (pz - points[i, k, 2]) * point_normals[i, k, 2])
    tolerance = np.float32(PLANE_TOLERANCE) * depth
    if plane >= tolerance:
        return np.float32(0.0)
    plane /= tolerance
    cosine *= cosine  # cos^8 by squaring (a float power costs more than the rest of the weight)
    cosine *= cosine
    cosine *= cosine
    return cosine * (np.float32(1.0) - plane * plane)


@numba.njit(nogil=True, cache=True)
def interleave_filter(gathered, points, point_normals, point_depth, interleave, band, out):  # pragma: no cover
    """Each gather point of the rows of `band` (a slice): the geometry-weighted mean of the interleave x
    interleave block around it (points on its plane, within FILTER_REACH of its depth)."""
    rows, columns = point_depth.shape
    low = -((interleave - 1) // 2)
    for i in range(band.start, band.stop):
        for k in range(columns):
            depth = point_depth[i, k]
            if not np.isfinite(depth):
                continue
            px, py, pz = points[i, k, 0], points[i, k, 1], points[i, k, 2]
            nx, ny, nz = point_normals[i, k, 0], point_normals[i, k, 1], point_normals[i, k, 2]
            reach = np.float32(FILTER_REACH) * depth
            total = np.float32(0.0)
            sums = np.zeros(CHANNELS, np.float32)
            # Shift the block inside the grid at its borders, so it still holds every subset once.
            top = min(max(i + low, 0), max(rows - interleave, 0))
            left = min(max(k + low, 0), max(columns - interleave, 0))
            for a in range(top, min(top + interleave, rows)):
                for b in range(left, min(left + interleave, columns)):
                    w = similarity(px, py, pz, nx, ny, nz, depth, points, point_normals, point_depth, a, b)
                    if w > 0:
                        dx, dy, dz = points[a, b, 0] - px, points[a, b, 1] - py, points[a, b, 2] - pz
                        w *= max(np.float32(1.0) - (dx * dx + dy * dy + dz * dz) / (reach * reach), np.float32(0.0))
                    total += w
                    for c in range(CHANNELS):
                        sums[c] += w * gathered[a, b, c]
            if total > 0:
                for c in range(CHANNELS):
                    out[i, k, c] = sums[c] / total
