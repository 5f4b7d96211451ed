"""Job files: typed, validated, defaults filled, one-line errors naming the key path."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from pipeline.config import ConfigError, load_job

REPO = Path(__file__).resolve().parents[1]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "job.yaml"
    path.write_text(text)
    return path


GOOD = """
name: t
scenes: {procedural: {count: 2}}
embodiments: [{name: e, sensor: {width: 64, height: 48}}]
"""


def test_defaults_are_filled_and_hash_is_stable(tmp_path):
    job = load_job(write(tmp_path, GOOD))
    assert job.plan.trajectories_per_scene == 50 and job.plan.max_step == 0.05
    assert job.embodiments[0].placements == [1.0, 0.1]
    assert job.hash() == load_job(write(tmp_path, GOOD)).hash()
    assert job.hash() != load_job(write(tmp_path, GOOD.replace("count: 2", "count: 3"))).hash()


@pytest.mark.parametrize(
    "text, expected",
    [
        (GOOD.replace("count: 2", "cuont: 2"), "scenes.procedural.cuont: unknown key"),
        (GOOD.replace("width: 64", "width: -64"), "embodiments.0.sensor.width: Input should be greater than or equal to 8"),
        (GOOD.replace("{procedural: {count: 2}}", "{meshes: {root: no/such/folder}}"), "scenes.meshes.root: folder"),
        (GOOD.replace("name: t", "name: [t"), "not valid YAML"),
        (GOOD + "seed: -1\n", "seed: Input should be greater than or equal to 0"),
        (GOOD.replace("width: 64", "width: 64, hfov: .inf"), "embodiments.0.sensor.hfov: Input should be a finite number"),
        (GOOD + "plan: {max_step: .nan}\n", "plan.max_step: Input should be a finite number"),
        (GOOD.replace("name: t", "name: '..'"), "name: String should match pattern"),
    ],
)
def test_bad_job_files_give_one_line_errors_naming_the_key(tmp_path, text, expected):
    with pytest.raises(ConfigError) as error:
        load_job(write(tmp_path, text))
    message = str(error.value)
    assert expected in message and "\n" not in message
    assert str(tmp_path / "job.yaml") in message


def test_intrinsics_from_hfov_match_mvpd():
    from pipeline.config import Sensor

    fx, fy, cx, cy = Sensor(width=640, height=480, hfov=69.0).intrinsics()
    assert round(fx, 4) == 465.6029 and fx == fy and (cx, cy) == (320.0, 240.0)


def test_shipped_jobs_load(tmp_path):
    job = load_job(REPO / "jobs" / "demo.yaml")
    assert job.scenes.procedural is not None and len(job.embodiments) == 2
    # The MVPd job points at a licensed download; give it an (empty) folder to check the rest.
    shutil.copytree(REPO / "jobs", tmp_path / "jobs")
    (tmp_path / "data" / "hm3dsem").mkdir(parents=True)
    mvpd = load_job(tmp_path / "jobs" / "mvpd.yaml")
    sensor = mvpd.embodiments[0].sensor
    assert (sensor.width, sensor.height, sensor.hfov) == (640, 480, 69.0)
    assert sorted(mvpd.embodiments[0].placements) == [0.1, 1.0]
    assert mvpd.plan.trajectories_per_scene == 50
