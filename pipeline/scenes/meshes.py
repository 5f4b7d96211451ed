"""Plain labelled meshes: OBJ, PLY or GLB with instance labels, plus a JSON of names and categories.

Labels:
    PLY  a face property `object_id` (or `instance`, `label`, `segment`), else the same vertex property
         (a face takes the label of its first vertex);
    OBJ  the trailing integer of the current `o` / `g` name (`o 12`, `g chair_12`);
    GLB  a custom vertex attribute `_OBJECT_ID`, else the trailing integer of the node or mesh name.
Names: `<stem>.json` beside the mesh, `{"objects": [{"id": 12, "name": "chair", "category": 3,
"region": 0}, ...]}`; `category` defaults to the mpcat40 mapping of `name`, `region` to -1. Labels
0 and labels the JSON does not list are void; the latter are counted in `Scene.unknown_colors`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.scenes.categories import category_of
from pipeline.scenes.glb import name_label, read_glb
from pipeline.scenes.hm3dsem import to_world, up_axis_transform
from pipeline.scenes.scene import Scene, SceneError, SceneObject

LABEL_PROPERTIES = ("object_id", "instance", "label", "segment")


def read_names(path: Path) -> dict[int, SceneObject]:
    """Object id -> SceneObject from the JSON sidecar of a mesh file."""
    sidecar = path.with_suffix(".json")
    if not sidecar.is_file():
        raise SceneError(f"{sidecar}: missing; a plain mesh needs a JSON of object names beside it (see pipeline/scenes/meshes.py)")
    try:
        entries = json.loads(sidecar.read_text(encoding="utf-8"))["objects"]
        objects = {}
        for entry in entries:
            name = str(entry["name"])
            category = int(entry.get("category", category_of(name)))
            objects[int(entry["id"])] = SceneObject(int(entry["id"]), name, category, int(entry.get("region", -1)))
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as error:
        raise SceneError(f"{sidecar}: expected {{\"objects\": [{{\"id\": int, \"name\": str}}, ...]}} ({error}); fix the file") from None
    return objects


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices, triangles (polygons fanned), face labels and vertex colours (if every `v` has rgb)."""
    vertices, colors, faces, labels = [], [], [], []
    label = 0
    with path.open(encoding="utf-8", errors="replace") as handle:
        for number, line in enumerate(handle, start=1):
            fields = line.split()
            if not fields or fields[0].startswith("#"):
                continue
            try:
                if fields[0] == "v":
                    vertices.append([float(x) for x in fields[1:4]])
                    if len(fields) >= 7:
                        colors.append([float(x) for x in fields[4:7]])
                elif fields[0] in ("o", "g"):
                    label = name_label(" ".join(fields[1:]))
                elif fields[0] == "f":
                    corners = [int(f.split("/")[0]) for f in fields[1:]]
                    corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
                    if len(corners) < 3:
                        raise ValueError("a face needs 3 corners")
                    for k in range(1, len(corners) - 1):
                        faces.append([corners[0], corners[k], corners[k + 1]])
                        labels.append(label)
            except ValueError as error:
                raise SceneError(f"{path}:{number}: cannot read {fields[0]!r} line ({error}); fix the line") from None
    rgb = None
    if colors and len(colors) == len(vertices):
        values = np.array(colors)
        rgb = np.clip(np.round(values * (255.0 if values.max() <= 1.0 else 1.0)), 0, 255).astype(np.uint8)
    return (np.array(vertices, np.float32).reshape(-1, 3), np.array(faces, np.int64).reshape(-1, 3),
            np.array(labels, np.int64), rgb)


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    import trimesh

    try:
        mesh = trimesh.load(str(path), process=False, force="mesh")
        raw = mesh.metadata["_ply_raw"]
    except (ValueError, KeyError, IndexError, TypeError, AttributeError, UnicodeDecodeError) as error:
        raise SceneError(f"{path}: corrupt PLY ({type(error).__name__}: {error}); re-export the file") from None
    faces = np.asarray(mesh.faces, np.int64)
    face_data, vertex_data = raw["face"]["data"], raw["vertex"]["data"]
    labels = np.zeros(len(faces), np.int64)
    face_key = next((k for k in LABEL_PROPERTIES if k in face_data), None)
    vertex_key = next((k for k in LABEL_PROPERTIES if k in vertex_data), None)
    if face_key is not None:
        per_polygon = np.asarray(face_data[face_key]).reshape(-1).astype(np.int64)
        corners = face_data["vertex_indices"]
        sizes = np.array([len(c) for c in corners]) if len(per_polygon) != len(faces) else np.full(len(per_polygon), 3)
        labels = np.repeat(per_polygon, sizes - 2)
    elif vertex_key is not None:
        labels = np.asarray(vertex_data[vertex_key]).reshape(-1).astype(np.int64)[faces[:, 0]]
    rgb = None
    if getattr(mesh.visual, "kind", None) == "vertex":
        rgb = np.asarray(mesh.visual.vertex_colors)[:, :3].astype(np.uint8)
    return np.asarray(mesh.vertices, np.float32), faces, labels, rgb


def _read_glb_labelled(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    mesh = read_glb(path)
    labels = mesh.vertex_labels[mesh.faces[:, 0]] if mesh.vertex_labels is not None and len(mesh.faces) else np.zeros(len(mesh.faces), np.int64)
    colors = mesh.vertex_colors if mesh.vertex_colors is not None else mesh.base_colors
    return mesh.vertices, mesh.faces, labels, colors


READERS = {".obj": _read_obj, ".ply": _read_ply, ".glb": _read_glb_labelled}


def read_labelled_mesh(path: Path, up_axis: str = "y") -> Scene:
    """Read a plain mesh with instance labels and its JSON of names (see module doc)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise SceneError(f"{path}: unsupported mesh format {suffix!r}; use .obj, .ply or .glb")
    if not path.is_file():
        raise SceneError(f"{path}: no such file; check the mesh folder")
    objects = read_names(path)
    vertices, faces, labels, colors = READERS[suffix](path)
    listed = np.isin(labels, np.array(sorted(objects), dtype=np.int64)) & (labels > 0)
    unknown = np.unique(labels[~listed & (labels > 0)])
    face_ids = np.where(listed, labels, 0).astype(np.uint32)
    present = {int(i) for i in np.unique(face_ids) if i > 0}
    transform = up_axis_transform(up_axis)
    return Scene(
        scene_id=path.stem, vertices=to_world(vertices, transform), faces=faces.astype(np.int32), face_object_ids=face_ids,
        objects={i: o for i, o in sorted(objects.items()) if i in present},
        vertex_colors=colors if colors is not None else np.full((len(vertices), 3), 180, np.uint8),
        to_world=transform, source="mesh", path=str(path), unknown_colors=int(len(unknown)),
    )
