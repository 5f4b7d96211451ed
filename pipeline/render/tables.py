"""Parquet datasets written by the render stage: `videos`, `frame_stats` and `segments`.

One part file per render unit (one video of one embodiment). Timing columns (`render_seconds`) are the
only values that differ between two runs of one job; the Zarr stores never hold timings.
"""

from __future__ import annotations

import pyarrow as pa

from pipeline.io.tables import column, register

_KEY = [
    column("embodiment", pa.string(), "embodiment name (job file)"),
    column("video_name", pa.string(), "<scene_id>.<trajectory:010d>.<height_mm:010d>"),
]

VIDEOS = register("videos", [
    *_KEY,
    column("scene_id", pa.string(), "scene the video was rendered in"),
    column("trajectory", pa.int32(), "trajectory index within the scene and embodiment"),
    column("height_m", pa.float64(), "camera height above the floor, metres"),
    column("illumination", pa.string(), "'ambient' or 'spot-<watts>W' (e.g. 'spot-20W')"),
    column("sensor_model", pa.string(), "depth sensor model: 'ideal' or 'structured_light'"),
    column("frames", pa.int32(), "number of frames T"),
    column("width", pa.int32(), "image width, pixels"),
    column("height", pa.int32(), "image height, pixels"),
    column("fx", pa.float64(), "focal length x, pixels"),
    column("fy", pa.float64(), "focal length y, pixels"),
    column("cx", pa.float64(), "principal point x, pixels (pixel centres at u + 0.5)"),
    column("cy", pa.float64(), "principal point y, pixels (pixel centres at v + 0.5)"),
    column("exposure", pa.float64(), "linear scale from radiance W/(m^2 sr) to full scale; null for ambient light",
           nullable=True),
    column("store_path", pa.string(), "Zarr store, relative to the run root: videos/<embodiment>/<name>.zarr"),
    column("bytes", pa.int64(), "bytes of the Zarr store on disk (all arrays and metadata)"),
    column("render_seconds", pa.float64(), "wall time of the unit: load, ray cast, shading, Zarr write (not reproducible)"),
], row="one rendered video of one embodiment")

FRAME_STATS = register("frame_stats", [
    *_KEY,
    column("frame", pa.int32(), "frame index t, 0-based"),
    column("render_seconds", pa.float64(), "wall time to cast, shade, label and count this frame, seconds; Zarr writes are per shard and only in videos.render_seconds (not reproducible)"),
    column("void_fraction", pa.float64(), "fraction of pixels with panoptic id 0 (no hit or unlabelled)"),
    column("visible_objects", pa.int32(), "distinct non-void object ids in the frame"),
    column("valid_depth_fraction", pa.float64(), "fraction of pixels with depth > 0 (after the sensor model)"),
], row="one rendered frame (per-frame additions to the plan's `frames` rows)")

SEGMENTS = register("segments", [
    *_KEY,
    column("frame", pa.int32(), "frame index t, 0-based"),
    column("object_id", pa.uint32(), "panoptic id (> 0), the scene's object id"),
    column("category", pa.int16(), "mpcat40 index of the object (0 = void / unknown)"),
    column("area", pa.int64(), "pixels covered by the object in this frame"),
    column("x0", pa.int32(), "bounding box left column, inclusive"),
    column("y0", pa.int32(), "bounding box top row, inclusive"),
    column("x1", pa.int32(), "bounding box right column, exclusive"),
    column("y1", pa.int32(), "bounding box bottom row, exclusive"),
], row="one object visible in one frame (one mask)")
