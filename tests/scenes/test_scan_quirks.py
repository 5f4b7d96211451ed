"""What published scan files hold beyond their documentation (schemas/scan_sources.md, "Quirks"), each
as a case: Replica's class -1 instances, id_to_label and unused ids; instance ids at the uint32 edge;
repeated ids and segments; and malformed metadata failing in one line that names the file."""

from __future__ import annotations

import json
import logging
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.config import Embodiment, Job, PlanConfig
from pipeline.plan.poses import level_camera_rotations
from pipeline.render.renderer import VideoRenderer
from pipeline.runtime.executor import run_unit_locally
from pipeline.scenes.categories import category_of
from pipeline.scenes.hm3dsem import read_semantic_table
from pipeline.scenes.matterport3d import read_house, read_matterport3d
from pipeline.scenes.procedural.house import generate_house
from pipeline.scenes.replica import read_info, read_replica
from pipeline.scenes.scannet import read_labels_tsv, read_scannet
from pipeline.scenes.scene import Scene, SceneError
from pipeline.scenes.shard import SceneSharder
from pipeline.scenes.sources import load_scene_row
from pipeline.store.run_folder import RunFolder
from tests.plan.planning import plan_scene
from tests.scenes.scanfiles import (CLASSLESS_NAMES, classless_objects, object_index, write_matterport3d,
                                    write_published_replica, write_scannet, write_scannetpp)

BIG = 2**32 - 2  # the largest instance id whose object id (id + 1) is a uint32
MISC = 40  # mpcat40's "misc"


@pytest.fixture(scope="module")
def house() -> Scene:
    """A two-room generated house (about 50 k triangles)."""
    return generate_house(seed=7, detail=0.05, min_rooms=2, max_rooms=2)


def _shard(root: Path, sources: dict, tmp: Path) -> RunFolder:
    """Shard every scene of `sources` in one job (in-process units, real Parquet)."""
    job = Job.model_validate({"name": "quirks", "seed": 0, "embodiments": [{"name": "cam"}], "scenes": sources})
    run = RunFolder.create(tmp / "run", job)
    stage = SceneSharder(job)
    for unit in stage.units(run):
        run_unit_locally(stage, run, unit)
    return run


def _render_first_pose(scene: Scene) -> np.ndarray:
    """The panoptic image of the first pose of a walk planned on the scene's floor (160 x 120)."""
    _, paths, _ = plan_scene(scene, plan=PlanConfig(trajectories_per_scene=1, min_frames=20, max_frames=600, max_attempts=200))
    assert paths, "no walk planned on the scan's floor"
    path = paths[0]
    pose = np.eye(4)
    pose[:3, :3] = level_camera_rotations(path.trajectory.headings)[0]
    x, z = path.trajectory.positions[0]
    pose[:3, 3] = [x, path.floor_heights[0] + 1.0, z]
    body = Embodiment.model_validate({"name": "cam", "sensor": {"width": 160, "height": 120}})
    return VideoRenderer(scene, body, exposure=1.0).render(pose).panoptic


# ------------------------------------------------------------------------------------------- Replica


def test_a_published_replica_scene_shards_every_instance_and_renders(house: Scene, tmp_path: Path) -> None:
    """class -1 instances of four names, id_to_label with -2 and unused ids, gravity_dir, node_id and
    oriented boxes: every face-carrying instance is one object (never void), and the scene renders."""
    classless = classless_objects(house)
    write_published_replica(house, tmp_path / "replica", "room_1", classless)
    run = _shard(tmp_path / "replica", {"replica": {"root": str(tmp_path / "replica")}}, tmp_path)
    row = run.read("scenes").to_pylist()[0]
    rows = {r["object_id"]: r for r in run.read("objects").to_pylist()}
    index = object_index(house)
    wanted = {}
    for object_id, obj in house.objects.items():
        name = classless.get(object_id, obj.raw_name)
        category = category_of(name) or MISC if object_id in classless else obj.category
        triangles = int((house.face_object_ids == object_id).sum())
        wanted[index[object_id] + 2] = (name, category, triangles)  # Replica id = index + 1; object id = id + 1
    assert {i: (r["raw_name"], r["mpcat40_index"], r["triangles"]) for i, r in rows.items()} == wanted
    assert {rows[index[i] + 2]["raw_name"] for i in classless} == set(CLASSLESS_NAMES)
    assert row["void_triangles"] == 0 and row["unknown_colors"] == 0  # the unused ids label nothing
    panoptic = _render_first_pose(load_scene_row(row))
    seen = set(np.unique(panoptic).tolist()) - {0}
    assert seen and seen <= set(rows)


