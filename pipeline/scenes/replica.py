"""Replica scenes as downloaded: `<scene>/habitat/mesh_semantic.ply`, `<scene>/habitat/info_semantic.json`
and the coloured `<scene>/mesh.ply`.

The format this reader trusts (facebookresearch/Replica-Dataset README, "habitat" folder):

    habitat/mesh_semantic.ply   binary little-endian PLY of quads, Z up, metres; vertex x y z nx ny nz
                                red green blue; face vertex_indices (4 corners) and `object_id` (int)
    habitat/info_semantic.json  {"classes": [{"id", "name"}], "objects": [{"id", "class_id", "class_name",
                                ...}], "id_to_label": [...]}: instance ids and their class names
    mesh.ply                    the same scene as a quad mesh with vertex colours

Each quad becomes two triangles (0, 1, 2) and (0, 2, 3) that keep its object_id. Object id =
object_id + 1, name = the class name of its class_id (`classes`; an object whose class_id >= 0 is not
listed fails the scene naming the file and field), mpcat40 through our raw-name table. Face ids the
json does not list are void and counted. Colours: mesh.ply's vertex colours (labels move to its
faces by nearest face centre when its triangles differ), else the semantic mesh's own.

What published files hold beyond the README (habitat-sim's ReplicaSemanticScene.cpp reads them):
objects whose class_id is -1 with a class_name of their own ("undefined", "non-plane",
"anonymize_picture", "anonymize_text"): instances, named by that class_name (misc when our table has
no category for it); `id_to_label` (its [0] is -2, and it lists ids no face uses): not read, as
habitat-sim does not read it: faces carry instance ids and `objects` names them; objects no face
uses: dropped (nothing to see); `gravity_dir`, `node_id`, `oriented_bbox`: not read. An id listed
twice (habitat-sim keeps the last) fails the scene naming both entries; ids must fit the uint32
object ids (0 .. 2^32 - 2; habitat-sim skips ids over 10000).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.scenes.categories import MISC, category_of
from pipeline.scenes.ply import read_ply
from pipeline.scenes.scans import (instance_id, integer_field, labelled_faces, palette_vertex_colors, read_json, scan_scene,
                                   transfer_face_labels)
from pipeline.scenes.scene import Scene, SceneError, SceneObject

SEMANTIC_MESH = "mesh_semantic.ply"
SEMANTIC_INFO = "info_semantic.json"


def read_info(path: Path) -> dict[int, SceneObject]:
    """Object id (Replica id + 1) -> SceneObject from `info_semantic.json` (see module doc for its quirks)."""
    info = read_json(path, "a Replica scene needs habitat/info_semantic.json beside habitat/mesh_semantic.ply")
    if not isinstance(info, dict) or not isinstance(info.get("classes"), list) or not isinstance(info.get("objects"), list):
        raise SceneError(f"{path}: expected classes [{{id, name}}] and objects [{{id, class_id}}] lists; "
                         "re-download the scene")
    classes = _classes(path, info["classes"])
    objects: dict[int, SceneObject] = {}
    listed_at: dict[int, int] = {}
    for index, entry in enumerate(info["objects"]):
        where = f"{path}:objects[{index}]"
        if not isinstance(entry, dict):
            raise SceneError(f"{where}: expected an object {{id, class_id, ...}}, got {type(entry).__name__}; "
                             "re-download the scene")
        replica_id = instance_id(entry.get("id"), f"{where}.id")
        if replica_id in listed_at:
            raise SceneError(f"{where}.id: instance {replica_id} is also objects[{listed_at[replica_id]}]; each "
                             "instance needs its own id: re-download the scene or drop one entry")
        listed_at[replica_id] = index
        class_id = integer_field(entry.get("class_id"), f"{where}.class_id", -2**31, 2**31 - 1)
        name, category = _name_and_category(entry, class_id, classes, where)
        objects[replica_id + 1] = SceneObject(replica_id + 1, name, category)
    return objects


def _classes(path: Path, entries: list) -> dict[int, str]:
    """class id -> name of `classes`; a class listed twice fails naming both entries."""
    classes: dict[int, str] = {}
    listed_at: dict[int, int] = {}
    for index, entry in enumerate(entries):
        where = f"{path}:classes[{index}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            raise SceneError(f"{where}: expected {{id, name}} with a string name; re-download the scene")
        class_id = integer_field(entry.get("id"), f"{where}.id", -2**31, 2**31 - 1)
        if class_id in listed_at:
            raise SceneError(f"{where}.id: class {class_id} is also classes[{listed_at[class_id]}]; re-download the scene")
        listed_at[class_id] = index
        classes[class_id] = entry["name"]
    return classes


def _name_and_category(entry: dict, class_id: int, classes: dict[int, str], where: str) -> tuple[str, int]:
    """Raw name and mpcat40 of one `objects` entry. class_id -1 (published files: class_name "undefined",
    "non-plane", "anonymize_picture", "anonymize_text") is an instance without a class: its own class_name
    names it, and a name our table lacks is misc, so the instance is never void."""
    if class_id < 0:
        name = entry.get("class_name", "")
        if not isinstance(name, str):
            raise SceneError(f"{where}.class_name: expected a string, got {type(name).__name__}; re-download the scene")
        return name, category_of(name) or MISC
    if class_id not in classes:
        raise SceneError(f"{where}.class_id: {class_id} is not in classes; re-download the scene")
    return classes[class_id], category_of(classes[class_id])


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
