"""Quaternions, level OpenCV cameras and pose matrices (the helpers render imports)."""

from __future__ import annotations

import math

import numpy as np

from pipeline.plan.poses import level_camera_rotations, matrix_to_quaternion, pose_matrices, quaternion_to_matrix


def test_quaternion_round_trip_including_half_turns():
    rng = np.random.default_rng(3)
    quaternions = rng.normal(size=(200, 4))
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    quaternions[quaternions[:, 0] < 0] *= -1
    half_turns = np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])  # trace = -1
    quaternions = np.concatenate([quaternions, half_turns])
    back = matrix_to_quaternion(quaternion_to_matrix(quaternions))
    assert np.allclose(back, quaternions, atol=1e-12)


def test_level_camera_looks_along_heading_with_y_down_and_x_right():
    rotation = level_camera_rotations(np.array([-math.pi / 2]))[0]  # heading -90 degrees: forward = -z
    assert np.allclose(rotation[:, 2], [0, 0, -1])  # camera z (forward)
    assert np.allclose(rotation[:, 1], [0, -1, 0])  # camera y (down)
    assert np.allclose(rotation[:, 0], [1, 0, 0])  # camera x (right): looking along -z, right is +x
    assert math.isclose(np.linalg.det(rotation), 1.0)


def test_pose_matrices_from_frame_rows():
    quaternion = matrix_to_quaternion(level_camera_rotations(np.array([0.0])))[0]
    row = {"px": 1.0, "py": 2.0, "pz": 3.0, "qw": quaternion[0], "qx": quaternion[1], "qy": quaternion[2],
           "qz": quaternion[3]}
    matrix = pose_matrices([row])[0]
    assert np.allclose(matrix[:3, 3], [1, 2, 3]) and np.allclose(matrix[3], [0, 0, 0, 1])
    assert np.allclose(matrix[:3, 2], [1, 0, 0])  # heading 0 looks along +x
