"""A small, strict reader and writer of binary glTF (GLB) triangle meshes.

Reads what scans and exporters put in GLB files: any node tree (matrix or TRS transforms), several
meshes and primitives, indexed or not, POSITION, COLOR_0 (float or normalised integers, RGB or RGBA),
TEXCOORD_0 and base-colour textures (PNG / JPEG embedded in the binary chunk) or factors. Anything
broken (bad magic, truncated chunks, accessors reaching past the buffer) raises `SceneError` naming the
file. The writer emits one node, one mesh and one primitive with sorted JSON keys and no timestamps,
so the same arrays always give the same bytes.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from pipeline.scenes.scene import SceneError

MAGIC = b"glTF"
JSON_CHUNK = 0x4E4F534A
BIN_CHUNK = 0x004E4942
COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
TRIANGLES = 4
SUPPORTED_EXTENSIONS = frozenset({"KHR_materials_unlit"})  # required extensions we can safely ignore


@dataclass
class GlbMesh:
    """Triangles of a GLB file in the file's frame, all primitives merged.

    Attributes:
        vertices: (V, 3) float32 positions (node transforms applied).
        faces: (F, 3) int64 vertex indices.
        vertex_colors: (V, 3) uint8 COLOR_0 when every primitive has one, else None.
        vertex_uvs: (V, 2) float32 TEXCOORD_0 in glTF convention (v down), zeros where absent, or None.
        vertex_texture: (V,) int32 index into `textures` of the vertex's primitive (-1: untextured).
        base_colors: (V, 3) uint8 the material's base colour factor (white when none).
        textures: decoded RGB images, (H, W, 3) uint8.
        vertex_labels: (V,) int64 instance label per vertex: the custom `_OBJECT_ID` attribute, else the
            trailing integer of the node or mesh name ("chair_12" -> 12), else 0.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None
    vertex_uvs: np.ndarray | None
    vertex_texture: np.ndarray
    base_colors: np.ndarray
    textures: list[np.ndarray] = field(default_factory=list)
    vertex_labels: np.ndarray | None = None


def _corrupt(path: Path, what: str) -> SceneError:
    return SceneError(f"{path}: corrupt GLB ({what}); re-export or re-download the file")


