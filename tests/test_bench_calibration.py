"""The cost model's calibration (benchmarks/bench_scaling.py): refused or flagged under load, one house of the 1 % job."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from pipeline.config import load_job

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench_scaling():
    sys.path.insert(0, str(REPO))
    try:
        yield importlib.import_module("benchmarks.bench_scaling")
    finally:
        sys.path.remove(str(REPO))


def test_a_loaded_machine_is_refused_in_one_line_or_flagged(bench_scaling, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bench_scaling.os, "getloadavg", lambda: (3.2, 3.0, 2.5))
    with pytest.raises(bench_scaling.LoadTooHigh) as refused:
        bench_scaling.wait_for_quiet(0.0, allow_load=False)
    assert "3.20 >= 1.5" in str(refused.value) and "\n" not in str(refused.value)
    assert bench_scaling.wait_for_quiet(0.0, allow_load=True) == 3.2  # run, and the caller flags it


def test_the_calibration_waits_for_the_load_to_fall(bench_scaling, monkeypatch: pytest.MonkeyPatch) -> None:
    loads = iter([2.4, 1.9, 1.49, 9.0])  # a render's own load decaying, then (never read) a spike
    monkeypatch.setattr(bench_scaling.os, "getloadavg", lambda: (next(loads), 0.0, 0.0))
    monkeypatch.setattr(bench_scaling.time, "sleep", lambda seconds: None)
    assert bench_scaling.wait_for_quiet(60.0, allow_load=False) == 1.49


def test_the_calibration_job_is_one_house_of_the_one_percent_job(bench_scaling, tmp_path: Path) -> None:
    job = load_job(bench_scaling.one_house_job(tmp_path))
    full = load_job(REPO / "jobs" / "mvpd-1pct.yaml")
    assert job.scenes.procedural.count == 1 and full.scenes.procedural.count > 1
    assert job.model_copy(update={"scenes": full.scenes}) == full  # nothing else differs
