"""The stage runtime on a tiny stage: skip finished units, record failures, rerun exactly what is stale."""

from __future__ import annotations

import sys

import pytest
import ray.cloudpickle

from pipeline.config import Embodiment, Job, SceneSources, ProceduralSource
from pipeline.io.query import query
from pipeline.runtime.executor import run_stage
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.status import read_status
from tests.runtime import tiny_stage
from tests.runtime.tiny_stage import QuickTimeoutStage, TinyStage, UnsendableStage

# Ray workers cannot import the tests package: ship the tiny stage's module by value.
ray.cloudpickle.register_pickle_by_value(sys.modules[tiny_stage.__name__])


def make_job(heights: dict[str, list[float]], seed: int = 0) -> Job:
    return Job(name="tiny", seed=seed, scenes=SceneSources(procedural=ProceduralSource(count=1)),
               embodiments=[Embodiment(name=name, placements=h) for name, h in heights.items()])


@pytest.fixture
def run(tmp_path) -> RunFolder:
    return RunFolder.create(tmp_path / "run", make_job({"a": [1.0], "b": [0.5], "c": [0.1]}))


def values(run: RunFolder) -> dict[str, int]:
    return {r["unit"]: r["value"] for r in run.read("tiny").to_pylist()}


def test_second_run_of_a_finished_stage_runs_nothing(ray_session, run):
    first = run_stage(TinyStage(run.job()), run)
    assert [o.unit for o in first.outcomes] == ["a", "b", "c"] and not first.failed
    second = run_stage(TinyStage(run.job()), run)
    assert second.outcomes == [] and second.skipped == 3  # 3 up to date, 0 run
    assert len(run.read("tiny")) == 3  # no duplicated rows


def test_failing_unit_is_reported_others_finish_and_rerun_runs_exactly_it(ray_session, run):
    (run.root / "control").mkdir()
    (run.root / "control" / "b.fail").touch()
    report = run_stage(TinyStage(run.job()), run)
    assert [o.unit for o in report.failed] == ["b"]
    assert report.failed[0].error_type == "ValueError" and "told to fail" in report.failed[0].message
    assert sorted(values(run)) == ["a", "c"]
    status = read_status(run, "tiny")
    assert status[("tiny", "b")].state == "failed" and status[("tiny", "a")].state == "done"
    assert "told to fail" in (run.root / status[("tiny", "b")].log_path).read_text()
    assert run.marker("tiny", "b") is None

    (run.root / "control" / "b.fail").unlink()  # the cause is fixed
    again = run_stage(TinyStage(run.job()), run)
    assert [o.unit for o in again.outcomes] == ["b"] and not again.failed
    assert read_status(run, "tiny")[("tiny", "b")].attempt == 2  # 1 failed + 1 good
    assert sorted(values(run)) == ["a", "b", "c"]


def test_changing_the_job_reruns_exactly_the_stale_units(ray_session, run):
    run_stage(TinyStage(run.job()), run)
    before = values(run)
    changed = make_job({"a": [1.0], "b": [0.7], "c": [0.1]})  # only b's placements change
    run.save_job(changed)
    report = run_stage(TinyStage(changed), run)
    assert [o.unit for o in report.outcomes] == ["b"]
    assert values(run) == before  # same seed, same unit ids: the same draws
    shrunk = make_job({"a": [1.0], "c": [0.1]})  # b leaves the job: its rows and marker go
    report = run_stage(TinyStage(shrunk), run)
    assert report.outcomes == [] and sorted(values(run)) == ["a", "c"]
    assert run.marker("tiny", "b") is None and not (run.root / "tiny_files" / "b.txt").exists()


def test_force_reruns_every_unit_with_identical_output(ray_session, run):
    run_stage(TinyStage(run.job()), run)
    before = {p.name: p.read_bytes() for p in (run.root / "tiny").iterdir()}
    report = run_stage(TinyStage(run.job()), run, force=True)
    assert len(report.outcomes) == 3
    assert {p.name: p.read_bytes() for p in (run.root / "tiny").iterdir()} == before  # bit-identical parts


def test_killed_worker_is_retried_by_ray_and_leaves_no_partial_output(ray_session, run):
    (run.root / "control").mkdir()
    (run.root / "control" / "b.kill").touch()
    report = run_stage(TinyStage(run.job()), run)
    assert (run.root / "control" / "b.killed").exists()  # the first attempt really died
    assert not report.failed and sorted(values(run)) == ["a", "b", "c"]
    assert len(run.read("tiny")) == 3
    assert not (run.root / "_staging" / "tiny").exists()  # the dead attempt's staging is gone
    assert sorted(p.name for p in (run.root / "tiny_files").iterdir()) == ["a.txt", "b.txt", "c.txt"]


def test_query_answers_sql_over_written_tables(ray_session, run):
    run_stage(TinyStage(run.job()), run)
    result = query(run, "select count(*) as n, min(unit) as first from tiny").fetchall()
    assert result == [(3, "a")]
    statuses = query(run, "select state, count(*) from status group by state").fetchall()
    assert statuses == [("done", 3)]


def test_unit_running_past_its_timeout_is_cancelled_and_recorded(ray_session, run):
    (run.root / "control").mkdir()
    (run.root / "control" / "c.hang").touch()
    report = run_stage(QuickTimeoutStage(run.job()), run)
    assert [(o.unit, o.error_type) for o in report.failed] == [("c", "UnitTimeout")]
    assert sorted(values(run)) == ["a", "b"] and run.marker("tiny", "c") is None


def test_a_task_ray_could_not_start_counts_one_attempt(ray_session, run):
    """A Ray error that is no lost worker (here: an argument that cannot be set up) ended the first try: attempt
    1 in the outcome and the status table, not 1 + max_retries."""
    report = run_stage(UnsendableStage(run.job()), run, executor="ray")
    assert sorted(o.unit for o in report.failed) == ["a", "b", "c"]
    assert {o.attempt for o in report.failed} == {1}
    assert {o.attempt for o in read_status(run).values()} == {1}
