"""Mesh files read through trimesh: labels from a sidecar, properties, names or components; colours; bad faces."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.scenes.glb import write_glb
from pipeline.scenes.meshes import read_labelled_mesh
from pipeline.scenes.scene import SceneError
from pipeline.scenes.sources import load_scene_file
from tests.scenes.meshfiles import BOX_FACES, box, write_obj_with_degenerate_faces

QUAD = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)


def _names(path: Path) -> None:
    path.with_suffix(".json").write_text(json.dumps({"objects": [{"id": 5, "name": "chair"}, {"id": 9, "name": "kitchen cabinet", "region": 2}]}))


def test_obj_groups_label_faces(tmp_path: Path) -> None:
    path = tmp_path / "room.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\no chair_5\nf 1 2 3\ng 9\nf 2 4 3\ng 77\nf 1 2 4\n")
    _names(path)
    scene = load_scene_file(path)
    assert scene.face_object_ids.tolist() == [5, 9, 0]  # 77 is not in the JSON: void
    assert scene.unknown_colors == 1
    assert scene.objects[9].category == 7 and scene.objects[9].region == 2


def test_ply_face_property_labels_faces(tmp_path: Path) -> None:
    path = tmp_path / "room.ply"
    header = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 2\nproperty list uchar int vertex_indices\nproperty int object_id\nend_header\n")
    path.write_text(header + "".join(f"{x} {y} {z}\n" for x, y, z in QUAD) + "3 0 1 2 5\n3 1 3 2 9\n")
    _names(path)
    scene = load_scene_file(path, up_axis="z")
    assert scene.face_object_ids.tolist() == [5, 9]
    assert np.array_equal(scene.vertices[2], [0, 0, -1])


def test_glb_node_name_labels_faces(tmp_path: Path) -> None:
    path = tmp_path / "room.glb"
    write_glb(path, QUAD, np.array([[0, 1, 2], [1, 3, 2]]), None, name="chair_5")
    _names(path)
    assert load_scene_file(path).face_object_ids.tolist() == [5, 5]


def test_missing_sidecar_is_named_when_asked_for(tmp_path: Path) -> None:
    path = tmp_path / "room.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(SceneError, match=r"room\.json: missing"):
        read_labelled_mesh(path, labels="sidecar")


def test_bad_obj_line_is_reported_with_its_number(tmp_path: Path) -> None:
    path = tmp_path / "room.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 x 0\nf 1 2 3\n")
    _names(path)
    with pytest.raises(SceneError, match=r"room\.obj:3:"):
        load_scene_file(path)


def test_sources_list_sorted_refs_and_name_missing_scenes(tmp_path: Path, house_files: Path) -> None:
    from pipeline.config import SceneSources
    from pipeline.scenes.sources import list_scene_refs

    sources = SceneSources.model_validate({"procedural": {"count": 2, "seed": 4},
                                           "hm3dsem": {"root": str(house_files.parent.parent)}})
    refs = list_scene_refs(sources)
    assert [r.scene_id for r in refs] == ["proc-000004", "proc-000005", "proc-000007"]
    assert refs[2].source == "hm3dsem" and refs[2].option("up_axis") == "z"
    wrong = SceneSources.model_validate({"hm3dsem": {"root": str(house_files.parent.parent), "scenes": ["nope"]}})
    with pytest.raises(SceneError, match="no nope.semantic.txt"):
        list_scene_refs(wrong)


def test_a_folder_with_one_trio_loads(house_files: Path) -> None:
    assert load_scene_file(house_files.parent).scene_id == house_files.parent.name


def test_compressed_glb_is_refused_with_the_extension_named(tmp_path: Path) -> None:
    import struct

    document = b'{"asset":{"version":"2.0"},"extensionsRequired":["KHR_draco_mesh_compression"]}  '
    document += b" " * (-len(document) % 4)
    path = tmp_path / "draco.glb"
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 20 + len(document)) + struct.pack("<II", len(document), 0x4E4F534A) + document)
    (tmp_path / "draco.json").write_text('{"objects": []}')
    with pytest.raises(SceneError, match="KHR_draco_mesh_compression"):
        load_scene_file(path)


def test_obj_groups_name_objects_without_a_sidecar(tmp_path: Path) -> None:
    path = tmp_path / "room.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\ng Chair.001\nf 1 2 3\ng kitchen_cabinet_4\nf 2 4 3\n")
    scene = load_scene_file(path)
    names = {o.raw_name: o.category for o in scene.objects.values()}
    assert names == {"Chair.001": 3, "kitchen_cabinet_4": 7}  # suffixes dropped before the raw-name lookup
    assert len(set(scene.face_object_ids.tolist())) == 2


def test_unnamed_mesh_falls_back_to_connected_components(tmp_path: Path) -> None:
    import trimesh

    vertices = np.concatenate([box((0, 0, 0), (1, 1, 1)), box((3, 0, 0), (4, 1, 1))])
    faces = np.concatenate([BOX_FACES, BOX_FACES + 8])
    path = tmp_path / "two.stl"
    path.write_bytes(trimesh.Trimesh(vertices, faces, process=False).export(file_type="stl"))
    scene = load_scene_file(path)  # STL repeats every corner: components still join at shared positions
    assert len(scene.objects) == 2 and {o.category_name for o in scene.objects.values()} == {"misc"}
    left = scene.face_object_ids[scene.vertices[scene.faces[:, 0], 0] < 2]
    assert len(set(left.tolist())) == 1
    # No colour in the file: each object gets its own palette colour, not one flat grey.
    assert len({tuple(c) for c in scene.face_colors().tolist()}) == 2


def test_off_file_reads(tmp_path: Path) -> None:
    path = tmp_path / "tetra.off"
    path.write_text("OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")
    assert load_scene_file(path).triangle_count == 4


def test_degenerate_faces_are_dropped_and_counted(tmp_path: Path) -> None:
    path, bad = write_obj_with_degenerate_faces(tmp_path)
    scene = load_scene_file(path)
    assert scene.degenerate_faces == bad
    assert scene.triangle_count == 2  # the good quad


def test_unknown_labels_option_is_refused(tmp_path: Path) -> None:
    path, _ = write_obj_with_degenerate_faces(tmp_path)
    with pytest.raises(SceneError, match="labels 'colour'"):
        read_labelled_mesh(path, labels="colour")


def test_gltf_object_id_attribute_labels_faces(tmp_path: Path) -> None:
    import trimesh

    mesh = trimesh.Trimesh(QUAD, np.array([[0, 1, 2], [1, 3, 2]]), process=False)
    mesh.vertex_attributes["_OBJECT_ID"] = np.array([5, 9, 5, 9], np.float32)  # faces start at vertices 0 and 1
    path = tmp_path / "labelled.glb"
    path.write_bytes(mesh.export(file_type="glb"))
    scene = load_scene_file(path)
    assert scene.face_object_ids.tolist() == [5, 9]  # a face takes its first corner's label
    assert {o.raw_name for o in scene.objects.values()} == {"object_5", "object_9"}
