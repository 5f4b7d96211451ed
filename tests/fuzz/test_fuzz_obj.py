"""Fuzz tests of the OBJ + MTL reading (pipeline/scenes/trimesh_reader.py under the `meshes:` source):
valid files read back to the triangles written; broken ones give a scene or the project's one-line
error naming the file.

Valid files: vertices, polygons of 3 to 6 corners (absolute and relative indices), `o` / `g` groups and
`usemtl` materials whose MTL gives each a `Kd` colour. Broken ones: truncated, a line repeated, an index
or a number overflowed (0, past the end, 10^30, 1e400, nan), `mtllib` nested (the OBJ naming itself, an
MTL naming an image that is not one), NUL bytes and invalid UTF-8 in either file.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from pipeline.scenes.meshes import read_labelled_mesh
from pipeline.scenes.scene import SceneError
from pipeline.scenes.trimesh_reader import read_parts
from tests.fuzz.outcome import result_or_one_line_error

NAMES = st.sampled_from(["floor", "chair_1", "table.001", "wall", "lamp"])


@st.composite
def obj_files(draw: st.DrawFn) -> dict:
    """A valid OBJ: vertices, then blocks of polygons each under an optional group and material."""
    coordinate = st.floats(-50, 50, allow_nan=False, width=32)
    vertices = draw(st.lists(st.tuples(coordinate, coordinate, coordinate), min_size=3, max_size=12))
    blocks = []
    for _ in range(draw(st.integers(1, 4))):
        polygons = draw(st.lists(st.lists(st.integers(0, len(vertices) - 1), min_size=3, max_size=6), min_size=1, max_size=5))
        blocks.append({"group": draw(st.none() | NAMES), "material": draw(st.none() | NAMES), "polygons": polygons,
                       "relative": draw(st.booleans())})
    return {"vertices": vertices, "blocks": blocks}


def _write(folder: Path, obj: dict) -> Path:
    materials = sorted({b["material"] for b in obj["blocks"] if b["material"]})
    lines = ["mtllib scene.mtl"] if materials else []
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in obj["vertices"]]
    count = len(obj["vertices"])
    for block in obj["blocks"]:
        lines += [f"g {block['group']}"] if block["group"] else []
        lines += [f"usemtl {block['material']}"] if block["material"] else []
        for polygon in block["polygons"]:
            lines.append("f " + " ".join(str(i - count if block["relative"] else i + 1) for i in polygon))
    (folder / "scene.mtl").write_text("".join(f"newmtl {m}\nKd 0.5 0.25 0.75\n" for m in materials), encoding="utf-8")
    path = folder / "scene.obj"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _canonical(triangle: list[tuple[float, ...]]) -> tuple:
    """A triangle as the least of its rotations (a fan's diagonal may start at another corner)."""
    return min(tuple(triangle[i:] + triangle[:i]) for i in range(3))


@given(obj_files())
def test_a_valid_obj_reads_back_to_the_triangles_written(obj: dict) -> None:
    with tempfile.TemporaryDirectory() as folder:
        parts, short = read_parts(_write(Path(folder), obj))
    corners = [tuple(float(c) for c in v) for v in obj["vertices"]]
    written = sorted(_canonical([corners[p[0]], corners[p[i]], corners[p[i + 1]]])
                     for block in obj["blocks"] for p in block["polygons"] for i in range(1, len(p) - 1))
    read = sorted(_canonical([tuple(map(float, part.vertices[i])) for i in face]) for part in parts for face in part.faces)
    assert read == written and short == 0
    materials = {b["material"] for b in obj["blocks"] if b["material"]}
    assert {part.name for part in parts} - {""} <= materials


@st.composite
def broken(draw: st.DrawFn, obj: bytes, mtl: bytes) -> tuple[bytes, bytes]:
    """The OBJ and MTL with one defect of the kinds published and hostile files show."""
    kind = draw(st.sampled_from(["truncate", "repeat", "overflow", "nest", "nul", "utf8", "mtl"]))
    lines = obj.split(b"\n")
    if kind == "truncate":
        return obj[:draw(st.integers(0, len(obj)))], mtl
    if kind == "repeat":
        line = draw(st.integers(0, len(lines) - 1))
        return b"\n".join(lines[:line] + [lines[line]] * draw(st.integers(2, 4)) + lines[line + 1:]), mtl
    if kind == "overflow":
        line = draw(st.integers(0, len(lines) - 1))
        words = lines[line].split() or [b"f"]
        value = draw(st.sampled_from([b"0", b"99", b"-99", b"1" + b"0" * 30, b"1e400", b"nan", b"-inf", b"1/2/3/4", b"//"]))
        words[draw(st.integers(0, len(words) - 1))] = value
        lines[line] = b" ".join(words)
        return b"\n".join(lines), mtl
    if kind == "nest":
        nested = draw(st.sampled_from([b"mtllib scene.obj", b"mtllib scene.mtl scene.mtl", b"mtllib ../scene.mtl",
                                       b"call scene.obj", b"usemtl"]))
        return nested + b"\n" + obj, mtl
    if kind in ("nul", "utf8"):
        bad = b"\x00" if kind == "nul" else b"\xff\xfe\xc3"
        if draw(st.booleans()):
            where = draw(st.integers(0, len(obj)))
            return obj[:where] + bad + obj[where:], mtl
        where = draw(st.integers(0, len(mtl)))
        return obj, mtl[:where] + bad + mtl[where:]
    defect = draw(st.sampled_from([b"Kd x y z", b"Kd 1e400 nan -1", b"map_Kd scene.obj", b"map_Kd missing.png",
                                   b"newmtl", b"d nan", b"Ka 1", b"map_Kd ../../../etc/passwd"]))
    return obj, mtl + b"newmtl " + (mtl.split()[1] if len(mtl.split()) > 1 else b"x") + b"\n" + defect + b"\n"


@given(st.data(), obj_files())
def test_a_broken_obj_gives_a_scene_or_one_line_naming_the_file(data: st.DataObject, obj: dict) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = _write(Path(folder), obj)
        mtl = path.with_suffix(".mtl")
        obj_bytes, mtl_bytes = data.draw(broken(path.read_bytes(), mtl.read_bytes()))
        path.write_bytes(obj_bytes)
        mtl.write_bytes(mtl_bytes)
        result_or_one_line_error(lambda: read_labelled_mesh(path), SceneError, (str(path), str(mtl)))
