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

Colours: vertex colours, else material base colours and textures. A mesh with no colour at all is
painted with a palette colour per object (and a warning), so objects stay distinguishable.
Faces with fewer than 3 corners or zero area are dropped and counted in `Scene.degenerate_faces`.
"""

from __future__ import annotations

import json
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.scenes.categories import categories, category_of
from pipeline.scenes.glb import MAGIC, SUPPORTED_EXTENSIONS, name_label
from pipeline.scenes.hm3dsem import to_world, up_axis_transform
from pipeline.scenes.scene import Scene, SceneError, SceneObject

LOG = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")
LABEL_MODES = ("auto", "sidecar", "properties", "names", "components")
LABEL_PROPERTIES = ("object_id", "instance", "label", "segment")
MISC_CATEGORY = next((c.index for c in categories().values() if c.name == "misc"), 0)
# Required glTF extensions trimesh decodes (or that change nothing we read).
GLTF_EXTENSIONS = SUPPORTED_EXTENSIONS | {"KHR_texture_transform", "KHR_materials_pbrSpecularGlossiness"}


@dataclass
class MeshPart:
    """One placed geometry of the file, in the file's frame (node transform applied).

    Attributes:
        name: the OBJ material or the glTF node name ("" for a single unnamed mesh).
        vertices: (V, 3) float64 positions.
        faces: (F, 3) int64 triangles.
        face_labels: (F,) int64 label property per face, or None.
        face_groups: the OBJ `o` / `g` name of each face, or None.
        vertex_colors: (V, 3) uint8, or None.
        base_color: (3,) uint8 material colour, or None.
        texture: (H, W, 3) uint8 image with `uvs` ((V, 2), v up), or None.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    face_labels: np.ndarray | None = None
    face_groups: list[str] | None = None
    vertex_colors: np.ndarray | None = None
    base_color: np.ndarray | None = None
    texture: np.ndarray | None = None
    uvs: np.ndarray | None = None

    @property
    def coloured(self) -> bool:
        return self.vertex_colors is not None or self.base_color is not None or self.texture is not None


# ------------------------------------------------------------------------------------------ reading


def _load_trimesh(path: Path):  # noqa: ANN202 - trimesh.Scene, imported lazily (trimesh is slow to import)
    import trimesh

    if path.suffix.lower() in (".glb", ".gltf"):
        _check_gltf_extensions(path)
    try:
        # One geometry per material keeps OBJ `usemtl` groups apart; process=False keeps vertex order.
        return trimesh.load_scene(str(path), process=False)
    except (ValueError, KeyError, IndexError, TypeError, AttributeError, UnicodeDecodeError, OSError) as error:
        where = _first_bad_obj_line(path) if path.suffix.lower() == ".obj" else None
        if where is not None:
            raise SceneError(f"{path}:{where[0]}: cannot read {where[1]!r} line; fix the line") from None
        raise SceneError(f"{path}: trimesh cannot read the mesh ({type(error).__name__}: {error}); re-export the file") from None


def _check_gltf_extensions(path: Path) -> None:
    """Refuse glTF files that need an extension trimesh does not decode (it would read them as empty)."""
    if path.suffix.lower() == ".glb":
        with path.open("rb") as handle:
            head = handle.read(20)
            if len(head) < 20 or head[:4] != MAGIC:
                raise SceneError(f"{path}: corrupt GLB (no glTF header); re-export or re-download the file")
            document_bytes = handle.read(int.from_bytes(head[12:16], "little"))
    else:
        document_bytes = path.read_bytes()
    try:
        required = json.loads(document_bytes.decode("utf-8")).get("extensionsRequired", [])
    except (UnicodeDecodeError, json.JSONDecodeError, AttributeError) as error:
        raise SceneError(f"{path}: corrupt glTF JSON ({error}); re-export the file") from None
    unsupported = sorted(set(required) - GLTF_EXTENSIONS)
    if unsupported:
        raise SceneError(f"{path}: needs glTF extension {', '.join(unsupported)}, which the reader does not decode; "
                         "re-export without it")


