"""The shard stage: a tiny job writes `scenes` and `objects`; a broken scene fails alone."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from pipeline.config import Job
from pipeline.runtime.executor import UnitFailedError, run_unit_locally
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.scene import Scene
from pipeline.scenes.shard import SceneSharder
from pipeline.scenes.sources import load_scene_row


def _job(tmp_path: Path, hm3dsem_root: Path) -> Job:
    return Job.model_validate({
        "name": "tiny", "seed": 0,
        "scenes": {"procedural": {"count": 1, "seed": 7, "detail": 0.05, "min_rooms": 3, "max_rooms": 4},
                   "hm3dsem": {"root": str(hm3dsem_root)}},
        "embodiments": [{"name": "cam"}],
    })


@pytest.fixture()
def hm3dsem_root(house_files: Path, tmp_path: Path) -> Path:
    root = tmp_path / "hm3dsem"
    good = root / "00001-good"
    good.mkdir(parents=True)
    for path in house_files.parent.iterdir():
        shutil.copy(path, good / path.name.replace(house_files.parent.name, "00001-good"))
    broken = root / "00002-broken"
    shutil.copytree(good, broken)
    for path in broken.iterdir():
        path.rename(path.with_name(path.name.replace("00001-good", "00002-broken")))
    (broken / "00002-broken.semantic.glb").write_bytes(b"glTF garbage")
    return root


def test_shard_writes_tables_and_isolates_a_broken_scene(tmp_path: Path, hm3dsem_root: Path, small_house: Scene) -> None:
    job = _job(tmp_path, hm3dsem_root)
    run = RunFolder.create(tmp_path / "run", job)
    stage = SceneSharder(job)
    units = stage.units(run)
    assert [u.id for u in units] == ["00001-good", "00002-broken", "proc-000007"]
    for unit in units:
        if unit.id == "00002-broken":
            with pytest.raises(UnitFailedError, match=r"SceneError: .*00002-broken\.semantic\.glb: corrupt GLB"):
                run_unit_locally(stage, run, unit)
        else:
            run_unit_locally(stage, run, unit)
    scenes = {row["scene_id"]: row for row in run.read("scenes").to_pylist()}
    assert sorted(scenes) == ["00001-good", "proc-000007"]
    generated, read = scenes["proc-000007"], scenes["00001-good"]
    assert generated["triangles"] == read["triangles"] == small_house.triangle_count
    assert generated["object_count"] == len(small_house.objects)
    assert generated["room_count"] >= 3 and generated["floor_area"] > 20
    assert read["to_world"][:12] == [1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0]
    assert read["unknown_colors"] == 0 and read["void_triangles"] == 0
    objects = run.read("objects").to_pylist()
    assert len(objects) == 2 * len(small_house.objects)
    walls = [o for o in objects if o["mpcat40_name"] == "wall"]
    assert walls and all(o["is_stuff"] and o["surface_area"] > 1 for o in walls)
    assert load_scene_row(generated).triangle_count == small_house.triangle_count


def test_settings_follow_the_scene_sources(tmp_path: Path, hm3dsem_root: Path) -> None:
    job = _job(tmp_path, hm3dsem_root)
    changed = job.model_copy(update={"scenes": job.scenes.model_copy(update={"procedural": job.scenes.procedural.model_copy(update={"detail": 0.1})})})
    run = RunFolder.create(tmp_path / "run", job)
    unit = [u for u in SceneSharder(job).units(run) if u.id == "proc-000007"][0]
    assert SceneSharder(job).unit_hash(unit) != SceneSharder(changed).unit_hash(unit)
