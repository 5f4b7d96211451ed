"""HM3DSem files: exact round trip, byte-identical output, and one-line errors for bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.scenes.glb import read_glb, write_glb
from pipeline.scenes.hm3dsem import read_hm3dsem, write_hm3dsem
from pipeline.scenes.scene import Scene, SceneError, SceneObject
from pipeline.scenes.sources import load_scene_file


def test_round_trip_keeps_geometry_ids_names_and_categories(small_house: Scene, house_files: Path) -> None:
    read = read_hm3dsem(house_files, up_axis="z")
    assert np.array_equal(read.vertices, small_house.vertices)
    assert np.array_equal(read.faces, small_house.faces)
    assert np.array_equal(read.face_object_ids, small_house.face_object_ids)
    assert np.array_equal(read.vertex_colors, small_house.vertex_colors)
    assert read.objects == small_house.objects  # ids, raw names, categories and regions
    assert read.unknown_colors == 0
    assert read.scene_id == small_house.scene_id
    # The files are +Z up like HM3D's: the reader's to_world turns file +Z into world +Y.
    assert np.array_equal(read.to_world[:3, :3] @ [0, 0, 1], [0, 1, 0])


def test_files_are_stored_z_up(small_house: Scene, house_files: Path) -> None:
    raw = read_glb(house_files.with_name(f"{small_house.scene_id}.glb"))
    assert np.array_equal(raw.vertices[:, 2], small_house.vertices[:, 1])


def test_same_seed_gives_byte_identical_files(small_house: Scene, house_files: Path, tmp_path: Path) -> None:
    from pipeline.scenes.procedural.house import generate_house

    again = write_hm3dsem(generate_house(seed=7, detail=0.05, min_rooms=3, max_rooms=4), tmp_path)
    for suffix in (".glb", ".semantic.glb", ".semantic.txt"):
        name = f"{small_house.scene_id}{suffix}"
        assert (again.parent / name).read_bytes() == (house_files.parent / name).read_bytes(), name


def test_semantic_txt_format(house_files: Path) -> None:
    lines = house_files.read_text().splitlines()
    assert lines[0] == "HM3D Semantic Annotations"
    number, color, name, region = lines[1].split(",")
    assert number == "1" and len(color) == 6 and name.startswith('"') and int(region) >= 0


def _copy(house_files: Path, tmp_path: Path) -> Path:
    target = tmp_path / house_files.parent.name
    shutil.copytree(house_files.parent, target)
    return target / house_files.name


def test_missing_semantic_txt_is_named(house_files: Path, tmp_path: Path) -> None:
    text = _copy(house_files, tmp_path)
    text.unlink()
    with pytest.raises(SceneError, match=r"\.semantic\.txt: missing"):
        read_hm3dsem(text)


def test_corrupt_glb_is_named(house_files: Path, tmp_path: Path) -> None:
    text = _copy(house_files, tmp_path)
    glb = text.with_name(text.name.replace(".semantic.txt", ".glb"))
    glb.write_bytes(glb.read_bytes()[:1000])
    with pytest.raises(SceneError, match=rf"{glb.name}: corrupt GLB"):
        read_hm3dsem(text)
    glb.write_bytes(b"not a glb at all, just text")
    with pytest.raises(SceneError, match="corrupt GLB"):
        read_hm3dsem(text)


def test_malformed_line_is_reported_as_file_and_line(house_files: Path, tmp_path: Path) -> None:
    text = _copy(house_files, tmp_path)
    lines = text.read_text().splitlines()
    lines[3] = '3,NOTHEX,"chair"'
    text.write_text("\n".join(lines) + "\n")
    with pytest.raises(SceneError, match=rf"{text.name}:4: expected"):
        read_hm3dsem(text)


def test_unknown_colours_become_void_and_are_counted(small_house: Scene, house_files: Path, tmp_path: Path) -> None:
    text = _copy(house_files, tmp_path)
    lines = text.read_text().splitlines()
    dropped = [int(line.split(",")[1], 16) for line in lines[1:3]]
    text.write_text("\n".join([lines[0]] + lines[3:]) + "\n")
    read = read_hm3dsem(text)
    assert read.unknown_colors == 2
    was_dropped = np.isin(small_house.face_object_ids, dropped)
    assert (read.face_object_ids[was_dropped] == 0).all()
    assert np.array_equal(read.face_object_ids[~was_dropped], small_house.face_object_ids[~was_dropped])
    assert set(read.objects) == set(small_house.objects) - set(dropped)


def _tiny_trio(folder: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    colors = np.full((len(vertices), 3), 200, np.uint8)
    paint = np.tile(np.array([[0x11, 0x22, 0x33]], np.uint8), (len(vertices), 1))
    write_glb(folder / "bad.glb", vertices, faces, colors)
    write_glb(folder / "bad.semantic.glb", vertices, faces, paint)
    (folder / "bad.semantic.txt").write_text('HM3D Semantic Annotations\n1,112233,"chair",0\n')
    return folder / "bad.semantic.txt"


def test_nan_vertices_are_refused(tmp_path: Path) -> None:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], np.float32)
    text = _tiny_trio(tmp_path, vertices, np.array([[0, 1, 2]]))
    with pytest.raises(SceneError, match=r"bad\.glb: 1 vertices are NaN"):
        read_hm3dsem(text)


def test_empty_mesh_is_refused(tmp_path: Path) -> None:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    text = _tiny_trio(tmp_path, vertices, np.zeros((0, 3), np.int64))
    with pytest.raises(SceneError, match=r"bad\.glb: the mesh is empty"):
        load_scene_file(text)


def test_tiny_trio_reads_with_object_id_as_colour(tmp_path: Path) -> None:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    scene = load_scene_file(_tiny_trio(tmp_path, vertices, np.array([[0, 1, 2]])))
    assert scene.face_object_ids.tolist() == [0x112233]
    assert scene.objects == {0x112233: SceneObject(0x112233, "chair", 3, 0)}
    assert np.array_equal(scene.vertices, [[0, 0, 0], [1, 0, 0], [0, 0, -1]])  # +Z up file -> +Y up world


def test_textured_semantic_mesh_labels_faces_by_texel(tmp_path: Path) -> None:
    """Real HM3DSem semantic meshes paint objects through a texture: each face takes its texel's colour."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    vertices = corners[[0, 1, 2, 1, 3, 2]]  # two triangles with their own vertices
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    texture = np.zeros((2, 2, 3), np.uint8)
    texture[0, 0] = [0x11, 0x22, 0x33]  # top-left texel: the chair
    texture[1, 1] = [0xAA, 0xBB, 0xCC]  # bottom-right texel: a colour missing from the table
    uvs = np.array([[0.1, 0.1], [0.3, 0.1], [0.1, 0.3], [0.7, 0.7], [0.9, 0.9], [0.7, 0.9]], np.float32)
    write_glb(tmp_path / "t.glb", vertices, faces, np.full((6, 3), 200, np.uint8))
    write_glb(tmp_path / "t.semantic.glb", vertices, faces, None, uvs=uvs, texture=texture)
    (tmp_path / "t.semantic.txt").write_text('HM3D Semantic Annotations\n1,112233,"chair",0\n')
    scene = read_hm3dsem(tmp_path / "t.semantic.txt")
    assert scene.face_object_ids.tolist() == [0x112233, 0]
    assert scene.unknown_colors == 1


def test_semantic_table_without_header_keeps_its_first_row(tmp_path: Path) -> None:
    from pipeline.scenes.hm3dsem import read_semantic_table

    path = tmp_path / "x.semantic.txt"
    path.write_text('1,112233,"chair, wooden",4\n2,0000FF,"table",4\n')
    assert read_semantic_table(path) == {0x112233: ("chair, wooden", 4), 0x0000FF: ("table", 4)}
