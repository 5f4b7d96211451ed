"""The plan stage on box scenes: tables, video names, paired heights, determinism, unplannable scenes."""

from __future__ import annotations

import math

import numpy as np
import pyarrow.compute as pc
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.config import Body, Embodiment, Illumination, Job, PlanConfig, ProceduralSource, SceneSources, Sensor
from pipeline.io.tables import to_table
from pipeline.lazy_import import lazy_module
from pipeline.plan import navigable
from pipeline.plan.navigable import NavigableArea
from pipeline.plan.poses import pose_matrices
from pipeline.plan.report import plan_reports
from pipeline.plan.stage import PathPlanner
from pipeline.plan.synthetic import FLOOR, room_shell, scene_from_boxes, two_rooms
from pipeline.runtime.executor import run_unit_locally
from pipeline.runtime.executors import run_units
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.scene import Scene, SceneRef
from pipeline.scenes.shard import scene_row
from pipeline.scenes.sources import load_procedural

SCENES = {scene.scene_id: scene for scene in (
    two_rooms(door_width=0.9),
    scene_from_boxes("no-floor", [b for b in room_shell(0.0, 4.0, 0.0, 4.0) if b.category != FLOOR]),
)}
ROOMS = "rooms-door0900-wall100"


class BoxPlanner(PathPlanner):
    """The plan stage with its scenes taken from the box scenes above instead of the scene loaders."""

    def load_scene(self, row: dict) -> Scene:
        """The box scene of the row's id."""
        return SCENES[row["scene_id"]]


def make_job(seed: int = 0, embodiments: list[Embodiment] | None = None) -> Job:
    """Two embodiments with the same body: MVPd's heights, and a small camera at 0.5 m with a spot light."""
    body = Body(radius=0.1, height=1.5)
    return Job(name="plan-test", seed=seed, scenes=SceneSources(procedural=ProceduralSource(count=1)),
               plan=PlanConfig(trajectories_per_scene=3, min_frames=20, max_frames=600, max_attempts=300),
               embodiments=embodiments or [
                   Embodiment(name="mvpd", placements=[1.0, 0.1], body=body),
                   Embodiment(name="spot", placements=[0.5], body=body, sensor=Sensor(width=64, height=48),
                              illumination=Illumination(kind="spot", power=20.0)),
               ])


def sharded_run(root, job: Job, scene_ids: tuple[str, ...] = (ROOMS,)) -> RunFolder:
    """A run whose scenes table lists the box scenes."""
    run = RunFolder.create(root, job)
    for scene_id in scene_ids:
        ref = SceneRef(scene_id, "procedural", "", load_procedural)
        run.commit_tables("shard", scene_id, {"scenes": to_table("scenes", [scene_row(SCENES[scene_id], ref)])})
    return run


def planned_run(root, job: Job, scene_ids: tuple[str, ...] = (ROOMS,)) -> tuple[RunFolder, dict]:
    """A run whose scenes table lists the box scenes, with every plan unit run; returns markers by unit."""
    run = sharded_run(root, job, scene_ids)
    stage = BoxPlanner(job)
    return run, {unit.id: run_unit_locally(stage, run, unit) for unit in stage.units(run)}


def test_units_are_scene_times_embodiment(tmp_path):
    run, markers = planned_run(tmp_path / "run", make_job(), (ROOMS, "no-floor"))
    assert sorted(markers) == ["no-floor.mvpd", "no-floor.spot", f"{ROOMS}.mvpd", f"{ROOMS}.spot"]
    assert markers[f"{ROOMS}.mvpd"].rows == {"trajectories": 6, "frames": markers[f"{ROOMS}.mvpd"].rows["frames"]}


def test_videos_are_named_paired_by_height_and_carry_intrinsics(tmp_path):
    run, _ = planned_run(tmp_path / "run", make_job())
    videos = run.read("trajectories").filter(pc.equal(run.read("trajectories")["embodiment"], "mvpd")).to_pylist()
    assert [v["video_name"] for v in videos[:2]] == [f"{ROOMS}.0000000000.0000001000", f"{ROOMS}.0000000000.0000000100"]
    assert videos[0]["fx"] == pytest.approx(465.6029, abs=1e-4) and videos[0]["cx"] == 320.0
    frames = run.read("frames")
    for trajectory in range(3):
        high, low = (frames.filter(pc.equal(frames["video_name"], f"{ROOMS}.{trajectory:010d}.{mm:010d}"))
                     .sort_by("frame") for mm in (1000, 100))
        high_poses, low_poses = pose_matrices(high), pose_matrices(low)
        assert len(high_poses) == videos[2 * trajectory]["frames"] == len(low_poses)
        assert np.array_equal(high_poses[:, [0, 2], 3], low_poses[:, [0, 2], 3])  # same floor positions
        assert np.allclose(high_poses[:, 1, 3] - low_poses[:, 1, 3], 0.9)  # 1.0 m vs 0.1 m above the floor
        assert np.array_equal(high_poses[:, :3, :3], low_poses[:, :3, :3])


