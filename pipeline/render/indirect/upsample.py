"""Upsample: every pixel (block of INDIRECT_BLOCK x INDIRECT_BLOCK pixels) takes the bilinear mix of its four nearest
gather points under the filter's geometric weights (normal, plane distance: edge-aware); a pixel on none of their
surfaces (narrower than the stride: door frames, box tops) is marked an orphan, to gather on a finer grid of its own
(`IndirectGather._fill_orphans`)."""

from __future__ import annotations

import numba
import numpy as np

from pipeline.render.indirect.filter import plane_tolerance, similarity
from pipeline.render.indirect.grid import CHANNELS


@numba.njit(nogil=True, cache=True)
def upsample_blocks(combined, points, point_normals, point_depth, depth, direction, normal, origin, stride, block,
                    block_start, out, orphans):  # pragma: no cover (compiled)
    """Blocks of rows block_start.. (out holds those rows; block (R, C) is the surface of pixel (block R, block C);
    `block` is lighting.INDIRECT_BLOCK, passed because numba's cache keeps the value a global had when compiled):
    the bilinear mix of the four nearest gather points, each weighted by geometric similarity. A block
    none of them is alike to (a surface smaller than a cell) is left 0 and marked in `orphans`."""
    height, width = out.shape[0], out.shape[1]
    rows, columns = point_depth.shape
    half = np.float32(stride // 2)
    one = np.float32(1.0)
    # Each column's two nearest grid columns and the weight between them, once per band rather than per pixel.
    lefts, rights, across = np.empty(width, np.int64), np.empty(width, np.int64), np.empty(width, np.float32)
    for block_column in range(width):
        gk = (np.float32(block_column * block) - half) / np.float32(stride)
        lefts[block_column] = min(max(int(np.floor(gk)), 0), columns - 1)
        rights[block_column] = min(lefts[block_column] + 1, columns - 1)
        across[block_column] = min(max(gk - np.float32(lefts[block_column]), np.float32(0.0)), one)
    out[:] = 0.0  # once for the band, not a slice per pixel
    for local_row in range(height):
        row = (block_start + local_row) * block
        gi = (np.float32(row) - half) / np.float32(stride)
        i0 = min(max(int(np.floor(gi)), 0), rows - 1)
        i1 = min(i0 + 1, rows - 1)
        fi = min(max(gi - np.float32(i0), np.float32(0.0)), one)
        for block_column in range(width):
            column = block_column * block
            z = depth[row, column]
            if not np.isfinite(z):
                continue
            facing = (normal[row, column, 0] * direction[row, column, 0] + normal[row, column, 1] * direction[row, column, 1]
                      + normal[row, column, 2] * direction[row, column, 2])
            sign = np.float32(-1.0) if facing > 0 else one
            nx, ny, nz = sign * normal[row, column, 0], sign * normal[row, column, 1], sign * normal[row, column, 2]
            px = origin[0] + z * direction[row, column, 0]
            py = origin[1] + z * direction[row, column, 1]
            pz = origin[2] + z * direction[row, column, 2]
            k0, k1, fk = lefts[block_column], rights[block_column], across[block_column]
            tolerance = plane_tolerance(z)
            w00 = (one - fi) * (one - fk) * similarity(px, py, pz, nx, ny, nz, tolerance, points, point_normals, point_depth, i0, k0)
            w01 = (one - fi) * fk * similarity(px, py, pz, nx, ny, nz, tolerance, points, point_normals, point_depth, i0, k1)
            w10 = fi * (one - fk) * similarity(px, py, pz, nx, ny, nz, tolerance, points, point_normals, point_depth, i1, k0)
            w11 = fi * fk * similarity(px, py, pz, nx, ny, nz, tolerance, points, point_normals, point_depth, i1, k1)
            total = w00 + w01 + w10 + w11
            if total > np.float32(1e-6):
                w00, w01, w10, w11 = w00 / total, w01 / total, w10 / total, w11 / total
                for c in range(CHANNELS):
                    out[local_row, block_column, c] = (w00 * combined[i0, k0, c] + w01 * combined[i0, k1, c]
                                                       + w10 * combined[i1, k0, c] + w11 * combined[i1, k1, c])
                continue
            # None of the four is alike: the most similar of the 4 x 4 around (the same surface a cell further);
            # failing that, an orphan.
            best, best_a, best_b = np.float32(0.0), -1, -1
            for a in range(max(i0 - 1, 0), min(i0 + 3, rows)):
                for b in range(max(k0 - 1, 0), min(k0 + 3, columns)):
                    w = similarity(px, py, pz, nx, ny, nz, tolerance, points, point_normals, point_depth, a, b)
                    if w > best:
                        best, best_a, best_b = w, a, b
            if best_a < 0:
                orphans[local_row, block_column] = True
                continue
            for c in range(CHANNELS):
                out[local_row, block_column, c] = combined[best_a, best_b, c]