def _first_bad_obj_line(path: Path) -> tuple[int, str] | None:
    """(line number, keyword) of the first `v` / `vt` / `vn` line whose numbers do not parse."""
    with path.open(encoding="utf-8", errors="replace") as handle:
        for number, line in enumerate(handle, start=1):
            fields = line.split()
            if fields and fields[0] in ("v", "vt", "vn"):
                try:
                    [float(x) for x in fields[1:]]
                except ValueError:
                    return number, fields[0]
    return None


def _image_rgb(image: object) -> np.ndarray | None:
    if image is None:
        return None
    return np.asarray(image.convert("RGB"), np.uint8)  # type: ignore[attr-defined]


def _appearance(geometry: object) -> dict:
    """Colour fields of one trimesh geometry: vertex colours, a texture with UVs, or a base colour."""
    visual = geometry.visual  # type: ignore[attr-defined]
    kind = getattr(visual, "kind", None)
    if kind == "vertex":
        return {"vertex_colors": np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8)}
    if kind == "face":
        # Per-face colours: each face's colour on its corners (shared corners take one of them).
        colors = np.zeros((len(geometry.vertices), 3), np.uint8)  # type: ignore[attr-defined]
        colors[geometry.faces.reshape(-1)] = np.repeat(np.asarray(visual.face_colors)[:, :3], 3, axis=0)  # type: ignore[attr-defined]
        return {"vertex_colors": colors}
    material = getattr(visual, "material", None)
    if material is None:
        return {}
    image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    uv = getattr(visual, "uv", None)
    if image is not None and uv is not None and len(uv) == len(geometry.vertices):  # type: ignore[attr-defined]
        return {"texture": _image_rgb(image), "uvs": np.asarray(uv, np.float32)[:, :2]}
    factor = getattr(material, "baseColorFactor", None)
    if factor is None:
        factor = getattr(material, "diffuse", None)
    return {"base_color": np.asarray(factor, np.uint8)[:3]} if factor is not None else {}


def _ply_labels(geometry: object) -> np.ndarray | None:
    """Per-face labels from a PLY face (or vertex) label property, or None."""
    raw = getattr(geometry, "metadata", {}).get("_ply_raw")
    if not raw:
        return None
    faces = np.asarray(geometry.faces)  # type: ignore[attr-defined]
    face_data, vertex_data = raw.get("face", {}).get("data", {}), raw.get("vertex", {}).get("data", {})
    face_key = next((k for k in LABEL_PROPERTIES if k in face_data), None)
    if face_key is not None:
        per_polygon = np.asarray(face_data[face_key]).reshape(-1).astype(np.int64)
        if len(per_polygon) == len(faces):
            return per_polygon
        sizes = np.array([len(c) for c in face_data["vertex_indices"]])
        return np.repeat(per_polygon, np.maximum(sizes - 2, 0))
    vertex_key = next((k for k in LABEL_PROPERTIES if k in vertex_data), None)
    if vertex_key is not None:
        return np.asarray(vertex_data[vertex_key]).reshape(-1).astype(np.int64)[faces[:, 0]]
    return None


def _attribute_labels(geometry: object) -> np.ndarray | None:
    """Per-face labels from a glTF `_OBJECT_ID` (or `object_id`) vertex attribute, or None."""
    attributes = getattr(geometry, "vertex_attributes", {}) or {}
    key = next((k for k in ("_OBJECT_ID", "_object_id", "object_id") if k in attributes), None)
    if key is None:
        return None
    per_vertex = np.asarray(attributes[key]).reshape(len(attributes[key]), -1)[:, 0]
    return np.rint(per_vertex).astype(np.int64)[np.asarray(geometry.faces)[:, 0]]  # type: ignore[attr-defined]


@dataclass
class ObjFaces:
    """What trimesh does not keep of an OBJ: each triangle's `o` / `g` name, per material, in file order."""

    groups: dict[str, list[str]]
    short_faces: int  # `f` lines with fewer than 3 corners (trimesh drops them)
    any_group: bool