def test_replica_id_to_label_is_not_read(house: Scene, tmp_path: Path) -> None:
    """habitat-sim ignores id_to_label (ReplicaSemanticScene.cpp); so do we: a scrambled one changes nothing."""
    semantic = write_published_replica(house, tmp_path, "room_2", classless_objects(house))
    info_path = semantic.with_name("info_semantic.json")
    before = read_info(info_path)
    info = json.loads(info_path.read_text(encoding="utf-8"))
    info["id_to_label"] = [-2, "not a label", None, 10**30]
    info_path.write_text(json.dumps(info), encoding="utf-8")
    assert read_info(info_path) == before


def _replica_info(tmp_path: Path, objects: list, classes: list | None = None) -> Path:
    path = tmp_path / "info_semantic.json"
    path.write_text(json.dumps({"classes": classes if classes is not None else [{"id": 1, "name": "chair"}],
                                "objects": objects}), encoding="utf-8")
    return path


def test_replica_class_minus_one_names_the_instance(tmp_path: Path) -> None:
    path = _replica_info(tmp_path, [{"id": 1, "class_id": -1, "class_name": "undefined"},
                                    {"id": 2, "class_id": -1, "class_name": "picture"},
                                    {"id": 3, "class_id": 1, "class_name": "chair"}])
    objects = read_info(path)
    assert [(o.object_id, o.raw_name, o.category) for o in objects.values()] == [
        (2, "undefined", MISC), (3, "picture", category_of("picture")), (4, "chair", category_of("chair"))]
    assert category_of("picture") not in (0, MISC)  # a class -1 name our table maps keeps its category


def test_a_repeated_replica_id_fails_naming_both_entries(tmp_path: Path) -> None:
    path = _replica_info(tmp_path, [{"id": 5, "class_id": 1}, {"id": 6, "class_id": 1}, {"id": 5, "class_id": -1}])
    with pytest.raises(SceneError, match=r"info_semantic\.json:objects\[2\]\.id: instance 5 is also objects\[0\]"):
        read_info(path)
    path = _replica_info(tmp_path, [{"id": 5, "class_id": 1}], [{"id": 1, "name": "chair"}, {"id": 1, "name": "bed"}])
    with pytest.raises(SceneError, match=r"classes\[1\]\.id: class 1 is also classes\[0\]"):
        read_info(path)


# ------------------------------------------------------------------------------------------- instance ids


