"""Fuzz tests of the PLY reader (pipeline/scenes/ply.py): valid files of every format read back to what
was written; broken ones give a mesh or the project's one-line error naming the file.

Valid files: ASCII, binary little- and big-endian; polygons of 0 to 7 corners mixed in one face element
(n-gon exports), extra vertex and face properties of every type. Broken ones: that file truncated, a
header line repeated, an element count overflowed (huge, negative, nan, 10^30), a property turned into
a list of lists' counts (nested), NUL bytes or invalid UTF-8 inserted, bytes flipped.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from pipeline.scenes.meshes import read_labelled_mesh
from pipeline.scenes.ply import read_ply, write_ply
from pipeline.scenes.scene import SceneError
from tests.fuzz.outcome import result_or_one_line_error

FORMATS = [{"binary": True}, {"binary": True, "big_endian": True}, {"binary": False}]
EXTRA_TYPES = ["i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"]


def _column(draw: st.DrawFn, dtype: str, count: int) -> np.ndarray:
    """`count` values of a numpy type: whole numbers in its range, or finite floats it holds exactly."""
    kind = np.dtype(dtype)
    if kind.kind == "f":
        values = st.floats(allow_nan=False, allow_infinity=False, width=32 if kind.itemsize == 4 else 64)
    else:
        values = st.integers(int(np.iinfo(kind).min), int(np.iinfo(kind).max))
    return np.array(draw(st.lists(values, min_size=count, max_size=count)), dtype=kind)


@st.composite
def ply_meshes(draw: st.DrawFn) -> dict:
    """A valid mesh: vertex columns (x, y, z and extras), polygons of mixed sizes, per-polygon columns, format."""
    vertices = draw(st.integers(1, 12))
    vertex = {axis: _column(draw, "f4", vertices) for axis in "xyz"}
    for name in draw(st.lists(st.sampled_from(["red", "nx", "quality", "object_id"]), unique=True, max_size=2)):
        vertex[name] = _column(draw, draw(st.sampled_from(EXTRA_TYPES)), vertices)
    polygons = draw(st.lists(st.lists(st.integers(0, vertices - 1), max_size=7), max_size=12))
    face = {name: _column(draw, draw(st.sampled_from(EXTRA_TYPES)), len(polygons))
            for name in draw(st.lists(st.sampled_from(["object_id", "segment", "label"]), unique=True, max_size=2))}
    return {"vertex": vertex, "polygons": polygons, "face": face, "format": draw(st.sampled_from(FORMATS))}


def _write(folder: Path, mesh: dict) -> Path:
    return write_ply(folder / "fuzz.ply", mesh["vertex"], [np.array(p, np.int32) for p in mesh["polygons"]],
                     mesh["face"], **mesh["format"])


@given(ply_meshes())
def test_a_valid_ply_reads_back_to_the_arrays_written(mesh: dict) -> None:
    with tempfile.TemporaryDirectory() as folder:
        read = read_ply(_write(Path(folder), mesh))
    fans = [(index, [p[0], p[i], p[i + 1]]) for index, p in enumerate(mesh["polygons"]) for i in range(1, len(p) - 1)]
    assert read.triangles.tolist() == [corners for _, corners in fans]
    assert read.triangle_polygon.tolist() == [index for index, _ in fans]
    assert read.short_polygons == sum(len(p) < 3 for p in mesh["polygons"])
    for name, values in mesh["vertex"].items():
        assert read.vertex[name].dtype == values.dtype and np.array_equal(read.vertex[name], values), name
    for name, values in mesh["face"].items():
        assert read.face[name].dtype == values.dtype and np.array_equal(read.face[name], values), name


def _lines(data: bytes) -> tuple[list[bytes], bytes]:
    head, _, body = data.partition(b"end_header\n")
    return head.split(b"\n")[:-1], body


def _join(lines: list[bytes], body: bytes) -> bytes:
    return b"\n".join(lines) + b"\nend_header\n" + body


@st.composite
def broken(draw: st.DrawFn, data: bytes) -> bytes:
    """The file with one defect of the kinds published and hostile files show."""
    lines, body = _lines(data)
    kind = draw(st.sampled_from(["truncate", "repeat", "count", "nest", "nul", "utf8", "flip", "end_header", "types"]))
    if kind == "truncate":
        return data[:draw(st.integers(0, max(len(data) - 1, 0)))]
    if kind == "repeat":
        line = draw(st.integers(1, len(lines) - 1))
        return _join(lines[:line + 1] + [lines[line]] * draw(st.integers(1, 3)) + lines[line + 1:], body)
    if kind == "count":
        elements = [i for i, line in enumerate(lines) if line.startswith(b"element")]
        line = draw(st.sampled_from(elements))
        count = draw(st.sampled_from([b"-1", b"nan", b"1e3", b"4294967296", b"1000000000000", b"1" + b"0" * 30, b"0x10"]))
        lines[line] = b" ".join(lines[line].split()[:2] + [count])
        return _join(lines, body)
    if kind == "nest":  # a scalar property made a list (or a list made a list of lists' counts)
        props = [i for i, line in enumerate(lines) if line.startswith(b"property")]
        line = draw(st.sampled_from(props))
        lines[line] = lines[line].replace(b"property ", b"property list uchar ", 1)
        return _join(lines, body)
    if kind in ("nul", "utf8"):
        where = draw(st.integers(0, len(data)))
        return data[:where] + (b"\x00" if kind == "nul" else b"\xff\xfe\xc3") + data[where:]
    if kind == "flip":
        if not data:
            return data
        where = draw(st.integers(0, len(data) - 1))
        return data[:where] + bytes([data[where] ^ draw(st.integers(1, 255))]) + data[where + 1:]
    if kind == "end_header":
        return data.replace(b"end_header\n", b"end_header", 1)
    # types: a list's items or count given another type (float indices, a float count, a wide count)
    lists = [i for i, line in enumerate(lines) if line.startswith(b"property list")]
    words = lines[lists[0]].split()
    words[draw(st.sampled_from([2, 3]))] = draw(st.sampled_from([b"float", b"double", b"uint", b"char", b"float128"]))
    lines[lists[0]] = b" ".join(words)
    return _join(lines, body)


@given(st.data(), ply_meshes())
def test_a_broken_ply_gives_a_mesh_or_one_line_naming_the_file(data: st.DataObject, mesh: dict) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = _write(Path(folder), mesh)
        path.write_bytes(data.draw(broken(path.read_bytes())))
        read = result_or_one_line_error(lambda: read_ply(path), SceneError, str(path))
        if read is not None:  # whatever it made of the file, the mesh is consistent
            assert read.triangles.shape == (len(read.triangle_polygon), 3)
            assert not len(read.triangles) or 0 <= read.triangles.min() <= read.triangles.max() < len(read.vertex["x"])
        # the `meshes:` source on the same bytes: a scene or one line naming the file
        result_or_one_line_error(lambda: read_labelled_mesh(path), SceneError, str(path))
