"""Our PLY reader: binary little-endian and ASCII, triangles and quads, with and without per-face
properties, and through the `meshes:` source (a box trimesh exported, a Replica-style quad mesh)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.scenes.meshes import read_labelled_mesh
from pipeline.scenes.ply import fan_triangles, read_ply, write_ply
from pipeline.scenes.scene import SceneError

# A 2 x 1 strip of two unit squares in the z = 0 plane, corners counter-clockwise seen from +z.
STRIP = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], np.float32)
QUADS = np.array([[0, 1, 2, 3], [1, 4, 5, 2]])
TRIANGLES = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])


def _columns(colors: bool = True) -> dict[str, np.ndarray]:
    columns = {"x": STRIP[:, 0], "y": STRIP[:, 1], "z": STRIP[:, 2]}
    if colors:
        columns |= {"red": np.arange(6, dtype=np.uint8) * 40, "green": np.full(6, 7, np.uint8), "blue": np.zeros(6, np.uint8)}
    return columns


@pytest.mark.parametrize("binary", [True, False], ids=["binary_little_endian", "ascii"])
@pytest.mark.parametrize("polygons", [QUADS, TRIANGLES], ids=["quads", "triangles"])
@pytest.mark.parametrize("labelled", [True, False], ids=["object_id", "no_face_property"])
def test_read_ply_keeps_face_properties_on_their_faces(tmp_path: Path, binary: bool, polygons: np.ndarray,
                                                       labelled: bool) -> None:
    labels = {"object_id": np.arange(len(polygons), dtype=np.int32) + 5} if labelled else {}
    mesh = read_ply(write_ply(tmp_path / "strip.ply", _columns(), polygons, labels, binary=binary))
    assert np.array_equal(mesh.vertices, STRIP)
    assert mesh.triangles.tolist() == TRIANGLES.tolist()  # quads fan into (0, 1, 2), (0, 2, 3), polygon by polygon
    assert mesh.vertex_colors()[:, 0].tolist() == [0, 40, 80, 120, 160, 200]
    if labelled:
        per_face = [5, 5, 6, 6] if polygons is QUADS else [5, 6, 7, 8]
        assert mesh.per_triangle("object_id").tolist() == per_face
    else:
        assert mesh.face == {}


def test_mixed_polygons_and_short_ones_are_read_row_by_row(tmp_path: Path) -> None:
    path = tmp_path / "mixed.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
                     b"element face 3\nproperty list uchar int vertex_indices\nproperty int label\nend_header\n"
                     b"0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n2 1 0\n4 0 1 2 3 9\n2 4 5 3\n3 1 4 5 8\n")
    mesh = read_ply(path)
    assert mesh.triangles.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5]]
    assert mesh.per_triangle("label").tolist() == [9, 9, 8] and mesh.short_polygons == 1


def test_fan_triangles_of_a_pentagon() -> None:
    triangles, polygon = fan_triangles([np.array([0, 1, 2, 3, 4]), np.array([5, 6, 7])])
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [5, 6, 7]] and polygon.tolist() == [0, 0, 0, 1]


def test_a_truncated_binary_ply_names_the_file_and_element(tmp_path: Path) -> None:
    path = write_ply(tmp_path / "cut.ply", _columns(), QUADS, {"object_id": np.array([1, 2], np.int32)})
    path.write_bytes(path.read_bytes()[:-6])
    with pytest.raises(SceneError, match=r"cut\.ply:face\[1\]: the file ends inside this row.*re-download"):
        read_ply(path)


def test_meshes_source_reads_a_binary_ply_trimesh_exported(tmp_path: Path) -> None:
    import trimesh

    path = tmp_path / "box.ply"
    box = trimesh.creation.box(extents=(4.0, 2.5, 3.0))
    box.visual.face_colors = np.repeat([[200, 30, 30, 255], [30, 30, 200, 255]], 6, axis=0)
    path.write_bytes(box.export(file_type="ply", encoding="binary"))
    assert b"binary_little_endian" in path.read_bytes()[:200]
    scene = read_labelled_mesh(path)
    assert scene.triangle_count == 12 and np.allclose(scene.bounds(), [[-2, -1.25, -1.5], [2, 1.25, 1.5]])
    assert scene.face_colors()[:, 0].tolist() == [200] * 6 + [30] * 6  # face colours follow their faces


def test_meshes_source_reads_a_replica_style_quad_mesh_with_object_ids(tmp_path: Path) -> None:
    path = write_ply(tmp_path / "mesh_semantic.ply", _columns(), QUADS, {"object_id": np.array([3, 9], np.int32)})
    scene = read_labelled_mesh(path, up_axis="z")
    assert scene.face_object_ids.tolist() == [3, 3, 9, 9]  # each quad's two triangles keep its id
    assert sorted(scene.objects) == [3, 9] and scene.objects[9].raw_name == "object_9"