def _scan_obj_faces(path: Path) -> ObjFaces:
    """Each triangle's group name, in the order trimesh emits them (per material, then file order)."""
    groups: dict[str, list[str]] = {}
    group, material, short, any_group = "", "", 0, False
    with path.open(encoding="utf-8", errors="replace") as handle:
        for line in handle:
            head = line[:7]
            if head.startswith(("f ", "f\t")):
                corners = len(line.split()) - 1
                if corners < 3:
                    short += 1
                else:
                    groups.setdefault(material, []).extend([group] * (corners - 2))
            elif head.startswith(("o ", "g ", "o\t", "g\t")):
                group, any_group = line[2:].strip(), True
            elif head.startswith("usemtl"):
                material = line[6:].strip()
    return ObjFaces(groups, short, any_group)


def read_parts(path: Path) -> tuple[list[MeshPart], int]:
    """Every placed geometry of a mesh file (file frame) and the count of faces with < 3 corners."""
    scene = _load_trimesh(path)
    obj = _scan_obj_faces(path) if path.suffix.lower() == ".obj" else None
    parts = []
    for node in scene.graph.nodes_geometry:
        matrix, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        if not hasattr(geometry, "faces") or len(geometry.faces) == 0:
            continue  # point clouds and lines carry no surface
        vertices = np.asarray(geometry.vertices, np.float64)
        if not np.array_equal(matrix, np.eye(4)):
            vertices = vertices @ np.asarray(matrix)[:3, :3].T + np.asarray(matrix)[:3, 3]
        faces = np.asarray(geometry.faces, np.int64)
        labels = _ply_labels(geometry)
        labels = labels if labels is not None else _attribute_labels(geometry)
        name = _part_name(path, geometry, str(node), obj)
        part = MeshPart(name, vertices, faces, face_labels=labels, **_appearance(geometry))
        if obj is not None and obj.any_group:
            part.face_groups = _obj_groups_of(path, obj, geometry, len(faces))
        parts.append(part)
    if not parts:
        raise SceneError(f"{path}: the mesh is empty (0 triangles); check the file was exported with geometry")
    return parts, (obj.short_faces if obj is not None else 0)


def _part_name(path: Path, geometry: object, node: str, obj: ObjFaces | None) -> str:
    """The name a part carries: its OBJ material, its glTF node; "" for single-mesh formats."""
    if obj is not None:
        material = getattr(getattr(geometry.visual, "material", None), "name", None)  # type: ignore[attr-defined]
        return str(material) if material and obj.groups.keys() - {""} else ""
    return node if path.suffix.lower() in (".glb", ".gltf") else ""


def _obj_groups_of(path: Path, obj: ObjFaces, geometry: object, count: int) -> list[str]:
    material = getattr(getattr(geometry.visual, "material", None), "name", None) or ""  # type: ignore[attr-defined]
    groups = obj.groups.get(str(material)) if len(obj.groups) > 1 else next(iter(obj.groups.values()), [])
    if groups is None or len(groups) != count:
        raise SceneError(f"{path}: {count} triangles of material {material!r} but {len(groups or [])} `f` corners "
                         "in its groups; re-export the OBJ with triangles or use labels: names")
    return groups


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


def _face_names(parts: list[MeshPart]) -> list[str]:
    """Each face's name: its OBJ group when the groups name at least two, else its part's name."""
    groups = {g for p in parts for g in (p.face_groups or [])}
    use_groups = len(groups - {""}) >= 2
    names: list[str] = []
    for part in parts:
        names.extend(part.face_groups if use_groups and part.face_groups is not None else [part.name] * len(part.faces))
    return names


def choose_labels(parts: list[MeshPart], path: Path, mode: str) -> str:
    """The label source `auto` resolves to for these parts (see module doc)."""
    if mode != "auto":
        return mode
    if path.with_suffix(".json").is_file():
        return "sidecar"
    if all(p.face_labels is not None for p in parts):
        return "properties"
    if any(_face_names(parts)):
        return "names"
    return "components"


