"""Our PLY reader: binary little- and big-endian and ASCII, triangles, quads and mixed polygon sizes, with
and without per-face properties, through the `meshes:` source (a box trimesh exported, a Replica-style quad
mesh); its memory on mixed faces, and one line naming the file for every malformed file of issue 30."""

from __future__ import annotations

import struct
import tracemalloc
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


# ------------------------------------------------------------------------------- mixed polygon sizes

FORMATS = {"binary_little_endian": {"binary": True}, "binary_big_endian": {"binary": True, "big_endian": True},
           "ascii": {"binary": False}}


def _reference_fans(polygons: list[np.ndarray]) -> tuple[list[list[int]], list[int]]:
    """The old reader's triangulation, polygon by polygon: (0, i, i + 1), and each triangle's polygon."""
    triangles, polygon = [], []
    for index, corners in enumerate(polygons):
        for i in range(1, len(corners) - 1):
            triangles.append([int(corners[0]), int(corners[i]), int(corners[i + 1])])
            polygon.append(index)
    return triangles, polygon


def _mixed_mesh(rng: np.random.Generator, polygons: int, vertices: int = 40) -> tuple[dict, list[np.ndarray], dict]:
    vertex = {"x": rng.random(vertices).astype(np.float32), "y": rng.random(vertices).astype(np.float32),
              "z": rng.random(vertices).astype(np.float64), "red": rng.integers(0, 256, vertices).astype(np.uint8)}
    sizes = rng.choice([0, 1, 2, 3, 3, 4, 4, 5, 8], polygons)
    faces = [rng.integers(0, vertices, size).astype(np.int32) for size in sizes]
    face = {"object_id": rng.integers(-3, 500, polygons).astype(np.int32), "quality": rng.random(polygons).astype(np.float32)}
    return vertex, faces, face


@pytest.mark.parametrize("fmt", FORMATS)
def test_mixed_polygon_sizes_fan_as_the_old_reader_polygon_by_polygon(tmp_path: Path, fmt: str) -> None:
    vertex, faces, face = _mixed_mesh(np.random.default_rng(7), 300)
    mesh = read_ply(write_ply(tmp_path / "mixed.ply", vertex, faces, face, **FORMATS[fmt]))
    triangles, polygon = _reference_fans(faces)
    assert mesh.triangles.tolist() == triangles and mesh.triangle_polygon.tolist() == polygon
    assert mesh.per_triangle("object_id").tolist() == face["object_id"][polygon].tolist()
    assert np.array_equal(mesh.per_triangle("quality"), face["quality"][polygon])
    assert all(np.array_equal(mesh.vertex[name], values) for name, values in vertex.items())
    assert mesh.short_polygons == sum(len(f) < 3 for f in faces) and not mesh.only_triangles


def test_a_big_endian_triangle_mesh_reads_in_native_byte_order(tmp_path: Path) -> None:
    mesh = read_ply(write_ply(tmp_path / "be.ply", _columns(), TRIANGLES, {"label": np.arange(4, dtype=np.int16)},
                              big_endian=True))
    assert mesh.triangles.tolist() == TRIANGLES.tolist() and mesh.triangles.dtype.isnative
    assert mesh.per_triangle("label").tolist() == [0, 1, 2, 3] and np.array_equal(mesh.vertices, STRIP)


def _mixed_face_ply(path: Path, count: int, rng: np.random.Generator) -> Path:
    """A binary PLY of `count` vertices and `count` faces, triangles and quads at random, an int label each
    (written row by row here, so that the test also runs against readers whose writer lacks mixed faces)."""
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {count}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {count}\nproperty list uchar int vertex_indices\nproperty int label\n"
              "end_header\n").encode()
    sizes = rng.choice([3, 4], count)
    indices = rng.integers(0, count, (count, 4)).astype("<i4")
    rows = [bytes([size]) + indices[k, :size].tobytes() + struct.pack("<i", k % 50) for k, size in enumerate(sizes)]
    path.write_bytes(header + rng.random((count, 3)).astype("<f4").tobytes() + b"".join(rows))
    return path


