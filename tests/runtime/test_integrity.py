"""Damage behind a valid marker is found and repaired; retries are counted; inline and Ray write the same bytes.

The tiny stage checks the mechanism cheaply; a tiny real job (one generated house, 64x48 px) checks it
where it was seen: a deleted Zarr shard, a truncated `trajectories/` part and a truncated `status/` part.
"""

from __future__ import annotations

import hashlib
import io
import json
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import ray.cloudpickle
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.io.reader import VideoDamagedError, load_video
from pipeline.runtime.executor import plan_stage, run_stage
from pipeline.store.markers import file_checksum
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.status import read_status
from pipeline.store.datasets import damaged_parts, dataset_parts
from tests.runtime import tiny_stage
from tests.runtime.test_executor import make_job
from tests.runtime.tiny_stage import TinyStage

ray.cloudpickle.register_pickle_by_value(sys.modules[tiny_stage.__name__])
runner = CliRunner()


def invoke(*args: object):
    return runner.invoke(app, [str(a) for a in args])


def digest(root: Path, folders: tuple[str, ...]) -> dict[str, str]:
    """Relative path -> sha256 of every file below `folders` of a run."""
    found = {}
    for folder in folders:
        for path in sorted((root / folder).rglob("*")):
            if path.is_file():
                found[path.relative_to(root).as_posix()] = hashlib.sha256(path.read_bytes()).hexdigest()
    return found


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def parquet_rows(data: bytes) -> list[dict]:
    return pq.read_table(io.BytesIO(data)).to_pylist()


@pytest.fixture
def tiny(tmp_path) -> RunFolder:
    run = RunFolder.create(tmp_path / "run", make_job({"a": [1.0], "b": [0.5], "c": [0.1]}))
    run_stage(TinyStage(run.job()), run, executor="local")
    return run


# ------------------------------------------------------------------------------ the tiny stage


def test_marker_lists_every_file_with_its_size_and_checksum(tiny):
    marker = tiny.marker("tiny", "b")
    assert [f.path for f in marker.files] == ["tiny/part-b.parquet", "tiny_files/b.txt"]
    for entry in marker.files:
        assert entry.size == (tiny.root / entry.path).stat().st_size
        assert entry.crc32c == file_checksum(tiny.root / entry.path)
    assert dataset_parts(tiny, "tiny") == [tiny.root / "tiny" / f"part-{u}.parquet" for u in "abc"]


def test_a_part_no_marker_names_is_not_read(tiny):
    tiny.drop_marker("tiny", "c")  # as a unit that died between dropping its old marker and writing the new
    assert sorted(r["unit"] for r in tiny.read("tiny").to_pylist()) == ["a", "b"]
    assert (tiny.root / "tiny" / "part-c.parquet").exists()


def test_truncated_part_makes_its_unit_damaged_and_a_rerun_rewrites_exactly_it(tiny):
    clean = digest(tiny.root, ("tiny", "tiny_files"))
    truncate(tiny.root / "tiny" / "part-b.parquet")
    assert [d.unit for d in damaged_parts(tiny, "tiny")] == ["b"]
    assert sorted(r["unit"] for r in tiny.read("tiny").to_pylist()) == ["a", "c"]  # read on, without b
    plan = plan_stage(TinyStage(tiny.job()), tiny)
    assert [u.id for u in plan.to_run] == ["b"] and list(plan.damaged) == ["b"]
    report = run_stage(TinyStage(tiny.job()), tiny, executor="local")
    assert [o.unit for o in report.outcomes] == ["b"]
    assert digest(tiny.root, ("tiny", "tiny_files")) == clean


