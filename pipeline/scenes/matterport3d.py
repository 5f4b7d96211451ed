"""Matterport3D scans as downloaded: `<scan>/house_segmentations/<scan>.house` + `<scan>.ply`, and the
textured `<scan>/matterport_mesh/<uuid>/<uuid>.obj` (+ .mtl, JPEG textures) when present.

The format this reader trusts (niessner/Matterport, data_organization.md, "house_segmentations"):

    <scan>.house   ASCII; a first line `ASCII 1.1`, then one record per line, fields split by spaces:
                   C category_index category_mapping_index category_mapping_name mpcat40_index mpcat40_name 0 0 0 0 0
                   O object_index region_index category_index px py pz a0x a0y a0z a1x a1y a1z r0 r1 r2 0 ...
                   E segment_index object_index id area px py pz xlo ylo zlo xhi yhi zhi 0 0 0 0 0
                   (H, L, R, P, S, V, I records are read past). Names write spaces as '#'; '-' is no name.
    <scan>.ply     binary PLY, Z up, metres; vertex x y z nx ny nz tx ty red green blue; face
                   vertex_indices plus `material_id` (the documentation's face_material: the id of the
                   `E` segment holding the face), `segment_id` and `category_id`.

Faces join to objects through their segment: face material_id == E.id -> E.object_index -> O ->
O.category_index -> C (raw name = category_mapping_name, category = mpcat40_index, as the file says).
Object id = O's object_index + 1 (0 is void: faces of no segment, or of a segment of no object);
region = O's region_index. RGB: the textured OBJ's textures when present (labels move to its faces by
nearest face centre), else the segmentation mesh's vertex colours.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.scenes.ply import read_ply
from pipeline.scenes.scans import (distinct_positive, instance_id, integer_field, labelled_faces, lookup,
                                   palette_vertex_colors, scan_scene, transfer_face_labels)
from pipeline.scenes.scene import Scene, SceneError, SceneObject

HOUSE_SUFFIX = ".house"
SEGMENT_PROPERTIES = ("material_id", "face_material")


@dataclass
class House:
    """What a `.house` file says about objects: categories, objects and the segments that make them."""

    categories: dict[int, tuple[str, int]]  # category_index -> (raw name, mpcat40 index)
    objects: dict[int, tuple[int, int]]  # object_index -> (region_index, category_index)
    segment_objects: dict[int, int]  # segment id (the PLY's material_id) -> object_index (-1: none)


def _name(field: str) -> str:
    return "" if field == "-" else field.replace("#", " ")


def read_house(path: Path) -> House:
    """Parse the C, O and E records of a `.house` file; SceneError naming file:line and field on bad data.

    Read as habitat-sim's Mp3dSemanticScene.cpp reads it: blank lines skipped, fields split on runs of
    spaces, records other than C / O / E passed over, `O` category_index -1 (no category), region_index -1
    (no region) and `E` object_index -1 (a segment of no object: void). Segment ids are large
    (region_index * 1000000 + segment). Where habitat-sim keeps the last of two records with the same
    index (C, O) or segment id (E), we fail naming both lines."""
    try:
        text = path.read_bytes().decode("utf-8-sig", errors="replace")
    except OSError as error:
        raise SceneError(f"{path}: cannot read ({error.strerror}); re-download the scan's house_segmentations") from None
    if text.split("\n", 1)[0].split() == ["ASCII", "1.0"]:  # Matterport's mp.cpp: 1.0 has no C, O, E records
        raise SceneError(f"{path}:1: an ASCII 1.0 .house holds no objects (categories, objects and segments came "
                         "with 1.1); use the scan's v1.1 house_segmentations")
    house = House({}, {}, {})
    lines: dict[str, dict[int, int]] = {"C": {}, "O": {}, "E": {}}  # record kind -> key -> line number
    references: list[tuple[int, str, int, int]] = []  # (line, kind, key, index it names): checked once all are read
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        kind = fields[0] if fields else ""
        if kind not in lines:
            continue
        key, value, reference = _record(path, number, fields)
        if key in lines[kind]:
            raise SceneError(f"{path}:{number}: {_KEY_NAMES[kind]} {key} is also on line {lines[kind][key]}; "
                             "each needs its own; re-download the scan's house_segmentations")
        lines[kind][key] = number
        getattr(house, _TABLES[kind])[key] = value
        if reference >= 0:
            references.append((number, kind, key, reference))
    if not house.objects or not house.segment_objects:
        raise SceneError(f"{path}: no `O` object or `E` segment records (an empty .house); "
                         "re-download the scan's house_segmentations")
    for number, kind, key, reference in references:
        if kind == "O" and reference not in house.categories:
            raise SceneError(f"{path}:{number}: object {key} has category_index {reference}, which no `C` record "
                             "lists; re-download the scan's house_segmentations")
        if kind == "E" and reference not in house.objects:
            raise SceneError(f"{path}:{number}: segment {key} has object_index {reference}, which no `O` record "
                             "lists; re-download the scan's house_segmentations")
    return house


_TABLES = {"C": "categories", "O": "objects", "E": "segment_objects"}
_KEY_NAMES = {"C": "category_index", "O": "object_index", "E": "segment id"}
INT32 = (-2**31, 2**31 - 1)
INT64 = (-2**63, 2**63 - 1)


def _record(path: Path, number: int, fields: list[str]) -> tuple[int, object, int]:
    """(key, value, the index the record refers to or -1) of one C, O or E record; SceneError naming the line."""
    kind = fields[0]

    def number_at(position: int, name: str, low: int | None = None, high: int | None = None) -> int:
        try:
            value = int(fields[position])
        except (IndexError, ValueError):
            raise SceneError(f"{path}:{number}: cannot read the {kind!r} record's {name} in "
                             f"{' '.join(fields)[:60]!r}; re-download the scan's house_segmentations") from None
        where = f"{path}:{number}: {kind} {name}"
        return instance_id(value, where) if low is None or high is None else integer_field(value, where, low, high)

    if kind == "C":
        if len(fields) < 4:
            raise SceneError(f"{path}:{number}: the 'C' record {' '.join(fields)[:60]!r} has no category_mapping_name; "
                             "re-download the scan's house_segmentations")
        return number_at(1, "category_index", 0, INT32[1]), (_name(fields[3]), number_at(4, "mpcat40_index", 0, 41)), -1
    if kind == "O":
        index = number_at(1, "object_index")  # an instance id
        category = number_at(3, "category_index", -1, INT32[1])
        return index, (number_at(2, "region_index", -1, INT32[1]), category), category
    object_index = -1 if fields[2:3] == ["-1"] else number_at(2, "object_index")  # -1: a segment of no object
    return number_at(3, "id", *INT64), object_index, object_index


def house_objects(house: House) -> dict[int, SceneObject]:
    """Object id (object_index + 1) -> SceneObject with the category's raw name and mpcat40 index."""
    objects = {}
    for index, (region, category) in house.objects.items():
        name, mpcat40 = house.categories.get(category, ("", 0))
        objects[index + 1] = SceneObject(index + 1, name, mpcat40, region)
    return objects