def _chunks(path: Path, data: bytes) -> tuple[dict, bytes]:
    if len(data) < 20 or data[:4] != MAGIC:
        raise _corrupt(path, "no glTF header")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise SceneError(f"{path}: glTF version {version}; only glTF 2.0 GLB files are supported, re-export as glTF 2")
    if length > len(data):
        raise _corrupt(path, f"header says {length} bytes, file has {len(data)}")
    offset, document, binary = 12, None, b""
    while offset + 8 <= length:
        chunk_length, chunk_type = struct.unpack_from("<II", data, offset)
        body = data[offset + 8: offset + 8 + chunk_length]
        if len(body) != chunk_length:
            raise _corrupt(path, "truncated chunk")
        if chunk_type == JSON_CHUNK:
            try:
                document = json.loads(body.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as error:
                raise _corrupt(path, f"JSON chunk: {error}") from None
        elif chunk_type == BIN_CHUNK and not binary:
            binary = body
        offset += 8 + chunk_length
    if not isinstance(document, dict):
        raise _corrupt(path, "no JSON chunk")
    return document, binary


def _view_bytes(path: Path, document: dict, binary: bytes, index: int) -> tuple[bytes, int | None]:
    try:
        view = document["bufferViews"][index]
        if view.get("buffer", 0) != 0:
            raise SceneError(f"{path}: bufferView {index} points at an external buffer; pack the file as one GLB")
        start = view.get("byteOffset", 0)
        end = start + view["byteLength"]
    except (KeyError, IndexError, TypeError):
        raise _corrupt(path, f"bufferView {index}") from None
    if end > len(binary):
        raise _corrupt(path, f"bufferView {index} ends at byte {end} of a {len(binary)}-byte buffer")
    return binary[start:end], view.get("byteStride")


def _accessor(path: Path, document: dict, binary: bytes, index: int) -> np.ndarray:
    """An accessor as an (count, width) array (normalised integers scaled to [0, 1])."""
    try:
        accessor = document["accessors"][index]
        dtype = np.dtype(COMPONENTS[accessor["componentType"]])
        width = WIDTH[accessor["type"]]
        count = int(accessor["count"])
    except (KeyError, IndexError, TypeError):
        raise _corrupt(path, f"accessor {index}") from None
    if "sparse" in accessor:
        raise SceneError(f"{path}: accessor {index} is sparse; re-export without sparse accessors")
    if "bufferView" not in accessor:
        return np.zeros((count, width), dtype)
    data, stride = _view_bytes(path, document, binary, accessor["bufferView"])
    element = dtype.itemsize * width
    stride = stride or element
    start = accessor.get("byteOffset", 0)
    if count and start + stride * (count - 1) + element > len(data):
        raise _corrupt(path, f"accessor {index} reads past its bufferView")
    raw = np.frombuffer(data, np.uint8, count=max(len(data) - start, 0), offset=start) if count else np.zeros(0, np.uint8)
    if stride == element:
        values = raw[: count * element].view(dtype).reshape(count, width)
    else:
        rows = np.lib.stride_tricks.as_strided(raw, (count, element), (stride, 1))
        values = np.ascontiguousarray(rows).view(dtype).reshape(count, width)
    if accessor.get("normalized") and dtype.kind in "iu":
        return values.astype(np.float64) / np.iinfo(dtype).max
    return values


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T  # glTF is column-major
    matrix = np.eye(4)
    if "scale" in node:
        matrix = np.diag([*node["scale"], 1.0]) @ matrix
    if "rotation" in node:
        x, y, z, w = node["rotation"]
        rotation = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        r4 = np.eye(4)
        r4[:3, :3] = rotation
        matrix = r4 @ matrix
    if "translation" in node:
        t4 = np.eye(4)
        t4[:3, 3] = node["translation"]
        matrix = t4 @ matrix
    return matrix


def _mesh_instances(document: dict) -> list[tuple[int, np.ndarray, str]]:
    """(mesh index, world matrix, node name) of every node with a mesh, depth first from the default scene."""
    nodes = document.get("nodes", [])
    scenes = document.get("scenes")
    roots = scenes[document.get("scene", 0)].get("nodes", []) if scenes else list(range(len(nodes)))
    found: list[tuple[int, np.ndarray, str]] = []
    stack = [(r, np.eye(4)) for r in reversed(roots)]
    seen = 0
    while stack:
        index, parent = stack.pop()
        seen += 1
        if seen > 100_000:
            raise ValueError("node graph has a cycle")
        node = nodes[index]
        matrix = parent @ _node_matrix(node)
        if "mesh" in node:
            found.append((node["mesh"], matrix, str(node.get("name", ""))))
        stack.extend((c, matrix) for c in reversed(node.get("children", [])))
    return found


def _texture_image(path: Path, document: dict, binary: bytes, texture_index: int, cache: dict[int, int],
                   images: list[np.ndarray]) -> int:
    if texture_index in cache:
        return cache[texture_index]
    try:
        image_index = document["textures"][texture_index]["source"]
        image = document["images"][image_index]
    except (KeyError, IndexError, TypeError):
        raise _corrupt(path, f"texture {texture_index}") from None
    if "bufferView" not in image:
        raise SceneError(f"{path}: image {image_index} is an external file; pack textures into the GLB")
    data, _ = _view_bytes(path, document, binary, image["bufferView"])
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if decoded is None:
        raise _corrupt(path, f"image {image_index} does not decode")
    cache[texture_index] = len(images)
    images.append(cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB))
    return cache[texture_index]


