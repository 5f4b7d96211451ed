"""The demo-shaped job on a real S3 API (moto on 127.0.0.1): end to end on Ray, byte-equal to local disk,
readable by status/query/load_video, a failed upload leaves nothing visible, a rerun completes it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.store import remote as object_store
from pipeline.store.names import ATTEMPTS
from pipeline.runtime.executor import plan_stage
from pipeline.store.markers import parse_marker
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.verify import verify_run
from pipeline.stages import make_stage
from tests.demo_run import DEMO_SHAPED_JOB, DEMO_VIDEO, demo_shaped_run
from tests.storage.conftest import BUCKET, TEST_KEY_ID, TEST_SECRET, S3Server, forget_clients

# The status table records wall times: it is the one output a rerun changes by design.
TIMED = "status/"
# Datasets with a documented wall-time column (`render_seconds`, "not reproducible" in schemas/tables).
TIMED_DATASETS = ("videos", "frame_stats")


def assert_same_outputs(ours: dict[str, bytes], theirs: dict[str, bytes]) -> None:
    """Same files, same bytes; only parts with documented wall-time columns may differ, and only there."""
    assert sorted(ours) == sorted(theirs)
    differing = [p for p in theirs if ours[p] != theirs[p]]
    assert {p.split("/")[0] for p in differing} <= set(TIMED_DATASETS), differing
    for path in differing:
        assert untimed(ours[path]).equals(untimed(theirs[path])), path


def untimed(data: bytes) -> pa.Table:
    table = pq.read_table(pa.BufferReader(data))
    return table.drop_columns([c for c in table.column_names if c.endswith("seconds")])


def invoke(*args: object) -> object:
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def s3_run(s3: S3Server, ray_session, tmp_path_factory) -> str:
    job = tmp_path_factory.mktemp("s3-job") / "demo.yaml"
    job.write_text(DEMO_SHAPED_JOB, encoding="utf-8")
    url = s3.url("runs/demo")
    result = invoke("submit", job, "--run-dir", url, "--executor", "ray")
    assert result.exit_code == 0, result.output
    assert f"run folder: {url}" in result.output
    return url


def store_markers(s3: S3Server, url: str) -> dict[str, object]:
    """(stage/unit) -> marker, read straight from the bucket."""
    prefix = url.removeprefix("s3://")
    found = {}
    for key in s3.fs.find(f"{prefix}/_state"):
        if key.endswith(".json"):
            marker = parse_marker(s3.fs.cat_file(key).decode())
            if marker is not None:
                found[f"{marker.stage}/{marker.unit}"] = marker
    return found


def trusted_bytes_on_store(s3: S3Server, url: str) -> dict[str, bytes]:
    """Logical path -> bytes of every file a marker on the bucket names (fetched by the key it names)."""
    prefix = url.removeprefix("s3://")
    return {f.path: s3.fs.cat_file(f"{prefix}/{m.keys[f.path]}")
            for m in store_markers(s3, url).values() for f in m.files if not f.path.startswith(TIMED)}


def trusted_bytes_on_disk(run: Path) -> dict[str, bytes]:
    found = {}
    for path in (run / "_state").glob("*/*.json"):
        marker = parse_marker(path.read_text())
        if marker is not None and not marker.stage.startswith("_"):
            found.update({f.path: (run / f.path).read_bytes() for f in marker.files})
    return found


def test_demo_on_s3_equals_local_disk_byte_for_byte(s3, s3_run, tmp_path_factory):
    local = trusted_bytes_on_disk(demo_shaped_run(tmp_path_factory))
    remote = trusted_bytes_on_store(s3, s3_run)
    assert sorted(remote) == sorted(local)
    assert any(p.startswith("videos/") and ".zarr/" in p for p in remote) and any(p.endswith(".parquet") for p in remote)
    assert_same_outputs(remote, local)
    # Outputs stay under attempt-unique keys: the bucket holds no object at a logical path.
    prefix = s3_run.removeprefix("s3://")
    assert not s3.fs.exists(f"{prefix}/videos") and s3.fs.exists(f"{prefix}/{ATTEMPTS}")


def local_data(folder: Path) -> list[Path]:
    """Parquet parts and Zarr files below a local folder."""
    return [p for p in folder.rglob("*") if p.is_file() and (p.suffix == ".parquet" or ".zarr" in p.as_posix())]


def test_status_query_and_load_video_read_the_bucket(s3, s3_run, tmp_path_factory, monkeypatch):
    # A fresh local folder (another machine): everything is read in place on the bucket, nothing copied.
    machine = tmp_path_factory.mktemp("other-machine")
    monkeypatch.setenv("MVPD_CACHE_DIR", str(machine))
    status = invoke("status", s3_run)
    assert status.exit_code == 0, status.output
    assert "render" in status.output and "│ 12    │ 12   │" in status.output
    query = invoke("query", s3_run, "select count(*) as n from videos", "--format", "json")
    assert query.exit_code == 0, query.output
    assert json.loads(query.output)[0]["n"] == 12
    stats = invoke("stats", s3_run)
    assert stats.exit_code == 0 and "ambient" in stats.output, stats.output
    from pipeline.io.reader import iter_clips, load_video

    clip = next(iter_clips(s3_run, 4))
    assert clip["rgb"].shape == (4, 48, 64, 3)

    ours = load_video(s3_run, DEMO_VIDEO, "ambient")
    theirs = load_video(demo_shaped_run(tmp_path_factory), DEMO_VIDEO, "ambient")
    assert ours.rgb.shape == theirs.rgb.shape and ours.rgb.shape[0] > 0
    np.testing.assert_array_equal(ours.rgb[:], theirs.rgb[:])
    np.testing.assert_array_equal(ours.poses, theirs.poses)
    assert str(ours.path).startswith(f"{s3_run}/{ATTEMPTS}/render/")
    logs = invoke("logs", s3_run, f"ambient.{DEMO_VIDEO}", "--stage", "render")  # as uploaded by the worker
    assert logs.exit_code == 0 and f"== logs/render/ambient.{DEMO_VIDEO}.log ==" in logs.output and "committed" in logs.output
    assert local_data(machine) == [] and sum(p.stat().st_size for p in machine.rglob("*") if p.is_file()) < 64_000


def test_verify_finds_damage_on_the_bucket_and_a_rerun_repairs_it(s3, s3_run, monkeypatch, tmp_path_factory):
    monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path_factory.mktemp("verifier")))
    before = trusted_bytes_on_store(s3, s3_run)
    prefix = s3_run.removeprefix("s3://")
    marker = store_markers(s3, s3_run)[f"render/ambient.{DEMO_VIDEO}"]
    chunk = next(f.path for f in marker.files if "/rgb/c/" in f.path)
    part = next(f.path for f in marker.files if f.path.endswith(".parquet"))
    s3.fs.rm_file(f"{prefix}/{marker.keys[chunk]}")  # a lost object
    s3.fs.pipe_file(f"{prefix}/{marker.keys[part]}", b"not parquet")  # an object replaced by other bytes
    unit = f"ambient.{DEMO_VIDEO}"
    run = RunFolder.open(s3_run)
    assert plan_stage(make_stage("render", run.job()), run).damaged == {}  # status trusts the markers ...
    found = verify_run(run, executor="local")  # ... a verify reads the bucket
    assert list(found) == [("render", unit)]
    assert {(d.path, d.problem.split(" ")[0]) for d in found[("render", unit)]} == {(chunk, "is"), (part, "has")}
    assert list(plan_stage(make_stage("render", run.job()), run).damaged) == [unit]  # recorded on the bucket
    status = invoke("status", s3_run)
    assert f"render/{unit} damaged" in status.output and f"mvpd rerun {s3_run} --stage render" in status.output, status.output
    again = invoke("rerun", s3_run, "--stage", "render", "--executor", "local")
    assert again.exit_code == 0 and "1 done, 0 failed, 11 up to date" in again.output, again.output
    assert_same_outputs(trusted_bytes_on_store(s3, s3_run), before)
    assert verify_run(RunFolder.open(s3_run), executor="local") == {}


def test_no_credential_is_written_to_the_bucket_or_the_working_copy(s3, s3_run):
    prefix = s3_run.removeprefix("s3://")
    objects = [s3.fs.cat_file(key) for key in s3.fs.find(prefix)]
    local = [p.read_bytes() for p in s3.cache.rglob("*") if p.is_file()]
    assert objects and local
    for secret in (TEST_SECRET.encode(), TEST_KEY_ID.encode()):
        assert not [b for b in objects + local if secret in b]


def test_failed_upload_leaves_nothing_visible_and_a_rerun_completes(s3, s3_run, monkeypatch, tmp_path_factory):
    before = trusted_bytes_on_store(s3, s3_run)
    calls = {"n": 0}
    real_put = object_store.RunStore.put_files

    def failing_mid_write_of_the_fifth_unit(self, uploads):
        calls["n"] += 1
        if calls["n"] == 5:  # half of one render unit's files are uploaded, then the connection fails
            real_put(self, uploads[:len(uploads) // 2])
            raise OSError("upload refused: injected failure during the 5th upload batch")
        real_put(self, uploads)

    monkeypatch.setattr(object_store.RunStore, "put_files", failing_mid_write_of_the_fifth_unit)
    result = invoke("rerun", s3_run, "--stage", "render", "--all", "--executor", "local")
    monkeypatch.setattr(object_store.RunStore, "put_files", real_put)
    assert result.exit_code == 1 and "11 done, 1 failed" in result.output, result.output
    # The failed unit has no marker on the bucket, though its first four files were uploaded.
    assert len([k for k in store_markers(s3, s3_run) if k.startswith("render/")]) == 11
    status = invoke("status", s3_run)
    assert "injected failure during the 5th upload batch" in status.output or "OSError" in status.output, status.output
    # A fresh reader sees 11 videos: the failed attempt's uploaded keys are named by no marker.
    monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path_factory.mktemp("reader")))
    query = invoke("query", s3_run, "select count(*) as n from videos", "--format", "json")
    assert json.loads(query.output)[0]["n"] == 11, query.output
    again = invoke("rerun", s3_run, "--stage", "render", "--executor", "local")
    assert again.exit_code == 0 and "1 done, 0 failed, 11 up to date" in again.output, again.output
    assert_same_outputs(trusted_bytes_on_store(s3, s3_run), before)


def test_wrong_bucket_wrong_credentials_and_no_endpoint_fail_in_one_line(s3, tmp_path, monkeypatch):
    job = tmp_path / "demo.yaml"
    job.write_text(DEMO_SHAPED_JOB, encoding="utf-8")
    monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path / "cache"))

    def refused(url: str, expected: str) -> None:
        result = invoke("submit", job, "--run-dir", url, "--executor", "local")
        assert result.exit_code == 2, result.output
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert len(lines) == 1 and expected in lines[0], result.output
        assert not list((tmp_path / "cache").glob("*/_state/*/*.json"))  # no unit ran

    refused(f"s3://no-such-bucket-{BUCKET}/run", "does not exist")
    from moto import settings

    monkeypatch.setattr(settings, "INITIAL_NO_AUTH_ACTION_COUNT", 0)  # the server now checks credentials
    refused(s3.url("runs/refused"), "access refused")
    monkeypatch.undo()
    monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://127.0.0.1:9")  # nothing listens on the discard port
    forget_clients()
    try:
        refused(s3.url("runs/unreachable"), "cannot be")
    finally:
        monkeypatch.undo()
        forget_clients()
    assert not s3.fs.exists(f"{BUCKET}/runs/refused") and not s3.fs.exists(f"{BUCKET}/runs/unreachable")
