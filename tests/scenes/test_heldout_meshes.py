"""Held-out style meshes (made here, as a user would bring them) shard with the right objects and render in colour."""

from __future__ import annotations


import numpy as np
import pytest

from pipeline.config import Job
from pipeline.render.renderer import VideoRenderer
from pipeline.runtime.executor import run_unit_locally
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.scene import Scene
from pipeline.scenes.shard import SceneSharder
from pipeline.scenes.sources import load_scene_row
from tests.scenes.meshfiles import (write_gltf_scene_graph, write_obj_with_degenerate_faces, write_obj_with_materials,
                                    write_ply_with_labels)


@pytest.fixture(scope="module")
def sharded(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunFolder, Job, dict]:
    """One job whose `meshes:` source (default pattern) holds every held-out file; every unit sharded."""
    root = tmp_path_factory.mktemp("meshes")
    expected = {"room": write_obj_with_materials(root)[1], "scan": write_ply_with_labels(root)[1],
                "model": write_gltf_scene_graph(root)[1], "broken": write_obj_with_degenerate_faces(root)[1]}
    job = Job.model_validate({"name": "heldout", "seed": 0, "scenes": {"meshes": {"root": str(root)}},
                              "embodiments": [{"name": "cam", "sensor": {"width": 64, "height": 48}}]})
    run = RunFolder.create(tmp_path_factory.mktemp("run") / "run", job)
    stage = SceneSharder(job)
    units = stage.units(run)
    assert sorted(u.id for u in units) == sorted(expected)  # the default pattern takes every mesh suffix, not .mtl/.png/.bin
    for unit in units:
        run_unit_locally(stage, run, unit)
    return run, job, expected


def _scene(run: RunFolder, scene_id: str) -> tuple[dict, Scene]:
    row = next(r for r in run.read("scenes").to_pylist() if r["scene_id"] == scene_id)
    return row, load_scene_row(row)


def _top_down_frame(scene: Scene, job: Job) -> list[np.ndarray]:
    """Mean RGB of each object seen by a camera 6 m above the middle of the scene looking straight down."""
    low, high = scene.bounds()
    pose = np.eye(4)
    pose[:3, :3] = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)  # camera x, y, z -> world +X, +Z, -Y
    pose[:3, 3] = [(low[0] + high[0]) / 2, high[1] + 6.0, (low[2] + high[2]) / 2]
    frame = VideoRenderer(scene, job.embodiments[0], exposure=1.0).render(pose)
    return [frame.rgb[frame.panoptic == i].mean(axis=0) for i in np.unique(frame.panoptic) if i > 0]


def _assert_coloured(object_colors: list[np.ndarray]) -> None:
    assert len(object_colors) >= 3, "fewer than 3 objects in view"
    saturated = [c for c in object_colors if c.max() - c.min() > 60]
    assert len(saturated) >= 2, f"flat grey objects: {object_colors}"
    assert len({tuple(np.round(c / 40)) for c in object_colors}) >= 3, "objects share one colour"


def test_obj_with_materials_gives_one_object_per_material(sharded: tuple[RunFolder, Job, dict]) -> None:
    run, job, expected = sharded
    row, scene = _scene(run, "room")
    assert row["object_count"] == len(expected["room"]) == 4
    assert {o.raw_name: o.category for o in scene.objects.values()} == expected["room"]
    pixels = _top_down_frame(scene, job)
    _assert_coloured(pixels)
    rug = next(i for i, o in scene.objects.items() if o.raw_name == "rug")
    assert scene.face_material is not None and scene.textures[int(scene.face_material[scene.face_object_ids == rug][0])].shape[0] == 8  # map_Kd


def test_ply_with_vertex_labels_and_colours(sharded: tuple[RunFolder, Job, dict]) -> None:
    run, job, expected = sharded
    row, scene = _scene(run, "scan")
    assert row["object_count"] == expected["scan"] == 3
    assert sorted(scene.objects) == [10, 11, 12]  # the labels are the object ids
    _assert_coloured(_top_down_frame(scene, job))


def test_gltf_scene_graph_places_nodes(sharded: tuple[RunFolder, Job, dict]) -> None:
    run, job, expected = sharded
    row, scene = _scene(run, "model")
    assert row["object_count"] == len(expected["model"]) == 4
    objects = {r["raw_name"]: r for r in run.read("objects").to_pylist() if r["scene_id"] == "model"}
    for name, low in expected["model"].items():  # the shared cushion mesh lands twice, under the sofa's transform
        assert np.allclose([objects[name]["min_x"], objects[name]["min_y"], objects[name]["min_z"]], low, atol=1e-5), name
    assert objects["sofa"]["mpcat40_name"] == "sofa" and objects["cushion_2"]["mpcat40_name"] == "cushion"
    _assert_coloured(_top_down_frame(scene, job))


def test_degenerate_faces_are_counted_in_the_shard_table(sharded: tuple[RunFolder, Job, dict]) -> None:
    run, _, expected = sharded
    row, _ = _scene(run, "broken")
    assert row["degenerate_faces"] == expected["broken"] == 3
    assert row["triangles"] == 2
    log = next(run.root.glob("**/shard/**/broken*.log"), None) or next(p for p in run.root.rglob("*.log") if "broken" in p.name)
    assert "3 degenerate faces" in log.read_text()
