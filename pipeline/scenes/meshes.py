"""Any mesh trimesh reads (OBJ + MTL, PLY, GLB / glTF, STL, OFF) as a labelled scene.

The file is read through trimesh (geometry, the scene graph's node transforms, materials, vertex
colours, textures including MTL `map_Kd`). What labels the faces is chosen by `labels`:

    sidecar     `<stem>.json` beside the mesh (documented in schemas/mesh_sidecar.md):
                `{"objects": [{"id": 12, "name": "chair", "category": 3, "region": 0}, ...]}`; the
                ids come from label properties, else from the trailing integer of the OBJ `o` / `g`
                name or of the glTF node name ("chair_12" -> 12). `category` defaults to the mpcat40
                mapping of `name`, `region` to -1. Ids the JSON does not list are void and counted
                in `Scene.unknown_colors`.
    properties  a PLY face property `object_id` (or `instance`, `label`, `segment`), else the same
                vertex property (a face takes its first vertex's label), or a glTF `_OBJECT_ID`
                vertex attribute; the label is the object id, named `object_<id>`.
    names       the OBJ group (`o` / `g`) of each face, else its material (`usemtl`); the glTF node
                name otherwise: each distinct name is one object, mapped to mpcat40 through the
                raw-name table when the name (trailing `_<n>` / `.<n>` removed) matches, else `misc`.
    components  each connected component of the mesh is one `misc` object.
    auto        (default) the first of those that the file supports, in that order.

Colours: vertex colours, else material base colours and textures. A mesh with no colour at all (an
OBJ whose MTL file is missing included: its `usemtl` names still make the objects), or whose faces
all carry one colour (every material Blender's default grey; `keep_uniform_color` keeps it), is
painted with a palette colour per object (and one warning), so objects stay distinguishable.
`scale` gives the metres of one file unit; a scene over 1 km or under 1 m across gets one warning
naming the likely unit. Warnings are one line per file and kind, however many materials it has.
Faces with fewer than 3 corners or zero area are dropped and counted in `Scene.degenerate_faces`.
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from pipeline.scenes.categories import categories, category_of
from pipeline.scenes.glb import name_label
from pipeline.scenes.scans import palette_vertex_colors, scan_scene
from pipeline.scenes.scene import Scene, SceneError, SceneObject
from pipeline.scenes.trimesh_reader import MESH_SUFFIXES, MeshPart, read_parts

LOG = logging.getLogger(__name__)

LABEL_MODES = ("auto", "sidecar", "properties", "names", "components")
MISC_CATEGORY = next((c.index for c in categories().values() if c.name == "misc"), 0)


# ------------------------------------------------------------------------------------------- labels


def read_sidecar(path: Path) -> dict[int, SceneObject]:
    """Object id -> SceneObject from the JSON sidecar of a mesh file (schemas/mesh_sidecar.md)."""
    sidecar = path.with_suffix(".json")
    if not sidecar.is_file():
        raise SceneError(f"{sidecar}: missing; labels: sidecar needs a JSON of object names beside the mesh (schemas/mesh_sidecar.md)")
    try:
        entries = json.loads(sidecar.read_text(encoding="utf-8"))["objects"]
        objects = {}
        for entry in entries:
            name = str(entry["name"])
            category = int(entry.get("category", category_of(name)))
            objects[int(entry["id"])] = SceneObject(int(entry["id"]), name, category, int(entry.get("region", -1)))
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, UnicodeDecodeError) as error:
        raise SceneError(f"{sidecar}: expected {{\"objects\": [{{\"id\": int, \"name\": str}}, ...]}} ({error}); fix the file") from None
    return objects


def _name_category(name: str) -> int:
    """mpcat40 index of an object name ("chair_3", "Chair.001" -> chair), `misc` when unmapped."""
    base = re.sub(r"([_.\s-]*\d+)+$", "", name).replace("_", " ").strip()
    return category_of(base) or category_of(name) or MISC_CATEGORY


def face_names(parts: list[MeshPart]) -> tuple[list[str], np.ndarray]:
    """Distinct names and each face's index into them: its OBJ group when the groups name at least two,
    else its part's name. Per part, not per face, where possible (a scan has millions of faces)."""
    groups = {g for p in parts for g in (p.face_groups or [])}
    use_groups = len(groups - {""}) >= 2
    index = {name: k for k, name in enumerate(sorted(groups))} if use_groups else {}
    blocks = []
    for part in parts:
        if use_groups and part.face_groups is not None:
            blocks.append(np.array([index[g] for g in part.face_groups], np.int64))
        else:
            blocks.append(np.full(len(part.faces), index.setdefault(part.name, len(index)), np.int64))
    return list(index), np.concatenate(blocks)