def textured_mesh(scan_folder: Path) -> Path | None:
    """The scan's `matterport_mesh/<uuid>/<uuid>.obj`, or None when it was not downloaded."""
    return next(iter(sorted(scan_folder.glob("matterport_mesh/*/*.obj"))), None)


def read_matterport3d(house_path: Path, up_axis: str = "z", textured: bool = True) -> Scene:
    """Read a Matterport3D scan given its `.house` file (see module doc); raises SceneError naming the file."""
    house_path = Path(house_path)
    ply_path = house_path.with_suffix(".ply")
    if not ply_path.is_file():
        raise SceneError(f"{ply_path}: missing; a Matterport3D scan needs {house_path.stem}.house and "
                         f"{house_path.stem}.ply side by side (house_segmentations)")
    house = read_house(house_path)
    mesh = read_ply(ply_path)
    key = next((k for k in SEGMENT_PROPERTIES if k in mesh.face), None)
    if key is None:
        raise SceneError(f"{ply_path}: faces have no material_id (segment id) property; re-download the scan's "
                         "house_segmentations")
    segment_ids = np.array(list(house.segment_objects), np.int64)
    segment_object = np.array(list(house.segment_objects.values()), np.int64) + 1
    face_segments = mesh.per_triangle(key).astype(np.int64)
    found, labels = lookup(segment_ids, segment_object, face_segments)
    objects = house_objects(house)
    face_ids, _ = labelled_faces(labels, objects)
    unknown = len(distinct_positive(np.where(found, 0, face_segments + 1).clip(min=0)))  # + 1: segment id 0 counts
    vertices = mesh.vertices
    obj_path = textured_mesh(house_path.parent.parent) if textured else None
    if obj_path is not None:
        return _textured_scan(house_path, obj_path, vertices, mesh.triangles, face_ids, objects, up_axis, unknown)
    colors = mesh.vertex_colors()
    appearance = {"vertex_colors": colors if colors is not None else
                  palette_vertex_colors(len(vertices), mesh.triangles, face_ids)}
    return scan_scene(house_path.stem, "matterport3d", house_path, vertices, mesh.triangles, face_ids, objects,
                      up_axis, appearance, unknown, mesh.short_polygons)


def _textured_scan(house_path: Path, obj_path: Path, vertices: np.ndarray, faces: np.ndarray, face_ids: np.ndarray,
                   objects: dict[int, SceneObject], up_axis: str, unknown: int) -> Scene:
    """The textured OBJ's geometry and textures, each face labelled like the nearest segmentation face."""
    from pipeline.scenes.meshes import merged_geometry, textured_appearance, vertex_colors_of
    from pipeline.scenes.trimesh_reader import read_parts

    parts, short_faces = read_parts(obj_path)
    obj_vertices, obj_faces = merged_geometry(parts)
    obj_ids = transfer_face_labels(vertices.astype(np.float64), faces, face_ids,
                                   obj_vertices.astype(np.float64), obj_faces)
    colors = vertex_colors_of(parts, obj_ids)
    appearance = textured_appearance(parts, colors, obj_faces) if any(p.texture is not None for p in parts) \
        else {"vertex_colors": colors}
    return scan_scene(house_path.stem, "matterport3d", house_path, obj_vertices, obj_faces, obj_ids, objects,
                      up_axis, appearance, unknown, short_faces)
