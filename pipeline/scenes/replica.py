"""Replica scenes as downloaded: `<scene>/habitat/mesh_semantic.ply`, `<scene>/habitat/info_semantic.json`
and the coloured `<scene>/mesh.ply`.

The format this reader trusts (facebookresearch/Replica-Dataset README, "habitat" folder):

    habitat/mesh_semantic.ply   binary little-endian PLY of quads, Z up, metres; vertex x y z nx ny nz
                                red green blue; face vertex_indices (4 corners) and `object_id` (int)
    habitat/info_semantic.json  {"classes": [{"id", "name"}], "objects": [{"id", "class_id", "class_name",
                                ...}], "id_to_label": [...]}: instance ids and their class names
    mesh.ply                    the same scene as a quad mesh with vertex colours

Each quad becomes two triangles (0, 1, 2) and (0, 2, 3) that keep its object_id. Object id =
object_id + 1, name = the class name of its class_id (`classes`; an object whose class_id is not
listed fails the scene naming the file and field), mpcat40 through our raw-name table. Face ids the
json does not list are void and counted. Colours: mesh.ply's vertex colours (labels move to its
faces by nearest face centre when its triangles differ), else the semantic mesh's own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.scenes.categories import category_of
from pipeline.scenes.ply import read_ply
from pipeline.scenes.scans import labelled_faces, palette_vertex_colors, read_json, scan_scene, transfer_face_labels
from pipeline.scenes.scene import Scene, SceneError, SceneObject

SEMANTIC_MESH = "mesh_semantic.ply"
SEMANTIC_INFO = "info_semantic.json"


def read_info(path: Path) -> dict[int, SceneObject]:
    """Object id (Replica id + 1) -> SceneObject from `info_semantic.json`."""
    info = read_json(path, "a Replica scene needs habitat/info_semantic.json beside habitat/mesh_semantic.ply")
    try:
        classes = {int(c["id"]): str(c["name"]) for c in info["classes"]}
        entries = [(int(o["id"]), int(o["class_id"])) for o in info["objects"]]
    except (KeyError, TypeError, ValueError):
        raise SceneError(f"{path}: expected classes [{{id, name}}] and objects [{{id, class_id}}]; "
                         "re-download the scene") from None
    objects = {}
    for index, (replica_id, class_id) in enumerate(entries):
        if class_id not in classes:
            raise SceneError(f"{path}: objects[{index}].class_id {class_id} is not in classes; re-download the scene")
        name = classes[class_id]
        objects[replica_id + 1] = SceneObject(replica_id + 1, name, category_of(name))
    return objects


def read_replica(semantic_path: Path, up_axis: str = "z") -> Scene:
    """Read a Replica scene given its `habitat/mesh_semantic.ply` (see module doc)."""
    semantic_path = Path(semantic_path)
    scene_folder = semantic_path.parent.parent
    objects = read_info(semantic_path.with_name(SEMANTIC_INFO))
    semantic = read_ply(semantic_path)
    if "object_id" not in semantic.face:
        raise SceneError(f"{semantic_path}: faces have no object_id property; re-download the scene's habitat folder")
    face_ids, unknown = labelled_faces(semantic.per_triangle("object_id").astype(np.int64) + 1, objects)
    vertices, faces, colors = semantic.vertices, semantic.triangles, semantic.vertex_colors()
    short = semantic.short_polygons
    coloured_path = scene_folder / "mesh.ply"
    if coloured_path.is_file():
        coloured = read_ply(coloured_path)
        face_ids = transfer_face_labels(vertices, faces, face_ids, coloured.vertices, coloured.triangles)
        vertices, faces, colors, short = coloured.vertices, coloured.triangles, coloured.vertex_colors(), coloured.short_polygons
    appearance = {"vertex_colors": colors if colors is not None else palette_vertex_colors(len(vertices), faces, face_ids)}
    return scan_scene(scene_folder.name, "replica", semantic_path, vertices, faces, face_ids, objects, up_axis,
                      appearance, unknown, short)
