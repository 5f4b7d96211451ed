"""A driver whose run lock was taken over commits nothing more and stops (issue 20, point 2), on local disk:
inline, where the driver's own units check the fence, and on Ray, where the workers do."""

from __future__ import annotations

import json
import sys

import pytest
import ray.cloudpickle

from pipeline.runtime.executor import run_stage
from pipeline.store.lock import LeaseLostError
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.status import read_status
from tests.runtime import tiny_stage
from tests.runtime.test_executor import make_job
from tests.runtime.tiny_stage import TinyStage

ray.cloudpickle.register_pickle_by_value(sys.modules[tiny_stage.__name__])


@pytest.fixture
def run(tmp_path) -> RunFolder:
    return RunFolder.create(tmp_path / "run", make_job({"a": [1.0], "b": [0.5], "c": [0.1]}))


def take_over(run: RunFolder) -> None:
    """Another driver takes the lock over (as it may once this one's heartbeat is stale)."""
    path = run.root / "_state" / "lock.json"
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "owner": "elsewhere.7.0", "host": "elsewhere", "pid": 7}))


def test_inline_units_stop_committing_once_the_lock_is_taken_over(run):
    with run.locked():
        with pytest.raises(LeaseLostError, match="now held by pid 7 on elsewhere") as stopped:
            run_stage(TinyStage(run.job()), run, executor="local", on_unit=lambda outcome: take_over(run))
    assert "\n" not in str(stopped.value)
    assert sorted(run.markers("tiny")) == ["a"]  # the first unit committed before the takeover, no other
    assert read_status(run, "tiny") == {}  # nor the status table
    assert json.loads((run.root / "_state" / "lock.json").read_text())["owner"] == "elsewhere.7.0"  # left alone


def test_ray_workers_check_the_fence_and_the_driver_stops(ray_session, run):
    with run.locked():
        take_over(run)
        with pytest.raises(LeaseLostError, match="now held by pid 7 on elsewhere"):
            run_stage(TinyStage(run.job()), run, executor="ray")
    assert run.markers("tiny") == {}
