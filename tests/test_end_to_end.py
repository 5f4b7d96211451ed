"""The whole job through `mvpd` on local Ray: shard -> plan -> render, then status, query and rerun."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app

runner = CliRunner()
JOB = """
name: e2e
seed: 7
scenes:
  procedural: {count: 1, seed: 1, detail: 0.05}
  meshes: {root: meshes, pattern: "*.glb"}
embodiments:
  - name: tiny
    sensor: {width: 64, height: 48, hfov: 69.0}
    placements: [1.0, 0.1]
    body: {radius: 0.15, height: 1.2}
plan: {trajectories_per_scene: 1, min_frames: 10, max_frames: 40}
"""


def invoke(*args: object):
    return runner.invoke(app, [str(a) for a in args])


def zarr_digest(run: Path) -> str:
    """Digest of every file of every Zarr store (the `videos` Parquet parts hold timings, which vary)."""
    digest = hashlib.sha256()
    for path in sorted((run / "videos").rglob("*")):
        if path.is_file() and ".zarr" in str(path):
            digest.update(str(path.relative_to(run)).encode() + path.read_bytes())
    return digest.hexdigest()


@pytest.fixture(scope="module")
def job_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("job")
    (folder / "meshes").mkdir()
    (folder / "meshes" / "broken.glb").write_bytes(b"glTF this is not a real binary glTF")
    (folder / "meshes" / "broken.json").write_text('{"objects": [{"id": 1, "name": "chair"}]}')
    (folder / "job.yaml").write_text(JOB)
    return folder / "job.yaml"


@pytest.fixture(scope="module")
def run(ray_session, job_file, tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("runs") / "e2e"
    result = invoke("submit", job_file, "--run-dir", run)
    assert result.exit_code == 1, result.output  # the broken mesh fails its unit, the rest goes on
    return run


def test_a_broken_scene_fails_alone_and_is_reported(run):
    result = invoke("status", run)
    assert result.exit_code == 1
    assert "shard/broken" in result.output and "SceneError" in result.output
    assert "broken.glb" in result.output


def test_the_generated_house_goes_through_every_stage(run):
    result = invoke("query", run, "select count(*) from scenes", "--format", "csv")
    assert result.exit_code == 0 and result.output.splitlines()[1] == "1"
    result = invoke("query", run, "select height_m, frames from videos order by height_m", "--format", "json")
    assert result.exit_code == 0, result.output
    videos = __import__("json").loads(result.output)
    assert [v["height_m"] for v in videos] == [0.1, 1.0]  # one trajectory, both heights
    assert videos[0]["frames"] == videos[1]["frames"] >= 10
    assert len(list((run / "videos" / "tiny").glob("*.zarr"))) == 2
    # `frames` shows the poses of the plan together with the per-frame statistics of the render.
    sql = "select count(*), count(void_fraction), min(visible_objects) from frames"
    result = invoke("query", run, sql, "--format", "csv")
    total, with_stats, fewest_objects = (int(v) for v in result.output.splitlines()[1].split(","))
    assert total == with_stats == sum(v["frames"] for v in videos) and fewest_objects >= 1


def test_stats_count_what_the_tables_hold_and_draw_them(run, tmp_path):
    from pipeline.io.dataset_stats import dataset_stats
    from pipeline.store.run_folder import RunFolder

    folder = RunFolder.open(run)
    found = dataset_stats(folder)
    segments, videos = folder.read("segments").to_pylist(), folder.read("videos").to_pylist()
    (row,) = found.per_embodiment
    assert (row["embodiment"], row["scenes"], row["videos"]) == ("tiny", 1, 2)
    assert row["frames"] == sum(v["frames"] for v in videos) and row["masks"] == len(segments)
    assert found.instances == len({s["object_id"] for s in segments})  # one scene: ids are instances
    assert sum(c["masks"] for c in found.per_category) == len(segments)
    picture = tmp_path / "stats.png"
    result = invoke("stats", run, "--out", picture)
    assert result.exit_code == 0, result.output
    assert "object instances" in result.output and picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_overview_draws_the_plan_every_video_of_a_trajectory_and_the_statistics(run, tmp_path):
    from pipeline.overview import write_overview
    from pipeline.store.run_folder import RunFolder

    pictures = write_overview(RunFolder.open(run), tmp_path)
    names = sorted(p.name for p in pictures)
    assert names[-1] == "stats.png" and sum(n.endswith(".plan.png") for n in names) == 1
    assert sum(n.endswith(".gif") for n in names) == 2  # the trajectory at both heights
    magic = {".png": b"\x89PNG", ".gif": b"GIF8"}
    assert all(p.read_bytes().startswith(magic[p.suffix]) for p in pictures)


def test_stats_of_a_run_without_videos_is_a_one_line_error(tmp_path):
    from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources
    from pipeline.store.run_folder import RunFolder

    job = Job(name="empty", scenes=SceneSources(procedural=ProceduralSource(count=1)), embodiments=[Embodiment(name="cam")])
    RunFolder.create(tmp_path / "empty", job)
    result = invoke("stats", tmp_path / "empty")
    assert result.exit_code == 2 and "render" in result.output and len(result.output.strip().splitlines()) == 1


def test_rerun_runs_only_what_is_missing(run):
    result = invoke("rerun", run, "--stage", "render")
    assert result.exit_code == 0 and "0 done, 0 failed, 2 up to date" in result.output
    marker = next((run / "_state" / "render").glob("*.json"))
    marker.unlink()
    result = invoke("rerun", run, "--stage", "render")
    assert result.exit_code == 0 and "1 done, 0 failed, 1 up to date" in result.output


def test_same_job_gives_bit_identical_videos(run, job_file, tmp_path):
    again = tmp_path / "again"
    assert invoke("submit", job_file, "--run-dir", again).exit_code == 1  # the same broken mesh
    assert zarr_digest(again) == zarr_digest(run)
    for dataset in ("trajectories", "frames", "segments", "objects"):
        ours = sorted((run / dataset).glob("*.parquet"))
        theirs = sorted((again / dataset).glob("*.parquet"))
        assert [p.read_bytes() for p in ours] == [p.read_bytes() for p in theirs], dataset