def _labels_sidecar(parts: list[MeshPart], path: Path) -> tuple[np.ndarray, dict[int, SceneObject], int]:
    objects = read_sidecar(path)
    if all(p.face_labels is not None for p in parts):
        labels = np.concatenate([p.face_labels for p in parts])  # type: ignore[misc]
    else:
        labels = np.array([name_label(n) for n in _face_names(parts)], np.int64)
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
    names = _face_names(parts)
    distinct = sorted({n for n in names if n})
    if not distinct:
        raise SceneError(f"{path}: labels: names, but the file names no group, material or node; use labels: components")
    ids = {name: index for index, name in enumerate(distinct, start=1)}
    labels = np.array([ids.get(n, 0) for n in names], np.int64)
    objects = {i: SceneObject(i, name, _name_category(name)) for name, i in ids.items()}
    return labels, objects, 0


def _labels_components(parts: list[MeshPart], path: Path) -> tuple[np.ndarray, dict[int, SceneObject], int]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    vertices, faces = _merged_geometry(parts)
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


def _merged_geometry(parts: list[MeshPart]) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    vertices = np.concatenate([p.vertices for p in parts]).astype(np.float32)
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)])
    return vertices, faces


def palette_color(object_id: int) -> np.ndarray:
    """A stable, distinct-looking colour per object id (golden-ratio hue steps)."""
    import colorsys

    hue = (object_id * 0.618033988749895) % 1.0
    return np.round(np.array(colorsys.hsv_to_rgb(hue, 0.55, 0.9)) * 255).astype(np.uint8)


def _vertex_colors(parts: list[MeshPart], face_ids: np.ndarray) -> np.ndarray:
    """(V, 3) colours: the part's vertex or base colour, a palette colour per object where none."""
    blocks, start = [], 0
    for part in parts:
        if part.vertex_colors is not None:
            block = part.vertex_colors
        elif part.base_color is not None:
            block = np.tile(part.base_color, (len(part.vertices), 1))
        elif part.texture is not None:
            block = np.tile(part.texture.reshape(-1, 3).mean(axis=0).astype(np.uint8), (len(part.vertices), 1))
        else:
            block = np.full((len(part.vertices), 3), 160, np.uint8)
            ids = face_ids[start: start + len(part.faces)]
            for object_id in np.unique(ids):
                block[part.faces[ids == object_id].reshape(-1)] = palette_color(int(object_id))
        blocks.append(block.astype(np.uint8))
        start += len(part.faces)
    return np.concatenate(blocks)


def _textured(parts: list[MeshPart], vertex_colors: np.ndarray, faces: np.ndarray) -> dict:
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


def read_labelled_mesh(path: Path, up_axis: str = "y", labels: str = "auto") -> Scene:
    """Read a mesh file as a labelled Scene (see module doc); raises SceneError naming the file."""
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
    vertices, faces = _merged_geometry(parts)
    appearance = {"vertex_colors": _vertex_colors(parts, face_ids)}
    if any(p.texture is not None for p in parts):
        appearance = _textured(parts, appearance["vertex_colors"], faces)
    if not any(p.coloured for p in parts):
        LOG.warning("%s: no vertex colours, materials or textures; painting each object a palette colour", path)
    keep = _non_degenerate(vertices, faces)
    dropped = int((~keep).sum()) + short_faces
    if dropped:
        LOG.warning("%s: dropped %d degenerate faces (fewer than 3 corners or zero area)", path, dropped)
        faces, face_ids = faces[keep], face_ids[keep]
        if appearance.get("face_uvs") is not None:
            appearance["face_uvs"], appearance["face_material"] = appearance["face_uvs"][keep], appearance["face_material"][keep]
    present = {int(i) for i in np.unique(face_ids) if i > 0}
    transform = up_axis_transform(up_axis)
    LOG.info("%s: %d triangles, %d objects from labels: %s", path, len(faces), len(present), mode)
    return Scene(
        scene_id=path.stem, vertices=to_world(vertices, transform), faces=faces.astype(np.int32),
        face_object_ids=face_ids.astype(np.uint32), objects={i: o for i, o in sorted(objects.items()) if i in present},
        to_world=transform, source="mesh", path=str(path), unknown_colors=int(unknown),
        degenerate_faces=dropped, **appearance,
    )


def _non_degenerate(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) True for faces with three distinct corners and non-zero area."""
    v = vertices.astype(np.float64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    distinct = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return distinct & (area > 0)
