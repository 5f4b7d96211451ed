"""The Ray executor submits with backpressure: at most `runtime.max_in_flight` tasks wait at once, and the
stage is put into Ray's object store once, not shipped with every task (what keeps the driver small at
18,000 units; benchmarks/bench_scaling.py measures it at that size)."""

from __future__ import annotations

import sys
from typing import Any

import pytest
import ray.cloudpickle

from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources
from pipeline.runtime.executor import run_stage
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult

UNITS = 8


class CountedStage(Stage):
    """Eight units that commit one small file each."""

    name = "counted"

    def units(self, run: RunFolder) -> list[Unit]:
        return [Unit(f"u{index}") for index in range(UNITS)]

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        context.staged_path(f"counted/{unit.id}.txt").write_text(unit.id)
        return UnitResult()


ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Ray workers cannot import tests/


def job(max_in_flight: int) -> Job:
    return Job(name="counted", seed=0, scenes=SceneSources(procedural=ProceduralSource(count=1)),
               embodiments=[Embodiment(name="a", placements=[1.0])], runtime={"max_in_flight": max_in_flight})


@pytest.mark.parametrize("max_in_flight, bound", [(1, 1), (3, 3), (0, 2)])  # 0: the session's 2 CPUs
def test_tasks_in_flight_never_exceed_the_bound_and_the_stage_is_put_once(
        ray_session, tmp_path, monkeypatch, max_in_flight: int, bound: int) -> None:
    waited_on: list[int] = []
    put: list[Any] = []
    real_wait, real_put = ray_session.wait, ray_session.put

    def counting_wait(refs: list[Any], *args: Any, **kwargs: Any) -> Any:
        waited_on.append(len(refs))  # run_on_ray waits on exactly the tasks in flight
        return real_wait(refs, *args, **kwargs)

    def counting_put(value: Any, *args: Any, **kwargs: Any) -> Any:
        put.append(value)
        return real_put(value, *args, **kwargs)

    monkeypatch.setattr(ray_session, "wait", counting_wait)
    monkeypatch.setattr(ray_session, "put", counting_put)
    run = RunFolder.create(tmp_path / "run", job(max_in_flight))
    report = run_stage(CountedStage(run.job()), run, executor="ray")
    assert report.done == UNITS and not report.failed
    assert max(waited_on) == bound  # reached (so the probe sees the queue) and never exceeded
    assert [type(value) for value in put] == [CountedStage]  # one put for all eight tasks
