"""The commit protocol on an object store without rename (fsspec's memory store; fast, in-process)."""

from __future__ import annotations

import json
import time
import uuid
from pathlib import Path

import fsspec
import pytest
from fsspec.implementations.memory import MemoryFileSystem
from typer.testing import CliRunner

from pipeline.cli.main import app

from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources
from pipeline.runtime.attempt import execute_unit
from pipeline.store.lock import LOCK_KEY
from pipeline.store.remote import RunStore, remote_url
from pipeline.store.names import ATTEMPTS
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.store.datasets import read_dataset
from pipeline.store.tables import to_table


def outcome_rows(*units: str) -> dict:
    return {"status": to_table("status", [{"stage": "fixture", "unit": u, "state": "done", "attempt": 1, "error_type": "",
                                            "message": "", "log_path": "", "seconds": 0.0} for u in units])}


class FailingOnWrite(MemoryFileSystem):
    """A memory store whose n-th upload fails, as a full disk or a dropped connection would."""

    protocol = "failingmem"
    fail_at = 2
    uploads = 0

    @classmethod
    def _strip_protocol(cls, path: str) -> str:
        return super()._strip_protocol(str(path).replace("failingmem://", "memory://", 1))

    def put_file(self, lpath, rpath, *args, **kwargs):
        type(self).uploads += 1
        if type(self).uploads == self.fail_at:
            raise OSError(f"upload of {rpath} failed: connection reset")
        return super().put_file(lpath, rpath, *args, **kwargs)


class TwoTableStage(Stage):
    """Writes two parts per unit, so an upload can fail between them."""

    name = "fixture"

    def units(self, run: RunFolder) -> list[Unit]:
        return [Unit("u1")]

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        for dataset, table in outcome_rows(unit.id).items():
            context.write_table(dataset, table)
        context.staged_path("extra/notes.txt").write_text("second file", encoding="utf-8")
        return UnitResult()