def test_embodiments_with_the_same_body_get_the_same_floor_paths(tmp_path):
    run, _ = planned_run(tmp_path / "run", make_job())
    frames = run.read("frames")
    mvpd = frames.filter(pc.equal(frames["video_name"], f"{ROOMS}.0000000002.0000001000"))
    spot = frames.filter(pc.equal(frames["video_name"], f"{ROOMS}.0000000002.0000000500"))
    assert np.array_equal(mvpd["px"].to_numpy(), spot["px"].to_numpy())
    seeds = set(run.read("trajectories")["seed"].to_pylist())
    assert len(seeds) == 1  # one draw seed for the scene, whatever the embodiment


def test_the_same_job_gives_bit_identical_tables_and_another_seed_does_not(tmp_path):
    first, _ = planned_run(tmp_path / "a", make_job(seed=1))
    second, _ = planned_run(tmp_path / "b", make_job(seed=1))
    third, _ = planned_run(tmp_path / "c", make_job(seed=2))
    for dataset in ("trajectories", "frames"):
        part = f"{dataset}/part-{ROOMS}.mvpd.parquet"
        assert (first.root / part).read_bytes() == (second.root / part).read_bytes()
        assert (first.root / part).read_bytes() != (third.root / part).read_bytes()
    assert sorted(p.name for p in (first.root / "navmesh").iterdir()) == sorted(
        p.name for p in (second.root / "navmesh").iterdir())


def test_a_scene_without_floor_is_reported_unplannable_with_no_rows(tmp_path):
    run, markers = planned_run(tmp_path / "run", make_job(), ("no-floor", ROOMS))
    marker = markers["no-floor.mvpd"]
    assert marker.info["status"] == "unplannable"
    assert "no walkable floor" in marker.info["reason"]
    assert marker.rows.get("trajectories", 0) == 0
    reports = {r.unit: r for r in plan_reports(run)}
    assert (reports["no-floor.spot"].status, reports["no-floor.spot"].paths) == ("unplannable", 0)
    assert (reports[f"{ROOMS}.spot"].status, reports[f"{ROOMS}.spot"].paths) == ("planned", 3)
    shown = CliRunner().invoke(app, ["plan", "report", str(run.root), "--problems"], env={"COLUMNS": "300"})
    assert shown.exit_code == 0 and "no-floor.mvpd" in shown.output and f"{ROOMS}.mvpd" not in shown.output
    assert "4 plan units, 2 with fewer paths than asked" in shown.output


def test_a_camera_above_the_ceiling_makes_the_scene_unplannable(tmp_path):
    giant = Embodiment(name="giant", placements=[2.9], body=Body(radius=0.1, height=3.0))  # rooms are 2.5 m high
    _, markers = planned_run(tmp_path / "run", make_job(embodiments=[giant]))
    marker = markers[f"{ROOMS}.giant"]
    assert marker.info["status"] == "unplannable"
    assert "camera at 2.9 m would be above the ceiling" in marker.info["reason"]


def test_a_rerun_reads_the_cached_navigable_area_and_recomputes_a_damaged_one(tmp_path):
    run, markers = planned_run(tmp_path / "run", make_job())
    cache = sorted((run.root / "navmesh").iterdir())
    assert len(cache) == 1  # one body: one area for both embodiments
    original = cache[0].read_bytes()
    stage = BoxPlanner(run.job())
    unit = [u for u in stage.units(run) if u.id == f"{ROOMS}.mvpd"][0]

    blocked = NavigableArea.load(cache[0])  # a cache with nothing navigable: the rerun must trust it
    blocked.navigable[:] = False
    blocked.islands[:] = -1
    blocked.stats["navigable_nodes"] = 0
    blocked.save(cache[0])
    assert run_unit_locally(stage, run, unit).info["status"] == "unplannable"

    cache[0].write_bytes(b"damaged")
    again = run_unit_locally(stage, run, unit)
    assert cache[0].read_bytes() == original and f"navmesh/{cache[0].name}" in again.outputs
    assert again.rows == markers[unit.id].rows and again.info["status"] == "planned"


def test_settings_follow_the_body_but_not_the_light():
    job = make_job()
    lit = job.model_copy(update={"embodiments": [e.model_copy(update={"illumination": Illumination()})
                                                 for e in job.embodiments]})
    assert PathPlanner(job).settings() == PathPlanner(lit).settings()
    bigger = job.model_copy(update={"embodiments": [job.embodiments[0].model_copy(
        update={"body": Body(radius=0.2)}), job.embodiments[1]]})
    assert PathPlanner(job).settings() != PathPlanner(bigger).settings()
    assert math.isclose(PathPlanner(job).settings()["plan"]["max_turn"], 0.5)


def test_every_unit_says_the_same_line_when_open3d_cannot_load_its_system_library(tmp_path, monkeypatch,
                                                                                  unloadable_module):
    monkeypatch.setattr(navigable, "o3d", lazy_module(unloadable_module))  # open3d as it loads without libusb
    job = make_job()
    run, stage = sharded_run(tmp_path / "run", job), BoxPlanner(job)
    units = stage.units(run)
    outcomes = run_units(stage, run, units, {unit.id: 1 for unit in units}, "local", None, None)  # one process
    assert [o.state for o in outcomes] == ["failed", "failed"]
    assert outcomes[0].message == outcomes[1].message and outcomes[0].error_type == outcomes[1].error_type
    assert "libusb-1.0.so.0: install the apt package libusb-1.0-0" in outcomes[0].message
    assert "make setup" in outcomes[0].message
