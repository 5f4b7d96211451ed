"""Parquet datasets written by the `shard` stage: `scenes` (one row per scene) and `objects`.

Later stages find their scenes in `scenes` and re-load one with
`pipeline.scenes.sources.load_scene_row(row)`; `options` carries what that needs (JSON).
"""

from __future__ import annotations

import pyarrow as pa

from pipeline.io.tables import column, register

SCENES = register(
    "scenes",
    [
        column("scene_id", pa.string(), "scene id, e.g. 'proc-000003' or '00808-y9hTuugGdiq'"),
        column("source", pa.string(), "'procedural', 'hm3dsem', 'mesh', 'matterport3d', 'scannet' or 'replica' (schemas/scan_sources.md)"),
        column("path", pa.string(), "file the scene is read from ('' for procedural houses)"),
        column("options", pa.string(), "JSON of the loader options (seed, detail, up_axis, ...)"),
        column("triangles", pa.int64(), "triangle count"),
        column("vertices", pa.int64(), "vertex count"),
        column("min_x", pa.float64(), "bounding box minimum x, metres, world frame (+Y up)"),
        column("min_y", pa.float64(), "bounding box minimum y, metres"),
        column("min_z", pa.float64(), "bounding box minimum z, metres"),
        column("max_x", pa.float64(), "bounding box maximum x, metres"),
        column("max_y", pa.float64(), "bounding box maximum y, metres"),
        column("max_z", pa.float64(), "bounding box maximum z, metres"),
        column("object_count", pa.int32(), "labelled object instances (void excluded)"),
        column("floor_area", pa.float64(), "square metres of floor seen from above (union of upward floor-category faces per storey; rugs not twice)"),
        column("void_triangles", pa.int64(), "triangles with object id 0 (void)"),
        column("unknown_colors", pa.int64(), "distinct semantic colours with no row in the source's table (void)"),
        column("to_world", pa.list_(pa.float64(), 16), "4x4 row-major transform from the file's frame to the world"),
        column("room_count", pa.int32(), "rooms (regions) of the scene; null when the source does not say", nullable=True),
        column("degenerate_faces", pa.int64(), "faces of the source dropped on reading: fewer than 3 corners or zero area"),
    ],
    row="one scene of the job",
)

OBJECTS = register(
    "objects",
    [
        column("scene_id", pa.string(), "scene id"),
        column("object_id", pa.uint32(), "object id > 0 (HM3DSem: the hex colour 0xRRGGBB as an integer; Matterport3D, "
               "ScanNet, ScanNet++, Replica: the dataset's instance id + 1)"),
        column("raw_name", pa.string(), "annotator's raw name"),
        column("mpcat40_index", pa.int16(), "mpcat40 category index (0 = void: the raw name is not mapped)"),
        column("mpcat40_name", pa.string(), "mpcat40 category name"),
        column("is_stuff", pa.bool_(), "wall, floor or ceiling"),
        column("region", pa.int32(), "room / region index, -1 when unknown"),
        column("triangles", pa.int64(), "triangles labelled with this object"),
        column("min_x", pa.float64(), "bounding box minimum x, metres, world frame"),
        column("min_y", pa.float64(), "bounding box minimum y, metres"),
        column("min_z", pa.float64(), "bounding box minimum z, metres"),
        column("max_x", pa.float64(), "bounding box maximum x, metres"),
        column("max_y", pa.float64(), "bounding box maximum y, metres"),
        column("max_z", pa.float64(), "bounding box maximum z, metres"),
        column("surface_area", pa.float64(), "square metres of the object's triangles"),
    ],
    row="one labelled object instance of a scene",
)