def test_same_size_corruption_is_found_by_verify_and_repaired(tiny):
    from pipeline.runtime.verify import verify_run

    clean = digest(tiny.root, ("tiny", "tiny_files"))
    path = tiny.root / "tiny_files" / "a.txt"
    text = path.read_bytes()
    path.write_bytes(bytes([text[0] ^ 1]) + text[1:])  # one flipped bit, same size
    assert not plan_stage(TinyStage(tiny.job()), tiny).to_run  # sizes alone cannot see it
    found = verify_run(tiny, executor="local")
    assert list(found) == [("tiny", "a")] and "checksum" in found[("tiny", "a")][0].problem
    assert [u.id for u in plan_stage(TinyStage(tiny.job()), tiny).to_run] == ["a"]  # remembered for rerun
    run_stage(TinyStage(tiny.job()), tiny, executor="local")
    assert digest(tiny.root, ("tiny", "tiny_files")) == clean
    assert verify_run(tiny, executor="local") == {}


def test_unreadable_part_of_the_right_size_is_skipped_recorded_and_repaired(tiny, caplog):
    clean = digest(tiny.root, ("tiny", "tiny_files"))
    part = tiny.root / "tiny" / "part-a.parquet"
    part.write_bytes(b"\0" * part.stat().st_size)  # same size, nothing Parquet can read (not even the footer)
    assert sorted(r["unit"] for r in tiny.read("tiny").to_pylist()) == ["b", "c"]
    assert "unreadable Parquet part" in caplog.text and "rerun stage tiny" in caplog.text
    assert list(plan_stage(TinyStage(tiny.job()), tiny).damaged) == ["a"]  # the reader's finding is kept
    run_stage(TinyStage(tiny.job()), tiny, executor="local")
    assert digest(tiny.root, ("tiny", "tiny_files")) == clean


def test_verify_on_ray_finds_the_same_damage(ray_session, tiny):
    from pipeline.runtime.verify import verify_run

    (tiny.root / "tiny_files" / "c.txt").write_text("x" * (tiny.root / "tiny_files" / "c.txt").stat().st_size)
    found = verify_run(tiny, executor="ray")
    assert list(found) == [("tiny", "c")] and found[("tiny", "c")][0].path == "tiny_files/c.txt"


def test_truncated_status_part_is_reported_rebuilt_from_markers_and_rewritten(tiny):
    part = tiny.root / "status" / "part-tiny.parquet"
    clean = part.read_bytes()
    truncate(part)
    assert [d.unit for d in damaged_parts(tiny, "status")] == ["tiny"]
    statuses = read_status(tiny, "tiny")  # no traceback: the outcomes come from the markers
    assert sorted(u for _, u in statuses) == ["a", "b", "c"] and {o.state for o in statuses.values()} == {"done"}
    report = run_stage(TinyStage(tiny.job()), tiny, executor="local")
    assert report.outcomes == [] and damaged_parts(tiny, "status") == []
    assert parquet_rows(part.read_bytes()) == parquet_rows(clean)  # same outcomes, written again


def test_inline_and_ray_executors_write_the_same_bytes(ray_session, tiny, tmp_path):
    other = RunFolder.create(tmp_path / "on_ray", tiny.job())
    report = run_stage(TinyStage(other.job()), other, executor="ray")
    assert len(report.outcomes) == 3 and not report.failed
    assert digest(other.root, ("tiny", "tiny_files")) == digest(tiny.root, ("tiny", "tiny_files"))
    assert [f for m in other.markers("tiny").values() for f in m.files] == \
        [f for m in tiny.markers("tiny").values() for f in m.files]


def test_auto_runs_small_work_in_process_without_starting_ray(tmp_path, monkeypatch):
    import pipeline.runtime.executors as executors

    def no_ray(*args, **kwargs):
        raise AssertionError("Ray was started for three tiny units")

    monkeypatch.setattr(executors, "ray_is_running", lambda: False)
    monkeypatch.setattr(executors, "run_on_ray", no_ray)
    run = RunFolder.create(tmp_path / "run", make_job({"a": [1.0], "b": [0.5]}))
    report = run_stage(TinyStage(run.job()), run)
    assert [o.unit for o in report.outcomes] == ["a", "b"] and not report.failed


