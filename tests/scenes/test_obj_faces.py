"""OBJ face lines the `meshes:` source refuses in one line naming the file and the line (issue 30): corners
that are no vertex (0, past the end, 10^30: trimesh raised "OverflowError: Python int too large to convert
to C long" or took 0 as the last vertex) and corners whose texture index is not a number."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.scenes.meshes import read_labelled_mesh
from pipeline.scenes.scene import SceneError

VERTICES = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"


@pytest.mark.parametrize("face, where", [
    ("f 1 2 1000000000000000000000000000000", ":5: face corner '1000000000"),
    ("f 0 1 2", ":5: face corner 0 is no vertex"),
    ("f 1 2 9", ":5: face corner '9' is not a vertex index (1..4 or -4..-1)"),
    ("f 1 2 -9", ":5: face corner '-9' is not a vertex index"),
    ("f 1/x 2 3", ":5: face corner '1/x' is not a vertex index"),
], ids=["10^30", "zero", "past_the_end", "relative_past_the_start", "texture_not_a_number"])
def test_a_face_corner_that_is_no_vertex_is_named_by_its_line(tmp_path: Path, face: str, where: str) -> None:
    path = tmp_path / "room.obj"
    path.write_text(VERTICES + face + "\n", encoding="utf-8")
    with pytest.raises(SceneError) as caught:
        read_labelled_mesh(path)
    message = str(caught.value)
    assert message.startswith(f"{path}{where}") and "\n" not in message and message.endswith("fix the line"), message


def test_relative_and_textured_corners_are_read(tmp_path: Path) -> None:
    path = tmp_path / "room.obj"
    path.write_text(VERTICES + "vt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1\nf -4//1 -2//1 -1//1\n", encoding="utf-8")
    assert read_labelled_mesh(path).triangle_count == 2
