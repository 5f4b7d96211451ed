"""Pinhole projection in the project's camera convention, the one copy every part uses.

Camera axes are OpenCV (x right, y down, z forward); a pose is a 4x4 camera-to-world matrix; pixel
(u, v) covers [u, u + 1) x [v, v + 1) and its centre is (u + 0.5, v + 0.5) (schemas/README.md).
Depth is planar z. The renderer casts its rays with `pixel_rays`, the reprojection test and FastSPAM
move points between frames with `unproject` and `project`, so all three agree by construction.
"""

from __future__ import annotations

import numpy as np

Intrinsics = tuple[float, float, float, float]  # fx, fy, cx, cy in pixels


def pixel_rays(u: np.ndarray, v: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame x / z and y / z of the rays through the centres of pixels (u, v) (float64)."""
    fx, fy, cx, cy = intrinsics
    x = (np.asarray(u, dtype=np.float64) + 0.5 - cx) / fx
    y = (np.asarray(v, dtype=np.float64) + 0.5 - cy) / fy
    return x, y


def unproject(u: np.ndarray, v: np.ndarray, z: np.ndarray, intrinsics: Intrinsics, pose: np.ndarray) -> np.ndarray:
    """World points (n, 3) of pixels (u, v) at planar depths `z` (metres), seen from camera-to-world `pose`."""
    x, y = pixel_rays(u, v, intrinsics)
    z = np.asarray(z, dtype=np.float64)
    camera = np.stack([x * z, y * z, z], axis=-1).reshape(-1, 3)
    return camera @ pose[:3, :3].T + pose[:3, 3]


def project(points: np.ndarray, intrinsics: Intrinsics, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points (n, 3) -> (column, row, z): continuous image coordinates and planar depth in the
    camera at camera-to-world `pose`. A point lies in pixel (floor(column), floor(row)); z <= 0 is behind."""
    fx, fy, cx, cy = intrinsics
    rotation, position = pose[:3, :3], pose[:3, 3]
    camera = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - position) @ rotation
    z = camera[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        column = fx * camera[:, 0] / z + cx
        row = fy * camera[:, 1] / z + cy
    return column, row, z


def pixels_inside(column: np.ndarray, row: np.ndarray, z: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, inside): integer pixels of projected points and whether each lies in the image, in front."""
    finite = np.isfinite(column) & np.isfinite(row) & (z > 0)
    u = np.floor(np.where(finite, column, -1)).astype(np.int64)
    v = np.floor(np.where(finite, row, -1)).astype(np.int64)
    inside = finite & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    return u, v, inside
