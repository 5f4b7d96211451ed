"""Placed geometries of any mesh file trimesh reads, with what labels and colours them.

The one place files are parsed (OBJ + MTL, PLY, GLB / glTF, STL, OFF): `read_parts` gives each node
of the file's scene graph as a `MeshPart` (node transform applied) with its label properties, OBJ
group names, vertex colours, material colour or texture. PLY files go through our own reader
(pipeline/scenes/ply.py), which keeps per-face properties on their faces in binary files and quads. Both the `meshes:` source (meshes.py) and
the HM3DSem reader (glb.py -> hm3dsem.py) build on it. trimesh parses a 1 M-triangle GLB in about a
fifth of the time the project's former hand-written GLB reader took (benchmarks/bench_mesh_readers.py).
Anything unreadable raises SceneError naming the file (and the OBJ line where one is to blame).
"""

from __future__ import annotations

import json
import logging
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.scenes.ply import PlyMesh, read_ply
from pipeline.scenes.scene import SceneError

if TYPE_CHECKING:
    import trimesh

LOG = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")
LABEL_PROPERTIES = ("object_id", "instance", "label", "segment")
GLB_MAGIC = b"glTF"
# What trimesh's loaders raise on files they cannot read (each becomes one line naming the file).
TRIMESH_ERRORS = (ValueError, KeyError, IndexError, TypeError, AttributeError, UnicodeDecodeError, OSError,
                  NotImplementedError, struct.error, OverflowError, ZeroDivisionError)
# Required glTF extensions that trimesh decodes or that change nothing this project reads.
GLTF_EXTENSIONS = frozenset({"KHR_materials_unlit", "KHR_texture_transform", "KHR_materials_pbrSpecularGlossiness"})


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
        missing_library: the `mtllib` file an OBJ names but lacks ("" otherwise); its parts are still
            split and named by `usemtl`, without colours.
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
    missing_library: str = ""

    @property
    def coloured(self) -> bool:
        """True when the file gives this part any colour (vertex colours, a material colour or a texture)."""
        return self.vertex_colors is not None or self.base_color is not None or self.texture is not None


# ------------------------------------------------------------------------------------------ reading


def _load_trimesh(path: Path, obj: ObjFaces | None = None) -> trimesh.Scene:
    import trimesh  # lazily: about 0.5 s to import, and listing scenes never needs it

    if path.suffix.lower() in (".glb", ".gltf"):
        check_gltf(path)
    resolver = None
    if obj is not None and obj.missing_library:
        resolver = _stand_in_materials(path, obj.groups.keys())
    try:
        # One geometry per material keeps OBJ `usemtl` groups apart; process=False keeps vertex order.
        return trimesh.load_scene(str(path), process=False, resolver=resolver)
    except TRIMESH_ERRORS as error:
        where = _first_bad_obj_line(path) if path.suffix.lower() == ".obj" else None
        if where is not None:
            raise SceneError(f"{path}:{where[0]}: {where[1]}; fix the line") from None
        if path.suffix.lower() == ".glb":
            raise _corrupt_glb(path, _one_line(error)) from None
        raise SceneError(f"{path}: trimesh cannot read the mesh ({_one_line(error)}); re-export the file") from None


def _one_line(error: BaseException) -> str:
    """An exception of trimesh's as a short single line (its messages may span lines)."""
    return f"{type(error).__name__}: {' '.join(str(error).split())[:120]}"


def _stand_in_materials(path: Path, names: object) -> object:
    """A trimesh resolver for an OBJ whose MTL file is missing: it serves a stand-in MTL declaring every
    `usemtl` name, so trimesh keeps one named geometry per material (without one it names none)."""
    from trimesh.resolvers import FilePathResolver

    stand_in = "".join(f"newmtl {name}\n" for name in sorted(names) if name).encode("utf-8")  # type: ignore[attr-defined]

    class StandInResolver(FilePathResolver):
        def get(self, name: str) -> bytes:
            try:
                return super().get(name)
            except (FileNotFoundError, ValueError):
                if name.strip().lower().endswith(".mtl"):
                    return stand_in
                raise

    return StandInResolver(str(path))


def _corrupt_glb(path: Path, what: str) -> SceneError:
    return SceneError(f"{path}: corrupt GLB ({what}); re-export or re-download the file")


