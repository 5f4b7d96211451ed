"""GLB (binary glTF) triangle meshes: read through trimesh into merged arrays, and a deterministic writer.

Reading (`read_glb`, what the HM3DSem reader uses): every node of the default scene with its transform,
all primitives merged, vertex colours (COLOR_0), TEXCOORD_0 with base-colour textures, or the
material's base colour. The header and chunk sizes are checked first, so a broken file raises
`SceneError` naming the file ("corrupt GLB"). The writer emits one node, one mesh and one primitive with
sorted JSON keys and no timestamps, so the same arrays always give the same bytes.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from pipeline.scenes.scene import SceneError
from pipeline.scenes.trimesh_reader import GLB_MAGIC as MAGIC
from pipeline.scenes.trimesh_reader import MeshPart, read_parts

JSON_CHUNK = 0x4E4F534A
BIN_CHUNK = 0x004E4942
TRIANGLES = 4
WHITE = np.array([255, 255, 255], np.uint8)


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
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None
    vertex_uvs: np.ndarray | None
    vertex_texture: np.ndarray
    base_colors: np.ndarray
    textures: list[np.ndarray] = field(default_factory=list)


def read_glb(path: str | Path) -> GlbMesh:
    """Read every triangle primitive of a GLB file (see module doc); raises SceneError when unusable."""
    path = Path(path)
    if path.suffix.lower() != ".glb":
        raise SceneError(f"{path}: expected a .glb file")
    parts, _ = read_parts(path)
    return merge_parts(parts)


def merge_parts(parts: list[MeshPart]) -> GlbMesh:
    """The placed parts of a file as one GlbMesh (UVs back in glTF convention: v runs down the image)."""
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    textures: list[np.ndarray] = []
    uvs, texture_of_vertex = [], []
    for part in parts:
        textured = part.texture is not None and part.uvs is not None
        texture_of_vertex.append(np.full(len(part.vertices), len(textures) if textured else -1, np.int32))
        if textured:
            textures.append(part.texture)  # type: ignore[arg-type]
            flipped = part.uvs.astype(np.float32).copy()  # type: ignore[union-attr]
            flipped[:, 1] = 1.0 - flipped[:, 1]
            uvs.append(flipped)
        else:
            uvs.append(np.zeros((len(part.vertices), 2), np.float32))
    return GlbMesh(
        vertices=np.concatenate([p.vertices for p in parts]).astype(np.float32),
        faces=np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)]),
        vertex_colors=(np.concatenate([p.vertex_colors for p in parts])  # type: ignore[misc]
                       if all(p.vertex_colors is not None for p in parts) else None),
        vertex_uvs=np.concatenate(uvs) if textures else None,
        vertex_texture=np.concatenate(texture_of_vertex),
        base_colors=np.concatenate([np.tile(p.base_color if p.base_color is not None else WHITE, (len(p.vertices), 1))
                                    for p in parts]).astype(np.uint8),
        textures=textures,
    )


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
