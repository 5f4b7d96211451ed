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


def test_the_model_and_the_check_are_medians_of_renders_in_turns(bench_scaling, monkeypatch: pytest.MonkeyPatch,
                                                                 tmp_path: Path) -> None:
    # Stop 36's three quiet runs, as one calibration of three rounds: one run's model could say 33.7 or 44.4.
    drift = iter([26.38, 22.08, 21.93, 20.03, 24.87, 21.15])
    taken = []

    def render(command, log, frames, wait_s, allow_load):
        taken.append(log.name)
        return {"cpu_ms_per_frame": next(drift), "quiet": True}

    monkeypatch.setattr(bench_scaling, "measured_render", render)
    monkeypatch.setattr(bench_scaling.subprocess, "run", lambda *args, **kwargs: None)
    monkeypatch.setattr(bench_scaling, "RENDER_ONE_HOUSE", tmp_path / "one_house.json")
    monkeypatch.setattr(bench_scaling, "wait_for_quiet", lambda wait_s, allow_load: 0.5)
    monkeypatch.setattr(bench_scaling, "frame_cpu_ms", lambda run_dir, store: 16.58)
    result = bench_scaling.calibration(tmp_path, 0.0, allow_load=False, repeats=3)
    assert taken == ["calibration-0.log", "check-0.log", "check-1.log", "calibration-1.log", "calibration-2.log",
                     "check-2.log"]  # the order swapped each round: both see the same drift
    projection = result["projection"]
    assert projection["model_ms_per_frame_per_core"] == 24.87 and projection["check_ms_per_frame_per_core"] == 21.93
    assert projection["model_renders_ms"]["runs"] == [26.38, 20.03, 24.87]
    assert projection["render_core_hours"]["model"] == 41.9 and projection["render_core_hours"]["model_range"] == [33.7, 44.4]
    assert not projection["met"] and not projection["settled"]  # the median says no, and the spread could flip it
    # The stage's share on top of the frames' own CPU, both measured in this run (not an older bench file).
    assert projection["frame_cpu_ms"] == 16.58 and projection["stage_over_frame"] == 1.5  # 24.87 / 16.58
    assert (tmp_path / "one_house.json").exists()


def test_a_projection_every_render_agrees_on_is_settled(bench_scaling) -> None:
    projection = bench_scaling.calibration_projection([21.0, 22.0, 23.0], [22.5, 21.5, 22.0])
    assert projection["render_core_hours"] == {"model": 37.0, "check": 37.0, "model_range": [35.4, 38.7]}
    assert projection["met"] and projection["settled"] and projection["within_target_error"]
    assert projection["model_error"] == 0.0
    far = bench_scaling.calibration_projection([20.0], [24.0])
    assert far["model_error"] == 0.2 and not far["within_target_error"]