def choose_labels(parts: list[MeshPart], path: Path, mode: str) -> str:
    """The label source `auto` resolves to for these parts (see module doc)."""
    if mode != "auto":
        return mode
    if path.with_suffix(".json").is_file():
        return "sidecar"
    if all(p.face_labels is not None for p in parts):
        return "properties"
    if any(face_names(parts)[0]):
        return "names"
    return "components"


def _labels_sidecar(parts: list[MeshPart], path: Path) -> tuple[np.ndarray, dict[int, SceneObject], int]:
    objects = read_sidecar(path)
    if all(p.face_labels is not None for p in parts):
        labels = np.concatenate([p.face_labels for p in parts])  # type: ignore[misc]
    else:
        names, which = face_names(parts)
        labels = np.array([name_label(n) for n in names], np.int64)[which]
    listed = np.isin(labels, np.array(sorted(objects), dtype=np.int64)) & (labels > 0)
    unknown = len(np.unique(labels[~listed & (labels > 0)]))
    return np.where(listed, labels, 0), objects, unknown


def _labels_properties(parts: list[MeshPart], path: Path) -> tuple[np.ndarray, dict[int, SceneObject], int]:
    if not all(p.face_labels is not None for p in parts):
        raise SceneError(f"{path}: labels: properties, but the file has no object_id / instance / label / segment "
                         "property (PLY) or _OBJECT_ID attribute (glTF); use labels: auto")
    labels = np.concatenate([p.face_labels for p in parts])  # type: ignore[misc]
    objects = {int(i): SceneObject(int(i), f"object_{int(i)}", MISC_CATEGORY) for i in np.unique(labels) if i > 0}
    return labels, objects, 0


def _labels_names(parts: list[MeshPart], path: Path) -> tuple[np.ndarray, dict[int, SceneObject], int]:
    names, which = face_names(parts)
    if not any(names):
        raise SceneError(f"{path}: labels: names, but the file names no group, material or node; use labels: components")
    # Object ids 1..N in name order; an empty name (faces outside any group) is void.
    ids = {name: k for k, name in enumerate(sorted(n for n in names if n), start=1)}
    labels = np.array([ids.get(n, 0) for n in names], np.int64)[which]
    objects = {i: SceneObject(i, name, _name_category(name)) for name, i in ids.items()}
    return labels, objects, 0


def _labels_components(parts: list[MeshPart], path: Path) -> tuple[np.ndarray, dict[int, SceneObject], int]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    vertices, faces = merged_geometry(parts)
    # Corners at the same position join, so a component is not split by duplicated vertices.
    _, same = np.unique(vertices, axis=0, return_inverse=True)
    corners = same.reshape(-1)[faces]
    edges = np.concatenate([corners[:, [0, 1]], corners[:, [1, 2]]])
    size = int(corners.max()) + 1
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(size, size))
    _, component = connected_components(graph, directed=False)
    _, labels = np.unique(component[corners[:, 0]], return_inverse=True)
    labels = labels.reshape(-1).astype(np.int64) + 1
    objects = {int(i): SceneObject(int(i), f"component_{int(i)}", MISC_CATEGORY) for i in np.unique(labels)}
    return labels, objects, 0


LABELLERS = {"sidecar": _labels_sidecar, "properties": _labels_properties, "names": _labels_names,
             "components": _labels_components}


# ------------------------------------------------------------------------------------- appearance


def merged_geometry(parts: list[MeshPart]) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    vertices = np.concatenate([p.vertices for p in parts]).astype(np.float32)
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)])
    return vertices, faces


def vertex_colors_of(parts: list[MeshPart], face_ids: np.ndarray, palette: bool = False) -> np.ndarray:
    """(V, 3) colours: the part's vertex or base colour, a palette colour per object where none (or
    everywhere, when `palette`)."""
    blocks, start = [], 0
    for part in parts:
        if palette or not part.coloured:
            block = palette_vertex_colors(len(part.vertices), part.faces, face_ids[start: start + len(part.faces)])
        elif part.vertex_colors is not None:
            block = part.vertex_colors
        elif part.base_color is not None:
            block = np.tile(part.base_color, (len(part.vertices), 1))
        else:
            block = np.tile(part.texture.reshape(-1, 3).mean(axis=0).astype(np.uint8), (len(part.vertices), 1))  # type: ignore[union-attr]
        blocks.append(block.astype(np.uint8))
        start += len(part.faces)
    return np.concatenate(blocks)


