"""Gather points: the surface under the centre pixel of every stride x stride cell of a frame."""

from __future__ import annotations

import numba
import numpy as np

# Values per gather point: irradiance E (RGB), then the glossy term G (RGB) the point's lobe reflects to the eye.
CHANNELS = 6


class GatherGrid:
    """Gather points every `stride` pixels: the surface under the centre pixel of each stride x stride cell
    (`_gather_points`): positions (rows, columns, 3), normals facing the camera, unit directions to the camera
    (eyes), depth (inf where the pixel hit nothing)."""

    def __init__(self, depth: np.ndarray, normal: np.ndarray, direction: np.ndarray, origin: np.ndarray, stride: int):
        height, width = depth.shape
        rows, columns = -(-height // stride), -(-width // stride)
        self.points = np.zeros((rows, columns, 3), np.float32)
        self.normals = np.zeros((rows, columns, 3), np.float32)
        self.eyes = np.zeros((rows, columns, 3), np.float32)
        self.depth = np.full((rows, columns), np.inf, np.float32)
        _gather_points(depth, normal, direction, origin, stride, self.points, self.normals, self.eyes, self.depth)


@numba.njit(nogil=True, cache=True)
def _gather_points(depth, normal, direction, origin, stride, points, point_normals, eyes,
                   point_depth):  # pragma: no cover (compiled)
    """The surface under the centre pixel of each stride x stride cell: position, normal facing the camera, unit
    direction to the camera, depth."""
    height, width = depth.shape
    for i in range(points.shape[0]):
        row = min(i * stride + stride // 2, height - 1)
        for k in range(points.shape[1]):
            column = min(k * stride + stride // 2, width - 1)
            z = depth[row, column]
            if not np.isfinite(z):
                continue
            facing = np.float32(0.0)
            for axis in range(3):
                points[i, k, axis] = origin[axis] + z * direction[row, column, axis]
                facing += normal[row, column, axis] * direction[row, column, axis]
            sign = np.float32(-1.0) if facing > 0 else np.float32(1.0)
            ray = direction[row, column]
            length = np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2])
            for axis in range(3):
                point_normals[i, k, axis] = sign * normal[row, column, axis]
                eyes[i, k, axis] = -direction[row, column, axis] / length
            point_depth[i, k] = z
