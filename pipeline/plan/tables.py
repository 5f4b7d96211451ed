"""Parquet datasets written by the plan stage: `trajectories` (one row per video) and `frames` (one per pose)."""

from __future__ import annotations

import pyarrow as pa

from pipeline.io.tables import column, register

TRAJECTORIES = register(
    "trajectories",
    [
        column("embodiment", pa.string(), "embodiment name (jobs/embodiments/<name>.yaml)"),
        column("video_name", pa.string(), "<scene_id>.<trajectory:010d>.<height_mm:010d>"),
        column("scene_id", pa.string(), "scene id"),
        column("trajectory", pa.int32(),
               "floor path index in the scene; the same index at every height is the same floor path"),
        column("height_m", pa.float64(), "camera height above the floor, metres (the placement)"),
        column("frames", pa.int32(), "number of frames (poses) of the video"),
        column("path_length_m", pa.float64(), "length of the floor path on the floor plane, metres"),
        column("seed", pa.int64(),
               "seed of the scene's start/goal draws (the same for every embodiment with the same body)"),
        column("width", pa.int32(), "image width, pixels"),
        column("height", pa.int32(), "image height, pixels"),
        column("fx", pa.float64(), "focal length along x, pixels"),
        column("fy", pa.float64(), "focal length along y, pixels"),
        column("cx", pa.float64(), "principal point x, pixels (pixel centres at u + 0.5)"),
        column("cy", pa.float64(), "principal point y, pixels (pixel centres at v + 0.5)"),
        column("near", pa.float64(), "near clip, metres"),
        column("far", pa.float64(), "far clip, metres"),
        column("waypoints", pa.int32(), "corners of the floor path (start and goal included)"),
        column("start_x", pa.float64(), "start of the floor path, world x, metres"),
        column("start_z", pa.float64(), "start of the floor path, world z, metres"),
        column("goal_x", pa.float64(), "goal of the floor path, world x, metres"),
        column("goal_z", pa.float64(), "goal of the floor path, world z, metres"),
    ],
    row="one video: a floor path of a scene seen from one camera height by one embodiment",
)

FRAMES = register(
    "frames",
    [
        column("embodiment", pa.string(), "embodiment name"),
        column("video_name", pa.string(), "video the frame belongs to"),
        column("frame", pa.int32(), "frame index, 0-based"),
        column("px", pa.float64(), "camera position, world x, metres"),
        column("py", pa.float64(), "camera position, world y (up), metres: floor height + placement"),
        column("pz", pa.float64(), "camera position, world z, metres"),
        column("qw", pa.float64(),
               "camera-to-world rotation quaternion, scalar part (OpenCV camera: x right, y down, z forward)"),
        column("qx", pa.float64(), "camera-to-world rotation quaternion, x"),
        column("qy", pa.float64(), "camera-to-world rotation quaternion, y"),
        column("qz", pa.float64(), "camera-to-world rotation quaternion, z"),
    ],
    row="one camera pose of one video (camera-to-world; qw >= 0)",
)