@pytest.fixture(scope="module")
def scannet_scene(house: Scene, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ScanNet v2 scene of the house; tests copy it before changing it."""
    return write_scannet(house, tmp_path_factory.mktemp("scannet"), "scene0000_00")


def _copy_scene(mesh: Path, tmp_path: Path) -> Path:
    target = tmp_path / mesh.parent.name
    shutil.copytree(mesh.parent, target)
    return target / mesh.name


def _edit_groups(mesh: Path, edit) -> Path:
    """Apply `edit(groups)` to the scene's aggregation.json; returns its path."""
    path = mesh.with_name(mesh.name.replace("_vh_clean_2.ply", ".aggregation.json"))
    document = json.loads(path.read_text(encoding="utf-8"))
    edit(document["segGroups"])
    path.write_text(json.dumps(document), encoding="utf-8")
    return path


def _floor_group(house: Scene) -> int:
    """The segGroups index (= object index) of the house's largest floor."""
    floors = [i for i, o in house.objects.items() if o.category == 2]
    return object_index(house)[max(floors, key=lambda i: int((house.face_object_ids == i).sum()))]


def test_the_largest_instance_id_keeps_its_value_end_to_end(house: Scene, scannet_scene: Path, tmp_path: Path) -> None:
    """objectId 2^32 - 2 -> object id 2^32 - 1 (the largest uint32): in the objects table, on every floor
    triangle and in the rendered panoptic image."""
    mesh = _copy_scene(scannet_scene, tmp_path / "data" / "scans")
    floor = _floor_group(house)

    def edit(groups: list) -> None:
        groups[floor]["objectId"] = BIG
    _edit_groups(mesh, edit)
    run = _shard(tmp_path / "data", {"scannet": {"root": str(tmp_path / "data")}}, tmp_path)
    rows = {r["object_id"]: r for r in run.read("objects").to_pylist()}
    floor_id = sorted(house.objects)[floor]
    assert rows[BIG + 1]["triangles"] == int((house.face_object_ids == floor_id).sum())
    assert rows[BIG + 1]["raw_name"] == house.objects[floor_id].raw_name
    scene = load_scene_row(run.read("scenes").to_pylist()[0])
    assert int((scene.face_object_ids == BIG + 1).sum()) == rows[BIG + 1]["triangles"]
    assert BIG + 1 in set(np.unique(_render_first_pose(scene)).tolist())  # the floor is seen, id intact


@pytest.mark.parametrize("value", [2**32 - 1, 2**32, 10**30, -1])
def test_an_instance_id_past_uint32_is_refused_in_one_line(house: Scene, scannet_scene: Path, tmp_path: Path,
                                                           value: int) -> None:
    """Before: 2^32 gave the floor panoptic id 1 with no objects row, 2^32 - 1 made it void; 10^30 raised
    OverflowError. Now each is refused naming the file and field."""
    mesh = _copy_scene(scannet_scene, tmp_path)
    floor = _floor_group(house)

    def edit(groups: list) -> None:
        groups[floor]["objectId"] = value
    _edit_groups(mesh, edit)
    with pytest.raises(SceneError, match=rf"aggregation\.json:segGroups\[{floor}\]\.objectId: instance id {value} is "
                                         r"outside 0\.\.4294967294") as caught:
        read_scannet(mesh)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("value", [2**32 - 1, 10**30, -3])
def test_replica_and_matterport_ids_past_uint32_are_refused(tmp_path: Path, value: int) -> None:
    path = _replica_info(tmp_path, [{"id": value, "class_id": 1}])
    with pytest.raises(SceneError, match=r"objects\[0\]\.id: instance id .* is outside 0\.\.4294967294"):
        read_info(path)
    house_path = tmp_path / "x.house"
    house_path.write_text(f"ASCII 1.1\nC 0 1 chair 3 chair 0 0 0 0 0\nO {value} 0 0 0 0 0\nE 0 0 7 1\n", encoding="utf-8")
    with pytest.raises(SceneError, match=r"x\.house:3: O object_index: instance id .* is outside 0\.\.4294967294"):
        read_house(house_path)


def test_the_largest_instance_id_is_accepted_by_replica_and_matterport(tmp_path: Path) -> None:
    assert list(read_info(_replica_info(tmp_path, [{"id": BIG, "class_id": 1}]))) == [BIG + 1]
    house_path = tmp_path / "x.house"
    house_path.write_text(f"ASCII 1.1\nC 0 1 chair 3 chair 0 0 0 0 0\nO {BIG} 0 0 0 0 0\nE 0 {BIG} 7 1\n", encoding="utf-8")
    house = read_house(house_path)
    assert list(house.objects) == [BIG] and house.segment_objects == {7: BIG}


# ------------------------------------------------------------------------------------------- duplicates


def test_a_repeated_object_id_fails_naming_both_groups(house: Scene, scannet_scene: Path, tmp_path: Path) -> None:
    """Before: a repeated objectId renamed the floor after the later group ("toilet") without a word."""
    mesh = _copy_scene(scannet_scene, tmp_path)
    floor = _floor_group(house)
    other = 0 if floor != 0 else 1

    def edit(groups: list) -> None:
        groups[other]["objectId"] = groups[floor]["objectId"]
    _edit_groups(mesh, edit)
    first, second = sorted((floor, other))
    with pytest.raises(SceneError, match=rf"segGroups\[{second}\]\.objectId: \d+ is also segGroups\[{first}\]\.objectId"):
        read_scannet(mesh)


def test_a_segment_in_two_groups_fails_naming_both(house: Scene, scannet_scene: Path, tmp_path: Path) -> None:
    mesh = _copy_scene(scannet_scene, tmp_path)

    def edit(groups: list) -> None:
        groups[3]["segments"].append(groups[1]["segments"][0])
    _edit_groups(mesh, edit)
    with pytest.raises(SceneError, match=r"segGroups\[3\]\.segments: segment \d+ is also in segGroups\[1\]"):
        read_scannet(mesh)


def test_repeated_groups_are_dropped_with_one_warning(house: Scene, scannet_scene: Path, tmp_path: Path,
                                                      caplog: pytest.LogCaptureFixture) -> None:
    """scene0217_00's aggregation lists every object twice under new objectIds (ScanNet/ScanNet issue #51):
    the repeats are dropped, the objects stay as they were."""
    mesh = _copy_scene(scannet_scene, tmp_path)
    expected = read_scannet(mesh)

    def edit(groups: list) -> None:
        groups += [{**g, "objectId": g["objectId"] + len(groups), "id": g["id"] + len(groups)} for g in list(groups)]
    _edit_groups(mesh, edit)
    with caplog.at_level(logging.WARNING):
        scene = read_scannet(mesh)
    assert np.array_equal(scene.face_object_ids, expected.face_object_ids) and scene.objects == expected.objects
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING and "repeat" in r.getMessage()]
    assert len(warnings) == 1 and f"{len(house.objects)} segGroups repeat" in warnings[0].getMessage()