def textured_appearance(parts: list[MeshPart], vertex_colors: np.ndarray, faces: np.ndarray) -> dict:
    """Scene texture fields: each part's texture, and one-pixel textures of the other faces' colours."""
    textures: list[np.ndarray] = []
    uv_blocks, material_blocks = [], []
    face_colors = vertex_colors[faces].mean(axis=1).astype(np.uint8)
    start = 0
    for part in parts:
        count = len(part.faces)
        if part.texture is not None and part.uvs is not None:
            material_blocks.append(np.full(count, len(textures), np.int64))
            textures.append(part.texture)
            uv_blocks.append(part.uvs[part.faces])
        else:
            colors, inverse = np.unique(face_colors[start: start + count], axis=0, return_inverse=True)
            material_blocks.append(len(textures) + inverse.reshape(-1))
            textures.extend(c.reshape(1, 1, 3) for c in colors)
            uv_blocks.append(np.full((count, 3, 2), 0.5, np.float32))
        start += count
    if len(textures) > np.iinfo(np.uint16).max:
        raise SceneError("a textured mesh with more than 65535 distinct plain face colours; bake the colours into a texture")
    return {"face_uvs": np.concatenate(uv_blocks).astype(np.float32), "textures": textures,
            "face_material": np.concatenate(material_blocks).astype(np.uint16), "vertex_colors": None}


# ----------------------------------------------------------------------------------------- assembly


def read_labelled_mesh(path: Path, up_axis: str = "y", labels: str = "auto", scale: float = 1.0,
                       keep_uniform_color: bool = False) -> Scene:
    """Read a mesh file as a labelled Scene (see module doc); raises SceneError naming the file.

    Args:
        scale: metres per file unit (vertices are multiplied by it).
        keep_uniform_color: keep a colour every face shares instead of painting a palette colour per object.
    """
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{path}: unsupported mesh format {path.suffix!r}; use one of {', '.join(MESH_SUFFIXES)}")
    if not path.is_file():
        raise SceneError(f"{path}: no such file; check the mesh folder")
    if labels not in LABEL_MODES:
        raise SceneError(f"{path}: labels {labels!r}: use one of {', '.join(LABEL_MODES)}")
    parts, short_faces = read_parts(path)
    mode = choose_labels(parts, path, labels)
    face_ids, objects, unknown = LABELLERS[mode](parts, path)
    vertices, faces = merged_geometry(parts)
    if scale != 1.0:
        vertices = (vertices.astype(np.float64) * scale).astype(np.float32)
    _warn_unlikely_unit(path, vertices, scale)
    if parts[0].missing_library:
        LOG.warning("%s: its material library %s is missing; objects come from its %d `usemtl` (and `o` / `g`) names, "
                    "painted a palette colour each", path, parts[0].missing_library, len(objects))
    elif not any(p.coloured for p in parts):
        LOG.warning("%s: no vertex colours, materials or textures; painting each object a palette colour", path)
    LOG.info("%s: labels: %s", path, mode)
    return scan_scene(path.stem, "mesh", path, vertices, faces, face_ids, objects, up_axis,
                      _appearance(parts, face_ids, faces, path, keep_uniform_color), unknown, short_faces)


def _appearance(parts: list[MeshPart], face_ids: np.ndarray, faces: np.ndarray, path: Path,
                keep_uniform_color: bool) -> dict:
    """Scene colour fields: textures when any part has one, else vertex colours; one colour on every
    face (Blender's default grey) becomes a palette colour per object unless `keep_uniform_color`."""
    colors = vertex_colors_of(parts, face_ids)
    if any(p.texture is not None for p in parts):
        return textured_appearance(parts, colors, faces)
    if keep_uniform_color or not any(p.coloured for p in parts) or not _one_colour(colors, faces):
        return {"vertex_colors": colors}
    LOG.warning("%s: every face has the same colour %s (as Blender's default material); painting each object a "
                "palette colour so that frames are not flat; set keep_uniform_color: true to keep it",
                path, tuple(int(c) for c in colors[faces[0, 0]]))
    return {"vertex_colors": vertex_colors_of(parts, face_ids, palette=True)}


def _one_colour(vertex_colors: np.ndarray, faces: np.ndarray) -> bool:
    """True when every face corner has the same colour."""
    corners = vertex_colors[faces.reshape(-1)]
    return bool((corners == corners[0]).all())


def _warn_unlikely_unit(path: Path, vertices: np.ndarray, scale: float) -> None:
    """One warning when the scene's extent suggests its unit is not metres (over 1 km or under 1 m across)."""
    extent = float((vertices.max(axis=0) - vertices.min(axis=0)).max()) if len(vertices) else 0.0
    if extent > 1000.0:
        # A building is 2-200 m across: over 20 km of "metres" is millimetres more likely than centimetres.
        unit, factor = ("millimetres", 0.001) if extent > 20000.0 else ("centimetres", 0.01)
        LOG.warning("%s: the scene is %.0f m across; its unit is likely %s: set scale: %g (now %g) on the meshes source",
                    path, extent, unit, scale * factor, scale)
    elif 0 < extent < 1.0:
        LOG.warning("%s: the scene is %.3g m across, smaller than a room; its unit is likely not metres (kilometres, or a "
                    "model scaled to a unit box): set scale on the meshes source (now %g) to the metres of one file unit",
                    path, extent, scale)