def test_reading_a_mixed_face_file_holds_less_than_twice_its_size_beyond_what_it_returns(tmp_path: Path) -> None:
    """The old row-by-row reader held ~8x the file on mixed triangles and quads (a Python array per row)."""
    path = _mixed_face_ply(tmp_path / "mixed.ply", 150_000, np.random.default_rng(3))  # ~4.7 MB
    read_ply(_mixed_face_ply(tmp_path / "warm.ply", 10, np.random.default_rng(4)))  # load the compiled walks first
    tracemalloc.start()
    try:
        mesh = read_ply(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    returned = sum(a.nbytes for a in [*mesh.vertex.values(), mesh.triangles, mesh.triangle_polygon, *mesh.face.values()])
    assert peak - returned < 2 * path.stat().st_size, (peak, returned, path.stat().st_size)


# ------------------------------------------------------------------------------- malformed files

BINARY = b"ply\nformat binary_little_endian 1.0\n"
ASCII = b"ply\nformat ascii 1.0\n"
VERTEX = b"element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
FACE = b"element face 1\nproperty list uchar int vertex_indices\n"
VERTEX_ROWS = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
FACE_ROW = struct.pack("<B3i", 3, 0, 1, 2)
ASCII_ROWS = b"0 0 0\n1 0 0\n0 1 0\n"

# Each file of issue 30's list (and its neighbours) -> what follows `<file>` in its one-line error.
MALFORMED = {
    "duplicate property": (BINARY + VERTEX.replace(b"float y", b"float x\nproperty float y") + FACE + b"end_header\n",
                           ":5: property 'x' occurs more than once in element 'vertex'"),
    "count nan": (BINARY + VERTEX.replace(b"3", b"nan", 1) + FACE + b"end_header\n", ":3: element 'vertex' count 'nan'"),
    "count -1": (BINARY + VERTEX.replace(b"3", b"-1", 1) + FACE + b"end_header\n", ":3: element 'vertex' count '-1'"),
    "count 10^30": (BINARY + VERTEX.replace(b"3", b"1" + b"0" * 30, 1) + FACE + b"end_header\n" + VERTEX_ROWS,
                    ":3: element 'vertex' count '1000000000"),
    "count 10^12": (BINARY + VERTEX.replace(b"3", b"1000000000000", 1) + FACE + b"end_header\n" + VERTEX_ROWS + FACE_ROW,
                    ":vertex: 1000000000000 rows need at least 12000000000000 bytes"),
    "end_header at the end without newline": (BINARY + VERTEX + FACE + b"end_header", ":vertex: 3 rows need at least 36 bytes"),
    "end_header without newline": (BINARY + VERTEX + FACE + b"end_header" + VERTEX_ROWS + FACE_ROW,
                                   ":9: `end_header` is not followed by a newline"),
    "float list indices": (BINARY + VERTEX + FACE.replace(b"int vertex", b"float vertex") + b"end_header\n" + VERTEX_ROWS
                           + struct.pack("<B3f", 3, 0, 1, 2), ":face.vertex_indices: items of type float32"),
    "ascii fractional index": (ASCII + VERTEX + FACE + b"end_header\n" + ASCII_ROWS + b"3 0.5 1 2\n",
                               ":face.vertex_indices: 0.5 is not a value of type int32"),
    "ascii index 1e30": (ASCII + VERTEX + FACE + b"end_header\n" + ASCII_ROWS + b"3 0 1e30 2\n",
                         ":face.vertex_indices: 1e+30 is not a value of type int32"),
    "list count past the end": (BINARY + VERTEX + FACE + b"end_header\n" + VERTEX_ROWS + struct.pack("<B3i", 200, 0, 1, 2),
                                ":face[0]: the file ends inside this row"),
    "uint list count 2^32 - 1": (BINARY + VERTEX + FACE.replace(b"1\n", b"2\n", 1).replace(b"uchar", b"uint") + b"end_header\n"
                                 + VERTEX_ROWS + struct.pack("<I3iI", 3, 0, 1, 2, 0xFFFFFFFF), ":face[1]: the file ends inside this row"),
    "negative list count": (BINARY + VERTEX + FACE.replace(b"1\n", b"2\n", 1).replace(b"uchar", b"char") + b"end_header\n"
                            + VERTEX_ROWS + struct.pack("<b3ib", 3, 0, 1, 2, -1), ":face[1].vertex_indices: the list count is not"),
    "ascii list count -1": (ASCII + VERTEX + FACE + b"end_header\n" + ASCII_ROWS + b"-1 0 1 2\n",
                            ":face[0].vertex_indices: the list count is not a whole number"),
    "ascii list count nan": (ASCII + VERTEX + FACE + b"end_header\n" + ASCII_ROWS + b"nan 0 1 2\n",
                             ":face[0].vertex_indices: the list count is not a whole number"),
    "truncated binary body": (BINARY + VERTEX + FACE + b"end_header\n" + VERTEX_ROWS[:20], ":vertex: 3 rows need at least 36 bytes"),
    "truncated ascii body": (ASCII + VERTEX + FACE + b"end_header\n" + ASCII_ROWS + b"3 0 1\n", ":face[0]: the file ends before"),
    "blank ascii body": (ASCII + VERTEX + FACE + b"end_header\n  \n", ":vertex: the file ends before"),
    "bad format": (BINARY.replace(b"little", b"middle") + VERTEX + FACE + b"end_header\n", ":2: format 'binary_middle_endian 1.0'"),
    "bad version": (ASCII.replace(b"1.0", b"2.0") + VERTEX + FACE + b"end_header\n", ":2: PLY version '2.0'"),
    "unknown type": (BINARY + VERTEX.replace(b"float x", b"float128 x") + FACE + b"end_header\n", ":4: unknown type 'float128'"),
    "no ply magic": (b"plx\n" + BINARY[4:] + VERTEX + FACE + b"end_header\n", ": not a PLY file"),
    "empty file": (b"", ": not a PLY file"),
    "no end_header": (BINARY + VERTEX + FACE, ": the PLY header has no `end_header` line"),
    "property before element": (BINARY + b"property float w\n" + VERTEX + FACE + b"end_header\n", ":3: a `property` line before"),
    "element twice": (BINARY + VERTEX + VERTEX + FACE + b"end_header\n", ":7: element 'vertex' occurs twice"),
    "ascii NUL byte": (ASCII + VERTEX + FACE + b"end_header\n0 0 0\n1 0\x00 0\n", ":11: '0\\x00' is not a number"),
    "ascii invalid UTF-8": (ASCII + VERTEX + FACE + b"end_header\n0 0 0\n1 \xff 0\n", ":11: '\\xff' is not a number"),
    "index out of range": (ASCII + VERTEX + FACE + b"end_header\n" + ASCII_ROWS + b"3 0 1 7\n",
                           ":face.vertex_indices: index 7 outside 0..2"),
    "vertex_indices not a list": (BINARY + VERTEX + b"element face 1\nproperty int vertex_indices\nend_header\n" + VERTEX_ROWS
                                  + struct.pack("<i", 0), ": the `face` element has no vertex_indices list"),
}


@pytest.mark.parametrize("name", MALFORMED)
def test_a_malformed_ply_fails_in_one_line_naming_the_file_and_where(tmp_path: Path, name: str) -> None:
    data, where = MALFORMED[name]
    path = tmp_path / "scan.ply"
    path.write_bytes(data)
    with pytest.raises(SceneError) as caught:
        read_ply(path)
    message = str(caught.value)
    assert message.startswith(f"{path}{where}") and "\n" not in message and message.count("; ") >= 1, message


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_a_count_of_a_trillion_rows_is_refused_before_anything_is_allocated(tmp_path: Path, fmt: str) -> None:
    path = tmp_path / "hostile.ply"
    rows = VERTEX_ROWS if fmt != "ascii" else ASCII_ROWS
    path.write_bytes(f"ply\nformat {fmt} 1.0\n".encode() + VERTEX + FACE.replace(b"1\n", b"1000000000000\n", 1)
                     + b"end_header\n" + rows + (FACE_ROW if fmt != "ascii" else b"3 0 1 2\n"))
    tracemalloc.start()
    try:
        with pytest.raises(SceneError, match=r"hostile\.ply:face"):
            read_ply(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000