@pytest.fixture
def url() -> str:
    return f"memory://mvpd-tests/{uuid.uuid4().hex}"


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("MVPD_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_urls_and_paths():
    assert remote_url("s3://bucket/prefix/") == "s3://bucket/prefix"
    assert remote_url(Path("s3://bucket/prefix")) == "s3://bucket/prefix"  # a Path collapses '//'
    assert remote_url("file:///tmp/run") is None and remote_url("/tmp/run") is None and remote_url("runs/demo") is None
    assert str(RunFolder("file:///tmp/some-run").root) == "/tmp/some-run"


def local_outputs(folder: Path) -> list[Path]:
    """Parquet parts and Zarr files under a local folder (a remote run's local folder must hold none)."""
    return [p for p in folder.rglob("*") if p.is_file() and (p.suffix == ".parquet" or ".zarr" in p.as_posix())]


def test_another_machine_reads_only_what_markers_name_in_place(url, cache, monkeypatch):
    writer = RunFolder.prepare(url)
    writer.commit_tables("fixture", "u1", outcome_rows("u1"))
    store = fsspec.filesystem("memory")
    prefix = url.removeprefix("memory://")
    # An attempt that died after uploading its part: its key exists, no marker names it.
    store.pipe_file(f"{prefix}/{ATTEMPTS}/fixture/u2/dead.1.1/status/part-u2.parquet",
                    store.cat_file(next(k for k in store.find(prefix) if k.endswith("part-u1.parquet"))))
    assert not store.exists(f"{prefix}/status")  # no object at a logical path: nothing was renamed into place
    monkeypatch.setenv("MVPD_CACHE_DIR", str(cache.parent / "other-machine"))
    reader = RunFolder(url)
    assert reader.root != writer.root
    assert read_dataset(reader, "status").column("unit").to_pylist() == ["u1"]
    assert local_outputs(reader.root) == [] and local_outputs(writer.root) == []  # read in place, no copy
    # The unit's marker goes from the store (retired elsewhere): its rows go with it at once.
    store.rm_file(f"{prefix}/_state/fixture/u1.json")
    assert read_dataset(reader, "status").num_rows == 0


def test_a_commit_replaces_the_previous_attempts_objects(url):
    run = RunFolder.prepare(url)
    first = run.commit_tables("fixture", "u1", outcome_rows("u1"))
    second = run.commit_tables("fixture", "u1", outcome_rows("u1"))
    store = fsspec.filesystem("memory")
    prefix = url.removeprefix("memory://")
    assert set(first.keys.values()).isdisjoint(second.keys.values())
    assert all(store.exists(f"{prefix}/{k}") for k in second.keys.values())
    assert not any(store.exists(f"{prefix}/{k}") for k in first.keys.values())


def test_a_failed_upload_fails_the_unit_and_marks_nothing_done(tmp_path):
    fsspec.register_implementation("failingmem", FailingOnWrite, clobber=True)
    FailingOnWrite.uploads = 0
    url = f"failingmem://mvpd-tests/{uuid.uuid4().hex}"
    run = RunFolder.prepare(url)
    job = Job(name="fixture", seed=0, scenes=SceneSources(procedural=ProceduralSource(count=1)),
              embodiments=[Embodiment(name="a", placements=[1.0])])
    outcome = execute_unit(TwoTableStage(job), run, Unit("u1"), attempt=1)
    assert outcome.failed and outcome.error_type == "OSError" and "connection reset" in outcome.message
    assert FailingOnWrite.uploads >= 2
    store = FailingOnWrite()
    prefix = url.removeprefix("failingmem://")
    assert not store.exists(f"{prefix}/_state/fixture/u1.json") and run.marker("fixture", "u1") is None
    assert read_dataset(run, "status").num_rows == 0
    # The next attempt (the store works again) commits the unit whole.
    FailingOnWrite.fail_at = -1
    try:
        assert not execute_unit(TwoTableStage(job), run, Unit("u1"), attempt=2).failed
    finally:
        FailingOnWrite.fail_at = 2
    marker = run.marker("fixture", "u1")
    assert marker is not None and sorted(marker.keys) == ["extra/notes.txt", "status/part-u1.parquet"]
    assert store.exists(f"{prefix}/_state/fixture/u1.json")
    assert read_dataset(run, "status").column("unit").to_pylist() == ["u1"]


class CopyingStage(Stage):
    """Reads the `status` rows an upstream unit committed and commits them again as its own."""

    name = "fixture"

    def units(self, run: RunFolder) -> list[Unit]:
        return [Unit("copy")]

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        context.write_table("status", context.run.read("status"))
        return UnitResult()


def test_a_worker_reads_its_inputs_in_place_and_commits_by_upload(url, cache, monkeypatch):
    run = RunFolder.prepare(url)
    run.commit_tables("upstream", "u1", outcome_rows("u1"))
    monkeypatch.setenv("MVPD_CACHE_DIR", str(cache.parent / "worker-machine"))
    worker = RunFolder(url)  # what a Ray task is handed: the URL
    job = Job(name="fixture", seed=0, scenes=SceneSources(procedural=ProceduralSource(count=1)),
              embodiments=[Embodiment(name="a", placements=[1.0])])
    assert not execute_unit(CopyingStage(job), worker, Unit("copy"), attempt=1).failed
    assert local_outputs(worker.root) == []  # neither the upstream part nor its own output stayed local
    assert read_dataset(run, "status").column("unit").to_pylist() == ["u1", "u1"]
    assert sorted(run.marker("fixture", "copy").keys) == ["status/part-copy.parquet"]


def test_a_driver_starting_beside_another_is_told_who_holds_the_run(url, tmp_path):
    """The first driver's lock is the first key of a new run: a second driver finds the lock (and is told who
    holds it), not "a folder that is not empty and has no job.yaml"."""
    holder = {"host": "elsewhere", "pid": 1, "process_started": 0, "started": 0, "owner": "elsewhere.1.0",
              "heartbeat": time.time()}
    RunStore(url).put_text(LOCK_KEY, json.dumps(holder))
    job = tmp_path / "job.yaml"
    job.write_text("name: race\nscenes: {procedural: {count: 1}}\nembodiments: [{name: e}]\n")
    result = CliRunner().invoke(app, ["submit", str(job), "--run-dir", url, "--executor", "local"])
    assert result.exit_code == 2, result.output
    assert "already being run by pid 1 on elsewhere" in result.output and "no job.yaml" not in result.output