def test_killed_worker_retry_is_recorded_as_attempt_2_with_the_reason(ray_session, tmp_path):
    run = RunFolder.create(tmp_path / "run", make_job({"a": [1.0], "b": [0.5]}))
    (run.root / "control").mkdir()
    (run.root / "control" / "b.kill").touch()  # the worker running b dies by SIGKILL mid-unit, once
    report = run_stage(TinyStage(run.job()), run, executor="ray")
    assert (run.root / "control" / "b.killed").exists() and not report.failed
    assert run.marker("tiny", "b").attempt == 2 and run.marker("tiny", "a").attempt == 1
    statuses = read_status(run, "tiny")
    assert statuses[("tiny", "b")].attempt == 2 and statuses[("tiny", "a")].attempt == 1
    log_text = (run.root / statuses[("tiny", "b")].log_path).read_text()
    assert "attempt 2" in log_text and "Ray retry 1" in log_text
    assert "attempt 1 ended because its Ray worker (pid" in log_text and "died" in log_text


# ------------------------------------------------------------------------- a tiny real job

JOB = """
name: damage
seed: 3
scenes:
  procedural: {count: 1, seed: 1, detail: 0.05}
embodiments:
  - name: tiny
    sensor: {width: 64, height: 48, hfov: 69.0}
    placements: [1.0, 0.1]
    body: {radius: 0.15, height: 1.2}
plan: {trajectories_per_scene: 1, min_frames: 10, max_frames: 20}
render: {frames_per_shard: 4}
"""
PIXELS_AND_PLANS = ("videos", "trajectories", "frames", "segments", "scenes", "objects")


