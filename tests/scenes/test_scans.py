"""Matterport3D, ScanNet v2, ScanNet++ and Replica as downloaded (written here in their own formats):
each shards with the house's objects, names and mpcat40 categories, plans walks on its floor and
renders frames whose panoptic ids reproject; a wrong input fails its scene alone, naming file and field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.config import Embodiment, Job, PlanConfig
from pipeline.plan.poses import level_camera_rotations
from pipeline.render.renderer import VideoRenderer
from pipeline.runtime.executor import UnitFailedError, run_unit_locally
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.procedural.house import generate_house
from pipeline.scenes.scene import Scene
from pipeline.scenes.shard import SceneSharder
from pipeline.scenes.sources import load_scene_row
from tests.plan.planning import plan_scene
from tests.render.test_renderer import _reprojection_agreement
from tests.scenes.scanfiles import (expected_objects, object_index, write_labels_tsv, write_matterport3d,
                                    write_matterport_textured_mesh, write_replica, write_scannet, write_scannetpp)

GOOD = {"matterport3d": ["2t7WUuJeko7", "textured0001"], "scannet": ["scene0000_00", "pp0a1b2c3d"], "replica": ["room_0"]}
# The ScanNet TSV maps "decoration" to misc (40) where our raw-name table says objects (39): the TSV wins.
TSV_NAMES = {"decoration": 40, "chair": 3}


@pytest.fixture(scope="module")
def house() -> Scene:
    """A two-room generated house (about 50 k triangles, its objects named as Matterport names them)."""
    return generate_house(seed=7, detail=0.05, min_rooms=2, max_rooms=2)


def _break(root: Path, house: Scene) -> dict[str, str]:
    """One wrong input per source beside the good scenes; scene id -> the message its unit must fail with."""
    empty = write_matterport3d(house, root / "mp", "emptyhouse0")
    empty.write_text("ASCII 1.1\n", encoding="utf-8")
    nocategory = write_matterport3d(house, root / "mp", "nocategory0")
    lines = nocategory.read_text(encoding="utf-8").splitlines()
    first_object = next(i for i, line in enumerate(lines) if line.startswith("O "))
    fields = lines[first_object].split()
    fields[3] = "999"
    lines[first_object] = " ".join(fields)
    nocategory.write_text("\n".join(lines) + "\n", encoding="utf-8")
    stray = write_scannet(house, root / "scannet", "scene0001_00")
    aggregation = stray.with_name("scene0001_00.aggregation.json")
    document = json.loads(aggregation.read_text(encoding="utf-8"))
    document["segGroups"][2]["segments"].append(987654)
    aggregation.write_text(json.dumps(document), encoding="utf-8")
    short = write_scannet(house, root / "scannet", "scene0002_00")
    segs = short.with_name("scene0002_00_vh_clean_2.0.010000.segs.json")
    document = json.loads(segs.read_text(encoding="utf-8"))
    document["segIndices"] = document["segIndices"][:-5]
    segs.write_text(json.dumps(document), encoding="utf-8")
    unnamed = write_replica(house, root / "replica", "office_9")
    info = unnamed.with_name("info_semantic.json")
    document = json.loads(info.read_text(encoding="utf-8"))
    document["objects"][4]["class_id"] = 4242
    info.write_text(json.dumps(document), encoding="utf-8")
    return {
        "emptyhouse0": r"emptyhouse0\.house: no `O` object or `E` segment records",
        "nocategory0": rf"nocategory0\.house:{first_object + 1}: object \d+ has category_index 999",
        "scene0001_00": r"scene0001_00\.aggregation\.json:segGroups\[2\]\.segments: names segment 987654, which "
                        r"scene0001_00_vh_clean_2\.0\.010000\.segs\.json \(segIndices\) does not hold",
        "scene0002_00": r"segs\.json: segIndices has \d+ entries but the mesh has \d+ vertices",
        "office_9": r"info_semantic\.json:objects\[4\]\.class_id: 4242 is not in classes",
    }


@pytest.fixture(scope="module")
def sharded(house: Scene, tmp_path_factory: pytest.TempPathFactory) -> tuple[RunFolder, dict[str, str]]:
    """One job with the three dataset sources (good and broken scenes), every unit sharded."""
    root = tmp_path_factory.mktemp("datasets")
    write_matterport3d(house, root / "mp", "2t7WUuJeko7")
    write_matterport3d(house, root / "mp", "textured0001")
    write_matterport_textured_mesh(house, root / "mp", "textured0001")
    write_scannet(house, root / "scannet", "scene0000_00")
    write_labels_tsv(root / "scannet", TSV_NAMES)
    write_scannetpp(house, root / "scannet", "pp0a1b2c3d")
    write_replica(house, root / "replica", "room_0")
    failures = _break(root, house)
    job = Job.model_validate({"name": "scans", "seed": 0, "embodiments": [{"name": "cam"}], "scenes": {
        "matterport3d": {"root": str(root / "mp")}, "scannet": {"root": str(root / "scannet")},
        "replica": {"root": str(root / "replica")}}})
    run = RunFolder.create(tmp_path_factory.mktemp("run") / "run", job)
    stage = SceneSharder(job)
    units = stage.units(run)
    assert sorted(u.id for u in units) == sorted([*failures, *(s for scenes in GOOD.values() for s in scenes)])
    for unit in units:
        if unit.id in failures:
            with pytest.raises(UnitFailedError, match=failures[unit.id]) as caught:
                run_unit_locally(stage, run, unit)
            assert "\n" not in str(caught.value)
        else:
            run_unit_locally(stage, run, unit)
    return run, failures


def _scene(run: RunFolder, scene_id: str) -> tuple[dict, Scene]:
    row = next(r for r in run.read("scenes").to_pylist() if r["scene_id"] == scene_id)
    return row, load_scene_row(row)


@pytest.mark.parametrize("source, scene_id", [(s, i) for s, ids in GOOD.items() for i in ids])
def test_each_dataset_shards_with_the_house_objects(sharded: tuple[RunFolder, dict], house: Scene,
                                                    source: str, scene_id: str) -> None:
    run, failures = sharded
    assert {r["scene_id"] for r in run.read("scenes").to_pylist()}.isdisjoint(failures)  # failed alone
    row, scene = _scene(run, scene_id)
    assert row["source"] == source and row["to_world"][:12] == [1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0]  # Z up
    expected = expected_objects(house)
    if source == "scannet":  # the download holds ScanNet's TSV: it maps the raw names of both layouts
        expected = sorted((name, TSV_NAMES.get(name, category)) for name, category in expected)
    objects = sorted((r["raw_name"], r["mpcat40_index"]) for r in run.read("objects").to_pylist() if r["scene_id"] == scene_id)
    assert objects == expected
    assert row["void_triangles"] == 0 and row["triangles"] == house.triangle_count
    assert np.allclose(scene.bounds(), house.bounds(), atol=1e-6)  # back in the +Y-up world, metres
    # Every face carries its own object: dataset id + 1 of the house object that face had.
    index = object_index(house)
    if source != "replica" and scene_id != "textured0001":
        wanted = np.array([index[int(i)] + 1 for i in house.face_object_ids])
        assert np.array_equal(scene.face_object_ids, wanted)
    if source == "matterport3d":
        rooms = {r["region"] for r in run.read("objects").to_pylist() if r["scene_id"] == scene_id}
        assert rooms == {o.region for o in house.objects.values()} and row["room_count"] == 2


def test_the_textured_matterport_mesh_gives_the_colours(sharded: tuple[RunFolder, dict], house: Scene) -> None:
    _, scene = _scene(sharded[0], "textured0001")
    assert scene.vertex_colors is None and scene.textures[0].shape == (16, 64, 3)
    index = object_index(house)
    wanted = np.array([index[int(i)] + 1 for i in house.face_object_ids])
    assert (scene.face_object_ids == wanted).mean() > 0.99  # moved by nearest face centre onto the OBJ's faces


def test_replica_quads_keep_their_object_ids(sharded: tuple[RunFolder, dict], house: Scene) -> None:
    row, scene = _scene(sharded[0], "room_0")
    index = object_index(house)
    # Quads reorder the triangles: compare each object's triangle count and area with the house's.
    read = {r["object_id"]: (r["triangles"], round(r["surface_area"], 6))
            for r in sharded[0].read("objects").to_pylist() if r["scene_id"] == "room_0"}
    areas = house.face_areas()
    wanted = {index[i] + 1: (int((house.face_object_ids == i).sum()), round(float(areas[house.face_object_ids == i].sum()), 6))
              for i in house.objects}
    assert read == wanted and row["triangles"] == house.triangle_count  # every quad fanned back into its two triangles


@pytest.mark.parametrize("scene_id", ["2t7WUuJeko7", "scene0000_00", "pp0a1b2c3d", "room_0"])
def test_walks_on_the_floor_and_frames_reproject(sharded: tuple[RunFolder, dict], scene_id: str) -> None:
    _, scene = _scene(sharded[0], scene_id)
    _, paths, _ = plan_scene(scene, plan=PlanConfig(trajectories_per_scene=1, min_frames=20, max_frames=600, max_attempts=200))
    assert paths, "no walk planned on the scan's floor"
    path = paths[0]
    floors = {int(i) for i in scene.face_object_ids[scene.face_normals()[:, 1] > 0.9]}
    assert any(scene.objects[i].category == 2 for i in floors if i in scene.objects)  # it walks on a labelled floor
    rotations = level_camera_rotations(path.trajectory.headings)
    poses = np.tile(np.eye(4), (2, 1, 1))
    for t in range(2):
        poses[t, :3, :3] = rotations[t]
        x, z = path.trajectory.positions[t]
        poses[t, :3, 3] = [x, path.floor_heights[t] + 1.0, z]
    body = Embodiment.model_validate({"name": "cam", "sensor": {"width": 160, "height": 120}})
    renderer = VideoRenderer(scene, body, exposure=1.0)
    agreement, visible = _reprojection_agreement(renderer, poses[0], poses[1])
    assert visible > 0.5 * 160 * 120 and agreement >= 0.95  # misses only at object edges (a furnished house)
    frame = renderer.render(poses[0])
    assert set(np.unique(frame.panoptic).tolist()) - {0} <= set(scene.objects)
    assert frame.rgb.reshape(-1, 3).std(axis=0).max() > 5  # coloured, not one flat colour


def test_the_readme_job_snippet_is_a_valid_scenes_section() -> None:
    import re

    import yaml

    from pipeline.config import SceneSources

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index("## Your scans"):]
    section = section[: section.index("\n## ")]
    block = re.search(r"```yaml\n(.*?)```", section, re.S).group(1)  # type: ignore[union-attr]
    sources = SceneSources.model_validate(yaml.safe_load(block)["scenes"])
    assert sources.matterport3d.textured and sources.scannet.labels_tsv and sources.meshes.scale == 0.01  # type: ignore[union-attr]
    for kind in ("matterport3d", "scannet", "replica", "hm3dsem", "meshes"):  # every source has its table row
        assert f"`{kind}: {{root:" in section


@pytest.mark.parametrize("relative", ["mp/2t7WUuJeko7/house_segmentations/2t7WUuJeko7.house",
                                      "scannet/scans/scene0000_00/scene0000_00_vh_clean_2.ply",
                                      "scannet/data/pp0a1b2c3d/scans/mesh_aligned_0.05.ply",
                                      "replica/room_0/habitat/mesh_semantic.ply"])
def test_a_dataset_file_loads_by_its_name(sharded: tuple[RunFolder, dict], house: Scene, relative: str) -> None:
    from pipeline.scenes.sources import load_scene_file

    row = next(r for r in sharded[0].read("scenes").to_pylist() if r["path"].endswith(relative))
    scene = load_scene_file(row["path"])  # what `mvpd scenes preview` / `stats` call
    assert scene.triangle_count == house.triangle_count and len(scene.objects) == len(house.objects)
