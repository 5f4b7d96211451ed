"""Camera poses: quaternion <-> rotation matrix, level cameras from a heading, 4x4 camera-to-world matrices.

Conventions (schemas/README.md): world +Y up; camera axes OpenCV (x right, y down, z forward); a pose is
camera-to-world; quaternions are (w, x, y, z) with w >= 0 so that equal rotations have equal numbers.
"""

from __future__ import annotations

from typing import Iterable, Mapping

import numpy as np
import pyarrow as pa

WORLD_DOWN = np.array([0.0, -1.0, 0.0])


def quaternion_to_matrix(quaternions: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices (normalised first)."""
    q = np.asarray(quaternions, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def matrix_to_quaternion(matrices: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) quaternions (w, x, y, z) with w >= 0.

    Uses the largest of the four candidate denominators per matrix (Shepperd's method), so it stays
    accurate for 180-degree rotations where the trace-based formula divides by ~0.
    """
    m = np.asarray(matrices, dtype=np.float64)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    t = np.trace(m, axis1=1, axis2=2)
    diagonal = np.stack([t, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    case = np.argmax(diagonal, axis=1)
    q = np.empty((len(m), 4))
    for k in range(4):
        sel = case == k
        if not sel.any():
            continue
        a = m[sel]
        if k == 0:
            s = 2.0 * np.sqrt(1.0 + t[sel])
            q[sel] = np.stack([0.25 * s, (a[:, 2, 1] - a[:, 1, 2]) / s, (a[:, 0, 2] - a[:, 2, 0]) / s,
                               (a[:, 1, 0] - a[:, 0, 1]) / s], axis=1)
        elif k == 1:
            s = 2.0 * np.sqrt(1.0 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2])
            q[sel] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / s, 0.25 * s, (a[:, 0, 1] + a[:, 1, 0]) / s,
                               (a[:, 0, 2] + a[:, 2, 0]) / s], axis=1)
        elif k == 2:
            s = 2.0 * np.sqrt(1.0 + a[:, 1, 1] - a[:, 0, 0] - a[:, 2, 2])
            q[sel] = np.stack([(a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 0, 1] + a[:, 1, 0]) / s, 0.25 * s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s], axis=1)
        else:
            s = 2.0 * np.sqrt(1.0 + a[:, 2, 2] - a[:, 0, 0] - a[:, 1, 1])
            q[sel] = np.stack([(a[:, 1, 0] - a[:, 0, 1]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(*shape, 4)


def level_camera_rotations(headings: np.ndarray) -> np.ndarray:
    """(T,) headings in radians -> (T, 3, 3) camera-to-world rotations of a level OpenCV camera.

    The heading is the angle of the viewing direction in the floor plane: forward = (cos h, 0, sin h)
    in world (x, y, z). The camera's y axis points down the world's -Y, and x = y cross z (right-handed).
    """
    h = np.asarray(headings, dtype=np.float64)
    forward = np.stack([np.cos(h), np.zeros_like(h), np.sin(h)], axis=1)
    down = np.broadcast_to(WORLD_DOWN, forward.shape)
    right = np.cross(down, forward)
    return np.stack([right, down, forward], axis=2)


def pose_matrices(frames: pa.Table | Iterable[Mapping[str, float]]) -> np.ndarray:
    """Rows of the `frames` table (a pyarrow Table or dicts with px..qz) -> (T, 4, 4) camera-to-world.

    Rows are used in the order given; sort by `frame` first when reading a whole dataset.
    """
    if isinstance(frames, pa.Table):
        columns = {name: frames.column(name).to_numpy() for name in ("px", "py", "pz", "qw", "qx", "qy", "qz")}
    else:
        rows = list(frames)
        columns = {name: np.array([row[name] for row in rows], dtype=np.float64)
                   for name in ("px", "py", "pz", "qw", "qx", "qy", "qz")}
    count = len(columns["px"])
    matrices = np.tile(np.eye(4), (count, 1, 1))
    if count == 0:
        return matrices
    quaternions = np.stack([columns["qw"], columns["qx"], columns["qy"], columns["qz"]], axis=1)
    matrices[:, :3, :3] = quaternion_to_matrix(quaternions)
    matrices[:, :3, 3] = np.stack([columns["px"], columns["py"], columns["pz"]], axis=1)
    return matrices