class _PrimitiveReader:
    """Reads the primitives of one parsed GLB, sharing its decoded textures."""

    def __init__(self, path: Path, document: dict, binary: bytes):
        self.path, self.document, self.binary = path, document, binary
        self.cache: dict[int, int] = {}
        self.images: list[np.ndarray] = []

    def accessor(self, index: int) -> np.ndarray:
        return _accessor(self.path, self.document, self.binary, index)

    def read(self, primitive: dict, matrix: np.ndarray, label: int, where: str) -> dict[str, np.ndarray | None]:
        """Positions (transformed), triangles, colours, UVs, texture, base colour and labels of a primitive."""
        attributes = primitive["attributes"]
        positions = self.accessor(attributes["POSITION"]).astype(np.float64)
        if not np.array_equal(matrix, np.eye(4)):
            positions = positions @ matrix[:3, :3].T + matrix[:3, 3]
        n = len(positions)
        indices = self.accessor(primitive["indices"]).reshape(-1).astype(np.int64) if "indices" in primitive else np.arange(n)
        if len(indices) % 3:
            raise _corrupt(self.path, f"{where}: {len(indices)} indices is not a multiple of 3")
        if len(indices) and (indices.min() < 0 or indices.max() >= n):
            raise _corrupt(self.path, f"{where}: index outside its {n} vertices")
        material = self.document.get("materials", [{}])[primitive["material"]] if "material" in primitive else {}
        pbr = material.get("pbrMetallicRoughness", {})
        factor = np.clip(np.round(np.array(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3]) * 255), 0, 255).astype(np.uint8)
        texture, uvs = -1, None
        if "baseColorTexture" in pbr and "TEXCOORD_0" in attributes:
            texture = _texture_image(self.path, self.document, self.binary, pbr["baseColorTexture"]["index"], self.cache, self.images)
            uvs = self.accessor(attributes["TEXCOORD_0"]).astype(np.float32)[:, :2]
        colors = None
        if "COLOR_0" in attributes:
            values = self.accessor(attributes["COLOR_0"])
            colors = np.clip(np.round(values[:, :3] * (255.0 if values.dtype.kind == "f" else 1.0)), 0, 255).astype(np.uint8)
        labels = (np.rint(self.accessor(attributes["_OBJECT_ID"])[:, 0]).astype(np.int64) if "_OBJECT_ID" in attributes
                  else np.full(n, label, np.int64))
        return {"v": positions.astype(np.float32), "f": indices.reshape(-1, 3), "c": colors, "uv": uvs,
                "tex": np.full(n, texture, np.int32), "base": np.tile(factor, (n, 1)), "label": labels}


def _merge(blocks: list[dict[str, np.ndarray | None]], images: list[np.ndarray]) -> GlbMesh:
    if not blocks:
        return GlbMesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), None, None,
                       np.zeros(0, np.int32), np.zeros((0, 3), np.uint8), [], np.zeros(0, np.int64))
    offsets = np.cumsum([0] + [len(b["v"]) for b in blocks[:-1]])  # type: ignore[arg-type]
    has_colors = all(b["c"] is not None for b in blocks)
    has_uvs = any(b["uv"] is not None for b in blocks)
    return GlbMesh(
        vertices=np.concatenate([b["v"] for b in blocks]),  # type: ignore[misc]
        faces=np.concatenate([b["f"] + o for b, o in zip(blocks, offsets, strict=True)]),  # type: ignore[operator]
        vertex_colors=np.concatenate([b["c"] for b in blocks]) if has_colors else None,  # type: ignore[misc]
        vertex_uvs=np.concatenate([b["uv"] if b["uv"] is not None else np.zeros((len(b["v"]), 2), np.float32)  # type: ignore[arg-type]
                                   for b in blocks]) if has_uvs else None,
        vertex_texture=np.concatenate([b["tex"] for b in blocks]),  # type: ignore[misc]
        base_colors=np.concatenate([b["base"] for b in blocks]),  # type: ignore[misc]
        textures=images,
        vertex_labels=np.concatenate([b["label"] for b in blocks]),  # type: ignore[misc]
    )