@pytest.fixture(scope="module")
def job_run(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    folder = tmp_path_factory.mktemp("damage")
    (folder / "job.yaml").write_text(JOB)
    run = folder / "run"
    result = invoke("submit", folder / "job.yaml", "--run-dir", run, "--executor", "local")
    assert result.exit_code == 0, result.output
    return run, digest(run, PIXELS_AND_PLANS)


def clean_bytes(found: dict[str, str]) -> dict[str, str]:
    """Digests without the `videos` parts, which hold render timings (they vary between runs)."""
    return {p: d for p, d in found.items() if not p.startswith("videos/part-")}


def test_deleted_zarr_shard_is_named_by_status_and_rerun_restores_the_video(job_run):
    run, clean = job_run
    shard = sorted((run / "videos" / "tiny").glob("*.zarr/rgb/c/1/*/*/*"))[0]
    video = shard.relative_to(run / "videos" / "tiny").parts[0].removesuffix(".zarr")
    shard.unlink()
    assert len(RunFolder(run).read("videos")) == 1  # readers leave the damaged video out ...
    assert [d.path for d in damaged_parts(RunFolder(run), "videos")] == [shard.relative_to(run).as_posix()]  # ... and say why
    with pytest.raises(VideoDamagedError, match="is missing"):  # no silent zeros where the shard was
        load_video(run, video, "tiny")
    result = invoke("status", run)
    assert result.exit_code == 1
    assert f"render/tiny.{video}" in result.output and "damaged" in result.output and "is missing" in result.output
    result = invoke("rerun", run, "--stage", "render", "--executor", "local")
    assert result.exit_code == 0 and "1 done, 0 failed, 1 up to date" in result.output, result.output
    assert clean_bytes(digest(run, PIXELS_AND_PLANS)) == clean_bytes(clean)
    assert invoke("status", run).exit_code == 0
    assert load_video(run, video, "tiny").frames > 0


def test_truncated_trajectories_part_is_named_by_status_and_rerun_restores_it(job_run):
    run, clean = job_run
    part = next((run / "trajectories").glob("part-*.parquet"))
    truncate(part)
    result = invoke("status", run)
    assert result.exit_code == 1 and f"plan/{part.stem.removeprefix('part-')}" in result.output
    assert f"trajectories/{part.name} has" in result.output
    result = invoke("rerun", run, "--stage", "plan", "--executor", "local")
    assert result.exit_code == 0, result.output
    assert "1 damaged units run again" in result.output
    assert clean_bytes(digest(run, PIXELS_AND_PLANS)) == clean_bytes(clean)
    result = invoke("rerun", run, "--stage", "render", "--executor", "local")  # nothing downstream was lost
    assert result.exit_code == 0 and "0 done, 0 failed, 2 up to date" in result.output


def test_truncated_status_part_never_blocks_status_rerun_or_submit(job_run):
    run, clean = job_run
    truncate(run / "status" / "part-render.parquet")
    result = invoke("status", run)
    assert result.exit_code == 0, result.output
    assert "status table of stage render" in result.output and "rebuilt from markers" in result.output
    result = invoke("rerun", run, "--stage", "render", "--all", "--executor", "local")
    assert result.exit_code == 0 and "2 done" in result.output, result.output
    assert "status table of stage render: status/part-render.parquet has" in result.output
    assert "status table" not in invoke("status", run).output  # rewritten by the rerun
    assert clean_bytes(digest(run, PIXELS_AND_PLANS)) == clean_bytes(clean)


def test_status_verify_finds_a_flipped_byte_and_rerun_repairs_it(job_run):
    run, clean = job_run
    shard = sorted((run / "videos" / "tiny").glob("*.zarr/depth/c/0/*/*"))[-1]
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0xFF
    shard.write_bytes(bytes(data))
    assert invoke("status", run).exit_code == 0  # same size: only reading can tell
    result = invoke("status", run, "--verify")
    assert result.exit_code == 1 and "fails its checksum" in result.output
    assert invoke("status", run).exit_code == 1  # remembered until repaired
    result = invoke("rerun", run, "--stage", "render", "--executor", "local")
    assert result.exit_code == 0 and "1 done" in result.output, result.output
    assert clean_bytes(digest(run, PIXELS_AND_PLANS)) == clean_bytes(clean)
    assert invoke("status", run, "--verify").exit_code == 0


def test_render_marker_lists_every_file_of_the_zarr_store(job_run):
    run, _ = job_run
    marker = json.loads(next((run / "_state" / "render").glob("*.json")).read_text())
    zarr_files = [f for f in marker["files"] if ".zarr/" in f["path"]]
    assert marker["version"] == 2 and len(zarr_files) > 4  # every file of the store, not the store as one
    assert all(set(f) == {"path", "size", "crc32c"} for f in marker["files"])


def test_evaluate_in_process_and_on_ray_give_the_same_result(ray_session, tmp_path):
    case = Path(__file__).resolve().parents[1] / "data" / "vsq_small"
    results = {}
    for executor in ("local", "ray"):
        out = tmp_path / f"{executor}.json"
        result = invoke("evaluate", "--gt-mvpd", case / "MVPd", "--split", "test", "--pred", case / "pred",
                        "--out", out, "--executor", executor)
        assert result.exit_code == 0, result.output
        results[executor] = json.loads(out.read_text())
        parts = digest(out.with_suffix(".run"), ("metrics",))
        results[executor + "_metrics"] = {Path(p).name: d for p, d in parts.items()}
    assert results["local"] == results["ray"] and results["local_metrics"] == results["ray_metrics"]
    assert len(results["local_metrics"]) == 3  # one part per video


def test_query_and_stats_leave_a_damaged_unit_out_and_say_so_in_one_line(job_run, caplog):
    run, _ = job_run
    shard = sorted((run / "videos" / "tiny").glob("*.zarr/panoptic/c/0/*/*"))[0]
    data = shard.read_bytes()
    shard.unlink()
    result = invoke("query", run, "select count(*) from videos", "--format", "csv")
    assert result.exit_code == 0 and result.output.splitlines()[1] == "1", result.output
    lines = [r.getMessage() for r in caplog.records if "damaged unit" in r.getMessage()]
    assert len(lines) == 1 and "rows of 1 damaged unit(s) left out" in lines[0] and "mvpd rerun" in lines[0]
    assert invoke("stats", run).exit_code == 0
    shard.write_bytes(data)  # put back as it was: the run is whole again
    assert invoke("status", run).exit_code == 0