def check_gltf(path: Path) -> None:
    """Check a GLB's header and chunk sizes and a glTF's JSON, and refuse required extensions that
    trimesh does not decode (it would read such files as empty or wrong)."""
    if path.suffix.lower() == ".glb":
        data = path.read_bytes()
        if len(data) < 20 or data[:4] != GLB_MAGIC:
            raise _corrupt_glb(path, "no glTF header")
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2:
            raise SceneError(f"{path}: glTF version {version}; only glTF 2.0 GLB files are supported, re-export as glTF 2")
        if length > len(data):
            raise _corrupt_glb(path, f"header says {length} bytes, file has {len(data)}")
        offset, document_bytes = 12, b""
        while offset + 8 <= length:
            chunk_length, chunk_type = struct.unpack_from("<II", data, offset)
            if offset + 8 + chunk_length > length:
                raise _corrupt_glb(path, "truncated chunk")
            if chunk_type == 0x4E4F534A and not document_bytes:  # "JSON"
                document_bytes = data[offset + 8: offset + 8 + chunk_length]
            offset += 8 + chunk_length
    else:
        document_bytes = path.read_bytes()
    try:
        document = json.loads(document_bytes.decode("utf-8"))
        required = document.get("extensionsRequired", [])
    except (UnicodeDecodeError, json.JSONDecodeError, AttributeError) as error:
        raise _corrupt_glb(path, f"JSON chunk: {error}") from None
    unsupported = sorted(set(required) - GLTF_EXTENSIONS)
    if unsupported:
        raise SceneError(f"{path}: needs glTF extension {', '.join(unsupported)}, which the reader does not decode; "
                         "use the uncompressed files (HM3D's plain .glb, not .basis.glb)")


def _first_bad_obj_line(path: Path) -> tuple[int, str] | None:
    """(line number, what is wrong) of the first `v` / `vt` / `vn` line whose numbers do not parse, or
    `f` line with a corner that is no vertex: asked only once trimesh has failed, to say where."""
    vertices = sum(1 for line in path.open("rb") if line.split()[:1] == [b"v"])
    with path.open(encoding="utf-8", errors="backslashreplace") as handle:
        for number, line in enumerate(handle, start=1):
            fields = line.split()
            if fields and fields[0] in ("v", "vt", "vn"):
                try:
                    [float(x) for x in fields[1:]]
                except ValueError:
                    return number, f"cannot read {fields[0]!r} line"
            if fields and fields[0] == "f":
                corner = next((c for c in fields[1:] if not _is_corner(c, vertices)), None)
                if corner is not None:
                    return number, (f"face corner {corner[:30]!r} is not a vertex index (1..{vertices} or -{vertices}..-1) "
                                    "with optional /texture/normal indices")
    return None


def _is_corner(text: str, vertices: int) -> bool:
    """`v`, `v/vt`, `v//vn` or `v/vt/vn` with v a vertex of the file."""
    parts = text.split("/")
    try:
        index = int(parts[0])
        [int(p) for p in parts[1:] if p]
    except ValueError:
        return False
    return 1 <= abs(index) <= vertices and len(parts) <= 3


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


def _ply_part(path: Path) -> tuple[MeshPart, int]:
    """A PLY file as one part, read by our own reader (pipeline/scenes/ply.py: binary and ASCII, any
    polygon size, per-face properties kept on their faces), and its count of polygons under 3 corners."""
    mesh = read_ply(path)
    labels = None
    face_key = next((k for k in LABEL_PROPERTIES if k in mesh.face), None)
    vertex_key = next((k for k in LABEL_PROPERTIES if k in mesh.vertex), None)
    if face_key is not None:
        labels = mesh.per_triangle(face_key).astype(np.int64)
    elif vertex_key is not None:
        labels = mesh.vertex[vertex_key].astype(np.int64)[mesh.triangles[:, 0]]
    part = MeshPart("", mesh.vertices.astype(np.float64), mesh.triangles, face_labels=labels,
                    vertex_colors=mesh.vertex_colors(), **_ply_texture(mesh))
    if part.vertex_colors is None and part.texture is None and all(c in mesh.face for c in ("red", "green", "blue")):
        # Per-face colours: every face gets corners of its own, so neighbours of another colour do not blend.
        corners = mesh.triangles.reshape(-1)
        rgb = np.stack([mesh.per_triangle(c) for c in ("red", "green", "blue")], axis=1).astype(np.uint8)
        part.vertices, part.faces = part.vertices[corners], np.arange(len(corners), dtype=np.int64).reshape(-1, 3)
        part.vertex_colors = np.repeat(rgb, 3, axis=0)
    return part, mesh.short_polygons


def _ply_texture(mesh: PlyMesh) -> dict:
    """`texture` and `uvs` of a PLY naming its image in a `comment TextureFile <name>` line, else {}."""
    name = next((c.split(maxsplit=1)[1] for c in mesh.comments if c.startswith("TextureFile") and len(c.split()) > 1), None)
    keys = next((k for k in (("texture_u", "texture_v"), ("s", "t"), ("u", "v")) if all(c in mesh.vertex for c in k)), None)
    if name is None or keys is None or not (mesh.path.parent / name).is_file():
        return {}
    from PIL import Image

    with Image.open(mesh.path.parent / name) as image:
        texture = np.asarray(image.convert("RGB"), np.uint8)
    return {"texture": texture, "uvs": np.stack([mesh.vertex[k] for k in keys], axis=1).astype(np.float32)}


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
    missing_library: str = ""  # the `mtllib` file named but absent beside the OBJ