def test_scannetpp_gives_a_shared_segment_to_its_smallest_group(house: Scene, tmp_path: Path,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    """ScanNet++ annotations are multi-label: scannetpp's semantic/transforms/mesh.py keeps, for a vertex in
    several groups, the smallest instance. A segment of the floor also listed by a small object goes to it."""
    mesh = write_scannetpp(house, tmp_path, "pp0a1b2c3d")
    anno = mesh.with_name("segments_anno.json")
    document = json.loads(anno.read_text(encoding="utf-8"))
    groups = document["segGroups"]
    floor = _floor_group(house)
    small = min((k for k in range(len(groups)) if k != floor), key=lambda k: int(
        (house.face_object_ids == sorted(house.objects)[k]).sum()))
    shared = groups[floor]["segments"][0]
    groups[small]["segments"].append(shared)
    anno.write_text(json.dumps(document), encoding="utf-8")
    with caplog.at_level(logging.WARNING):
        scene = read_scannet(mesh)
    index = object_index(house)
    floor_id, small_id = sorted(house.objects)[floor], sorted(house.objects)[small]
    moved = int((scene.face_object_ids == index[small_id] + 1).sum()) - int((house.face_object_ids == small_id).sum())
    assert moved > 0 and moved == int((house.face_object_ids == floor_id).sum()) - int(
        (scene.face_object_ids == index[floor_id] + 1).sum())
    assert sum("smallest group" in r.getMessage() for r in caplog.records) == 1


def _repeat_field(path: Path, kind: str, field: int, copy_from: int, into: int) -> int:
    """Give the `into`-th record of `kind` the `field` of its `copy_from`-th; returns the changed line number."""
    lines = path.read_text(encoding="utf-8").splitlines()
    records = [k for k, line in enumerate(lines) if line.startswith(f"{kind} ")]
    fields = lines[records[into]].split()
    fields[field] = lines[records[copy_from]].split()[field]
    lines[records[into]] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return records[into] + 1


def test_matterport_repeated_records_fail_naming_both_lines(house: Scene, tmp_path: Path) -> None:
    """habitat-sim keeps the last `E` of a segment id (a map) and lists both `O`s; either merges objects."""
    path = write_matterport3d(house, tmp_path, "dupobject00")
    first = _repeat_field(path, "O", 1, 0, 0)  # unchanged: the line number of the first O
    line = _repeat_field(path, "O", 1, 0, 1)
    with pytest.raises(SceneError, match=rf"dupobject00\.house:{line}: object_index 0 is also on line {first}"):
        read_matterport3d(path)
    path = write_matterport3d(house, tmp_path, "dupsegment0")
    first = _repeat_field(path, "E", 3, 0, 0)
    line = _repeat_field(path, "E", 3, 0, 3)
    with pytest.raises(SceneError, match=rf"dupsegment0\.house:{line}: segment id 1000 is also on line {first}"):
        read_matterport3d(path)


def test_hm3dsem_repeated_rows_fail_naming_both_lines(tmp_path: Path) -> None:
    path = tmp_path / "a.semantic.txt"
    path.write_text('HM3D Semantic Annotations\n1,FF0000,"floor",0\n2,00FF00,"chair",0\n1,0000FF,"toilet",1\n')
    with pytest.raises(SceneError, match=r"a\.semantic\.txt:4: instance id 1 is also on line 2"):
        read_semantic_table(path)
    path.write_text('HM3D Semantic Annotations\n1,FF0000,"floor",0\n\n2,00FF00,"chair",0\n3,ff0000,"toilet",1\n')
    with pytest.raises(SceneError, match=r"a\.semantic\.txt:5: colour FF0000 is also on line 2"):
        read_semantic_table(path)


def test_hm3dsem_rows_as_published(tmp_path: Path) -> None:
    """The header, blank lines, quoted names with commas or doubled quotes, and region -1 (habitat-sim's
    HM3DSemanticScene.cpp strips the quotes; csv keeps a comma inside them)."""
    path = tmp_path / "b.semantic.txt"
    path.write_text('HM3D Semantic Annotations\n\n1,0a0B0c,"wall",0\n2,FFFFFF,"table, dining",-1\n'
                    '3,123456,"6"" ruler",2\n')
    assert read_semantic_table(path) == {0x0A0B0C: ("wall", 0), 0xFFFFFF: ("table, dining", -1),
                                         0x123456: ('6" ruler', 2)}


def test_segment_ids_as_strings_or_null_are_read_as_scannet_reads_them(house: Scene, scannet_scene: Path,
                                                                       tmp_path: Path) -> None:
    """ScanNet's Aggregation.h (getUINT) reads a segment id given as a decimal string, and null as no segment."""
    mesh = _copy_scene(scannet_scene, tmp_path)
    expected = read_scannet(mesh)

    def edit(groups: list) -> None:
        for group in groups:
            group["segments"] = [str(s) for s in group["segments"]] + [None]
    _edit_groups(mesh, edit)
    scene = read_scannet(mesh)
    assert np.array_equal(scene.face_object_ids, expected.face_object_ids) and scene.objects == expected.objects


def test_the_hi_res_aggregation_is_not_paired_with_the_annotated_mesh(scannet_scene: Path, tmp_path: Path) -> None:
    """`<scene>_vh_clean.aggregation.json` indexes the hi-res mesh's segments (ScanNet README; CurryYuan/
    InstanceRefer pull request #9): its `segmentsFile` says so, and the reader refuses it beside _vh_clean_2."""
    mesh = _copy_scene(scannet_scene, tmp_path)
    aggregation = _edit_groups(mesh, lambda groups: None)
    document = json.loads(aggregation.read_text(encoding="utf-8"))
    document["segmentsFile"] = "scannet.scene0000_00_vh_clean.segs.json"
    aggregation.unlink()
    aggregation.with_name("scene0000_00_vh_clean.aggregation.json").write_text(json.dumps(document), encoding="utf-8")
    with pytest.raises(SceneError, match=r"scene0000_00_vh_clean\.aggregation\.json:segmentsFile: refers to "
                                         r"'scannet\.scene0000_00_vh_clean\.segs\.json', not scene0000_00_vh_clean_2\.0\.010000"):
        read_scannet(mesh)


def test_a_byte_order_mark_is_read_past(tmp_path: Path) -> None:
    """Files saved by Windows tools start with a UTF-8 byte-order mark; habitat-sim finds its HM3D header
    anywhere in the first line (SemanticScene.cpp, `header.find`). Without a header, the first row stays a row."""
    table = tmp_path / "c.semantic.txt"
    table.write_bytes(b'\xef\xbb\xbf1,FF0000,"floor",0\r\n2,00FF00,"chair",0\r\n')
    assert read_semantic_table(table) == {0xFF0000: ("floor", 0), 0x00FF00: ("chair", 0)}
    info = _replica_info(tmp_path, [{"id": 1, "class_id": 1}])
    info.write_bytes(b"\xef\xbb\xbf" + info.read_bytes())
    assert list(read_info(info)) == [2]


# ------------------------------------------------------------------------------------------- one-line errors


def _scannet_with_aggregation(scannet_scene: Path, tmp_path: Path, text: bytes) -> Path:
    mesh = _copy_scene(scannet_scene, tmp_path)
    mesh.with_name(mesh.name.replace("_vh_clean_2.ply", ".aggregation.json")).write_bytes(text)
    return mesh


@pytest.mark.parametrize("text, message", [
    (b'{"segGroups": [{"objectId": 1000000000000000000000000000000, "label": "x", "segments": [11]}]}',
     r"segGroups\[0\]\.objectId: instance id 1000000000000000000000000000000 is outside"),
    (b'{"segGroups": [{"objectId": 1, "label": "x\x00y", "segments": [11]}]}', r"aggregation\.json:1: not valid JSON"),
    (b'{"segGroups": ' + b"[" * 100000 + b"]" * 100000 + b"}", r"aggregation\.json: JSON nested too deeply"),
    (b'{"segGroups": [{"objectId": "3", "label": "x", "segments": [11]}]}', r"segGroups\[0\]\.objectId: '3' is not an integer"),
    (b'{"segGroups": [{"objectId": 3.5, "label": "x", "segments": [11]}]}', r"segGroups\[0\]\.objectId: 3\.5 is not an integer"),
    (b'{"segGroups": [{"objectId": true, "label": "x", "segments": [11]}]}', r"segGroups\[0\]\.objectId: True is not an integer"),
    (b'{"segGroups": [{"objectId": 1, "label": 7, "segments": [11]}]}', r"segGroups\[0\]\.label: expected a string"),
    (b'{"segGroups": [{"objectId": 1, "label": "x", "segments": [[11]]}]}', r"segGroups\[0\]\.segments\[0\]: \[11\] is not an integer"),
    (b'{"segGroups": [{"objectId": 1, "label": "x", "segments": [1e300]}]}', r"segGroups\[0\]\.segments\[0\]: 1e\+300 is"),
    (b'{"segGroups": [7]}', r"segGroups\[0\]: expected \{objectId, label, segments\}, got int"),
    (b'{"segGroups": [{"objectId": 1, "label": "x", "segments": [11]}]', r"aggregation\.json:1: not valid JSON"),
    (b'\xff\xfe{"segGroups": []}', r"aggregation\.json: not UTF-8 text"),
])
def test_malformed_scannet_metadata_fails_in_one_line(scannet_scene: Path, tmp_path: Path, text: bytes, message: str) -> None:
    mesh = _scannet_with_aggregation(scannet_scene, tmp_path, text)
    with pytest.raises(SceneError, match=message) as caught:
        read_scannet(mesh)
    assert "\n" not in str(caught.value) and str(caught.value).startswith(str(mesh.parent))


@pytest.mark.parametrize("body, message", [
    (b'{"segIndices": [1, 2, 99999999999999999999999]}', r"segIndices\[2\]: 99999999999999999999999 is outside"),
    (b'{"segIndices": [[1, 2], [3, 4]]}', r"segIndices\[0\]: \[1, 2\] is not an integer"),
    (b'{"segIndices": [1.5, 2]}', r"segIndices\[0\]: 1\.5 is not an integer"),
    (b'{"segIndices": [3.0, "x"]}', r"segIndices\[1\]: 'x' is not an integer"),  # an odd entry after a whole float
    (b'{"segIndices": 5}', r"no segIndices list"),
    (b'{"segIndices": [' + b"[" * 50000 + b"]" * 50000 + b"]}", r"JSON nested too deeply"),
])
def test_malformed_segs_fail_in_one_line(scannet_scene: Path, tmp_path: Path, body: bytes, message: str) -> None:
    """Before: shape mismatches and OverflowError surfaced as numpy's or Python's own messages."""
    mesh = _copy_scene(scannet_scene, tmp_path)
    mesh.with_name(mesh.name.replace(".ply", ".0.010000.segs.json")).write_bytes(body)
    with pytest.raises(SceneError, match=message) as caught:
        read_scannet(mesh)
    assert "\n" not in str(caught.value) and "segs.json" in str(caught.value)


HOUSE, INFO = ("y.house", read_house), ("info_semantic.json", read_info)


@pytest.mark.parametrize("file, text, message", [
    (HOUSE, "ASCII 1.1\nC 0 1 chair 99999999999999999999 chair\nO 0 0 0\nE 0 0 7 1\n", r":2: C mpcat40_index: .* is outside 0\.\.41"),
    (HOUSE, "ASCII 1.1\nC 0 1 chair 3 chair\nO 0 99999999999 0\nE 0 0 7 1\n", r":3: O region_index: 99999999999 is outside"),
    (HOUSE, "ASCII 1.1\nC 0 1 chair 3 chair\nO 0 0 0\nE 0 0 7.5 1\n", r":4: cannot read the 'E' record's id"),
    (HOUSE, "ASCII 1.1\nC 0\nO 0 0 0\nE 0 0 7 1\n", r":2: the 'C' record 'C 0' has no category_mapping_name"),
    (HOUSE, "ASCII 1.1\nC 0 1 chair 3 chair\nO 0 0 0\nE 0 -7 7 1\n", r":4: E object_index: instance id -7 is outside 0\.\."),
    (HOUSE, "ASCII 1.0\nH x - 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\n", r":1: an ASCII 1\.0 \.house holds no objects"),
    (INFO, '{"classes": [{"id": 1, "name": "chair"}], "objects": [{"id": 1, "class_id": 10000000000000000000000}]}',
     r":objects\[0\]\.class_id: 10000000000000000000000 is outside"),
    (INFO, '{"classes": [{"id": 1, "name": 3}], "objects": []}', r":classes\[0\]: expected \{id, name\} with a string name"),
    (INFO, '{"classes": [], "objects": [{"id": 1, "class_id": -1, "class_name": ["x"]}]}',
     r":objects\[0\]\.class_name: expected a string"),
    (INFO, '{"classes": [], "objects": [{"class_id": 2}]}', r":objects\[0\]\.id: None is not an integer"),
    (INFO, '[]', r": expected classes \[\{id, name\}\] and objects"),
])
def test_malformed_house_and_replica_info_fail_in_one_line(tmp_path: Path, file: tuple, text: str, message: str) -> None:
    name, read = file
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SceneError, match=re.escape(name) + message) as caught:
        read(path)
    assert "\n" not in str(caught.value)