def read_glb(path: str | Path) -> GlbMesh:
    """Read every triangle primitive of a GLB file (see module doc); raises SceneError when unusable."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise SceneError(f"{path}: no such file; check the scene folder holds it") from None
    document, binary = _chunks(path, data)
    unsupported = sorted(set(document.get("extensionsRequired", [])) - SUPPORTED_EXTENSIONS)
    if unsupported:
        raise SceneError(f"{path}: needs glTF extension {', '.join(unsupported)}, which this reader does not decode; "
                         "use the uncompressed files (HM3D's plain .glb, not .basis.glb)")
    reader = _PrimitiveReader(path, document, binary)
    blocks = []
    try:
        for mesh_index, matrix, node_name in _mesh_instances(document):
            mesh = document["meshes"][mesh_index]
            label = name_label(node_name) or name_label(str(mesh.get("name", "")))
            for number, primitive in enumerate(mesh["primitives"]):
                if primitive.get("mode", TRIANGLES) == TRIANGLES:
                    blocks.append(reader.read(primitive, matrix, label, f"mesh {mesh_index} primitive {number}"))
    except (KeyError, IndexError, TypeError, ValueError) as error:
        raise _corrupt(path, f"{type(error).__name__}: {error}") from None
    return _merge(blocks, reader.images)


def name_label(name: str) -> int:
    """The instance label a node or group name carries: "12" or "chair_12" -> 12; 0 when none."""
    tail = name.strip().rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else 0


def _pad(data: bytes, filler: bytes) -> bytes:
    return data + filler * (-len(data) % 4)


def write_glb(path: str | Path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None,
              name: str = "mesh", extras: dict | None = None, uvs: np.ndarray | None = None,
              texture: np.ndarray | None = None) -> Path:
    """Write one indexed triangle mesh (float32 positions, uint32 indices, RGBA8 vertex colours) as GLB.

    With `uvs` ((V, 2), glTF convention: v runs down the image) and an RGB `texture`, the mesh gets a
    material whose base colour is that texture, stored as an embedded PNG (how HM3DSem paints objects).

    Deterministic bytes: no timestamps, sorted JSON keys. The file is written next to its final path
    and renamed into place.
    """
    path = Path(path)
    vertices = np.ascontiguousarray(vertices, dtype="<f4")
    faces = np.ascontiguousarray(faces, dtype="<u4")
    blobs = [vertices.tobytes(), faces.tobytes()]
    attributes: dict[str, int] = {"POSITION": 0}
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": len(vertices), "type": "VEC3",
         "min": [float(v) for v in vertices.min(0)], "max": [float(v) for v in vertices.max(0)]},
        {"bufferView": 1, "componentType": 5125, "count": int(faces.size), "type": "SCALAR"},
    ]
    views = [{"buffer": 0, "byteLength": len(blobs[0]), "target": 34962},
             {"buffer": 0, "byteLength": len(blobs[1]), "target": 34963}]
    if colors is not None:
        rgba = np.concatenate([np.asarray(colors, np.uint8)[:, :3], np.full((len(colors), 1), 255, np.uint8)], 1)
        blobs.append(np.ascontiguousarray(rgba).tobytes())
        attributes["COLOR_0"] = 2
        accessors.append({"bufferView": 2, "componentType": 5121, "normalized": True, "count": len(rgba), "type": "VEC4"})
        views.append({"buffer": 0, "byteLength": len(blobs[2]), "target": 34962})
    material: dict | None = None
    if uvs is not None and texture is not None:
        blobs.append(np.ascontiguousarray(uvs, dtype="<f4").tobytes())
        attributes["TEXCOORD_0"] = len(accessors)
        accessors.append({"bufferView": len(views), "componentType": 5126, "count": len(uvs), "type": "VEC2"})
        views.append({"buffer": 0, "byteLength": len(blobs[-1]), "target": 34962})
        ok, png = cv2.imencode(".png", cv2.cvtColor(np.asarray(texture, np.uint8), cv2.COLOR_RGB2BGR))
        if not ok:
            raise SceneError(f"{path}: the texture could not be encoded as PNG; pass an (H, W, 3) uint8 image")
        blobs.append(png.tobytes())
        material = {"image": {"bufferView": len(views), "mimeType": "image/png"}}
        views.append({"buffer": 0, "byteLength": len(blobs[-1])})
    offset = 0
    for view, blob in zip(views, blobs, strict=True):
        view["byteOffset"] = offset
        offset += len(_pad(blob, b"\0"))
    binary = b"".join(_pad(b, b"\0") for b in blobs)
    node: dict = {"mesh": 0, "name": name}
    if extras:
        node["extras"] = extras
    primitive: dict = {"attributes": attributes, "indices": 1, "mode": TRIANGLES}
    document: dict = {
        "asset": {"version": "2.0", "generator": "mvpd-pipeline"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [node],
        "meshes": [{"name": name, "primitives": [primitive]}],
        "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(binary)}],
    }
    if material is not None:
        primitive["material"] = 0
        document["images"] = [material["image"]]
        document["textures"] = [{"source": 0}]
        document["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    text = _pad(json.dumps(document, sort_keys=True, separators=(",", ":")).encode("utf-8"), b" ")
    total = 12 + 8 + len(text) + 8 + len(binary)
    payload = b"".join([MAGIC, struct.pack("<II", 2, total), struct.pack("<II", len(text), JSON_CHUNK), text,
                        struct.pack("<II", len(binary), BIN_CHUNK), binary])
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_bytes(payload)
    temporary.replace(path)
    return path
