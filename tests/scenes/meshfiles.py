"""Held-out style mesh files the tests build themselves: what a researcher brings from another tool.

Each writer returns the file path and the objects it should yield. Sizes are in metres, +Y up.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

BOX_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
BOX_FACES = np.array([[0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3], [0, 1, 3], [0, 3, 2],
                      [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6]])
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])


def box(low: tuple[float, float, float], high: tuple[float, float, float]) -> np.ndarray:
    """The 8 corners of an axis-aligned box (faces: BOX_FACES)."""
    return np.asarray(low) + BOX_CORNERS * (np.asarray(high) - np.asarray(low))


def floor_quad(size: float, height: float = 0.0) -> np.ndarray:
    """A square of `size` metres at `height`, corners counter-clockwise seen from above."""
    return np.array([[0, height, 0], [0, height, size], [size, height, size], [size, height, 0]], np.float64)


def write_obj_with_materials(folder: Path) -> tuple[Path, dict[str, int]]:
    """An OBJ + MTL: floor, chair and table by `usemtl` with Kd colours, a rug textured by `map_Kd`.

    No `o` / `g` names, no labels, no sidecar: each material is one object. Returns the path and
    the expected raw name -> mpcat40 index.
    """
    checker = np.zeros((8, 8, 3), np.uint8)
    checker[::2, ::2] = checker[1::2, 1::2] = (20, 200, 40)  # green squares on black (RGB)
    cv2.imwrite(str(folder / "rug.png"), cv2.cvtColor(checker, cv2.COLOR_RGB2BGR))
    (folder / "room.mtl").write_text(
        "newmtl floor\nKd 0.55 0.45 0.35\n\nnewmtl chair\nKd 0.9 0.1 0.1\n\n"
        "newmtl table\nKd 0.1 0.2 0.9\n\nnewmtl rug\nKd 1 1 1\nmap_Kd rug.png\n", encoding="utf-8")
    lines = ["mtllib room.mtl"]
    offset, uv_offset = 1, 1

    def emit(material: str, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray | None = None) -> None:
        nonlocal offset, uv_offset
        lines.extend(f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in vertices)
        if uvs is not None:
            lines.extend(f"vt {u:.4f} {v:.4f}" for u, v in uvs)
        lines.append(f"usemtl {material}")
        for face in faces:
            lines.append("f " + " ".join(f"{i + offset}/{i + uv_offset}" if uvs is not None else str(i + offset) for i in face))
        offset += len(vertices)
        uv_offset += 0 if uvs is None else len(uvs)

    emit("floor", floor_quad(4.0), QUAD_FACES)
    emit("chair", box((0.5, 0, 0.5), (1.0, 0.5, 1.0)), BOX_FACES)
    emit("table", box((2.0, 0, 2.0), (3.2, 0.8, 3.0)), BOX_FACES)
    emit("rug", floor_quad(1.0, 0.01) + [2.5, 0, 0.3], QUAD_FACES, np.array([[0, 0], [0, 1], [1, 1], [1, 0]]))
    path = folder / "room.obj"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path, {"floor": 2, "chair": 3, "table": 5, "rug": 2}


def write_ply_with_labels(folder: Path) -> tuple[Path, int]:
    """A binary-free ASCII PLY: a floor and two boxes, per-vertex RGB and a per-vertex `object_id`."""
    parts = [(floor_quad(4.0), QUAD_FACES, (150, 140, 120), 10),
             (box((0.5, 0, 0.5), (1.5, 0.6, 1.2)), BOX_FACES, (200, 30, 30), 11),
             (box((2.5, 0, 2.5), (3.0, 1.8, 3.5)), BOX_FACES, (30, 30, 200), 12)]
    vertex_lines, face_lines, offset = [], [], 0
    for vertices, faces, color, label in parts:
        vertex_lines.extend(f"{x} {y} {z} {color[0]} {color[1]} {color[2]} {label}" for x, y, z in vertices)
        face_lines.extend("3 " + " ".join(str(i) for i in face) for face in faces + offset)
        offset += len(vertices)
    header = ["ply", "format ascii 1.0", f"element vertex {offset}", "property float x", "property float y",
              "property float z", "property uchar red", "property uchar green", "property uchar blue",
              "property int object_id", f"element face {len(face_lines)}", "property list uchar int vertex_indices",
              "end_header"]
    path = folder / "scan.ply"
    path.write_text("\n".join(header + vertex_lines + face_lines) + "\n", encoding="ascii")
    return path, len(parts)


def write_gltf_scene_graph(folder: Path) -> tuple[Path, dict[str, np.ndarray]]:
    """A .gltf (JSON + .bin) whose nodes place one shared cushion mesh twice under a translated sofa.

    Returns the path and each node's expected world-space bounding-box minimum.
    """
    import trimesh

    scene = trimesh.Scene()

    def colored(vertices: np.ndarray, faces: np.ndarray, rgba: tuple[int, int, int, int]) -> trimesh.Trimesh:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        mesh.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(baseColorFactor=rgba))
        return mesh

    scene.add_geometry(colored(floor_quad(4.0), QUAD_FACES, (160, 150, 130, 255)), node_name="floor", geom_name="floor_mesh")
    sofa = trimesh.transformations.translation_matrix([1.0, 0.0, 2.0])
    scene.add_geometry(colored(box((0, 0, 0), (2.0, 0.4, 0.8)), BOX_FACES, (40, 120, 40, 255)), node_name="sofa",
                       geom_name="sofa_mesh", transform=sofa)
    cushion = colored(box((0, 0, 0), (0.5, 0.2, 0.5)), BOX_FACES, (220, 180, 20, 255))
    for name, x in (("cushion_1", 0.2), ("cushion_2", 1.2)):
        scene.add_geometry(cushion, node_name=name, geom_name="cushion_mesh", parent_node_name="sofa",
                           transform=trimesh.transformations.translation_matrix([x, 0.4, 0.1]))
    for name, data in scene.export(file_type="gltf").items():
        (folder / name).write_bytes(data if isinstance(data, bytes) else str(data).encode("utf-8"))
    expected = {"floor": np.zeros(3), "sofa": np.array([1.0, 0.0, 2.0]),
                "cushion_1": np.array([1.2, 0.4, 2.1]), "cushion_2": np.array([2.2, 0.4, 2.1])}
    return folder / "model.gltf", expected


def write_obj_with_degenerate_faces(folder: Path) -> tuple[Path, int]:
    """An OBJ with a good quad and three bad faces (2 corners, a repeated corner, collinear corners)."""
    text = ("v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 2 0 0\n"
            "g floor\nf 1 4 3\nf 1 3 2\n"
            "f 1 2\n"  # fewer than 3 corners
            "f 1 1 3\n"  # a corner twice
            "f 1 2 5\n")  # three corners on one line: zero area
    path = folder / "broken.obj"
    path.write_text(text, encoding="utf-8")
    return path, 3