def _scan_obj_faces(path: Path) -> ObjFaces:
    """Each triangle's group name, in the order trimesh emits them (per material, then file order)."""
    groups: dict[str, list[str]] = {}
    group, material, short, any_group, missing = "", "", 0, False, ""
    with path.open(encoding="utf-8", errors="replace") as handle:
        for number, line in enumerate(handle, start=1):
            head = line[:7]
            if head.startswith("mtllib") and not missing and not (path.parent / line[6:].strip()).is_file():
                missing = line[6:].strip()
            if head.startswith(("f ", "f\t")):
                fields = line.split()
                if "0" in fields or " 0/" in line or "\t0/" in line:  # trimesh would take 0 as the last vertex
                    raise SceneError(f"{path}:{number}: face corner 0 is no vertex (OBJ counts from 1, or back from -1); "
                                     "fix the line")
                corners = len(fields) - 1
                if corners < 3:
                    short += 1
                else:
                    groups.setdefault(material, []).extend([group] * (corners - 2))
            elif head.startswith(("o ", "g ", "o\t", "g\t")):
                group, any_group = line[2:].strip(), True
            elif head.startswith("usemtl"):
                material = line[6:].strip()
    return ObjFaces(groups, short, any_group, missing)


def read_parts(path: Path) -> tuple[list[MeshPart], int]:
    """Every placed geometry of a mesh file (file frame) and the count of faces with < 3 corners."""
    if not path.is_file():
        raise SceneError(f"{path}: no such file; check the scene folder holds it")
    if path.suffix.lower() == ".ply":
        part, short_faces = _ply_part(path)
        if not len(part.faces):
            raise _empty_mesh(path)
        return [part], short_faces
    obj = _scan_obj_faces(path) if path.suffix.lower() == ".obj" else None
    scene = _load_trimesh(path, obj)
    parts, ungrouped = [], []
    for node in scene.graph.nodes_geometry:
        matrix, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        if not hasattr(geometry, "faces") or len(geometry.faces) == 0:
            continue  # point clouds and lines carry no surface
        vertices = np.asarray(geometry.vertices, np.float64)
        if not np.array_equal(matrix, np.eye(4)):
            vertices = vertices @ np.asarray(matrix)[:3, :3].T + np.asarray(matrix)[:3, 3]
        faces = np.asarray(geometry.faces, np.int64)
        labels = _attribute_labels(geometry)
        name = _part_name(path, geometry, str(node), obj)
        part = MeshPart(name, vertices, faces, face_labels=labels, **_appearance(geometry))
        if obj is not None and obj.missing_library:
            part.base_color = None  # the stand-in materials carry no colour of the file's
            part.missing_library = obj.missing_library
        if obj is not None and obj.any_group:
            part.face_groups = _obj_groups_of(obj, geometry, len(faces))
            if part.face_groups is None:
                ungrouped.append(name)
        parts.append(part)
    if ungrouped:
        # One line per file, however many materials: a scan can have hundreds.
        LOG.warning("%s: %d materials have another triangle count than their `f` lines give (e.g. %s); their `o` / `g` "
                    "names are ignored and their material names label them", path, len(ungrouped), ", ".join(map(repr, ungrouped[:3])))
    if not parts:
        raise _empty_mesh(path)
    return parts, (obj.short_faces if obj is not None else 0)


def _empty_mesh(path: Path) -> SceneError:
    return SceneError(f"{path}: the mesh is empty (0 triangles); check the file was exported with geometry")


def _part_name(path: Path, geometry: object, node: str, obj: ObjFaces | None) -> str:
    """The name a part carries: its OBJ material, its glTF node; "" for single-mesh formats."""
    if obj is not None:
        material = getattr(getattr(geometry.visual, "material", None), "name", None)  # type: ignore[attr-defined]
        return str(material) if material and obj.groups.keys() - {""} else ""
    return node if path.suffix.lower() in (".glb", ".gltf") else ""


def _obj_groups_of(obj: ObjFaces, geometry: object, count: int) -> list[str] | None:
    """The `o` / `g` name of each triangle trimesh gave for one material, or None when the file's `f`
    lines do not give the same number of triangles (then material names label it)."""
    material = getattr(getattr(geometry.visual, "material", None), "name", None) or ""  # type: ignore[attr-defined]
    groups = obj.groups.get(str(material)) if len(obj.groups) > 1 else next(iter(obj.groups.values()), [])
    if groups is None or len(groups) != count:
        return None
    return groups