def test_malformed_label_tables_fail_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "scannetv2-labels.combined.tsv"
    path.write_text("id\traw_category\tmpcat40index\n1\tchair\t3\n2\ttable\t99999\n", encoding="utf-8")
    with pytest.raises(SceneError, match=r"labels\.combined\.tsv:3: mpcat40index '99999' is not an mpcat40 index"):
        read_labels_tsv(path)
    short = tmp_path / "short" / "scannetv2-labels.combined.tsv"
    short.parent.mkdir()
    short.write_text("id\traw_category\tmpcat40index\n1\tchair\t3\n2\n3\tbed\t11\n", encoding="utf-8")
    assert read_labels_tsv(short) == {"chair": 3, "bed": 11}  # a row cut short maps nothing


def test_a_replica_scene_whose_faces_carry_huge_ids_keeps_them_void(house: Scene, tmp_path: Path) -> None:
    """Face ids the json does not list are void and counted, however large (no wrap onto a listed id)."""
    semantic = write_published_replica(house, tmp_path, "room_3", {})
    info_path = semantic.with_name("info_semantic.json")
    info = json.loads(info_path.read_text(encoding="utf-8"))
    info["objects"] = [o for o in info["objects"] if o["id"] != 1]  # faces of id 1 now name no instance
    info_path.write_text(json.dumps(info), encoding="utf-8")
    scene = read_replica(semantic)
    assert 2 not in scene.objects and scene.unknown_colors == 1 and (scene.face_object_ids == 0).sum() > 0
