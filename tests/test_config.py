"""Job files: typed, validated, defaults filled, one-line errors naming the key path."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest

from pipeline.config import ConfigError, EvaluateConfig, Job, load_job

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
    mvpd = load_mvpd_job(tmp_path)
    sensor = mvpd.embodiments[0].sensor
    assert (sensor.width, sensor.height, sensor.hfov) == (640, 480, 69.0)
    assert sorted(mvpd.embodiments[0].placements) == [0.1, 1.0]
    assert mvpd.plan.trajectories_per_scene == 50


def load_mvpd_job(tmp_path: Path, text: str | None = None) -> Job:
    """jobs/mvpd.yaml (or `text` in its place) with its downloads stood in for by an empty folder and file.

    Without open_clip and torch (CI) the CLIP encoder is refused with one line naming the fallback, and
    the job is checked with the fallback its comment names (`encoder: tfidf`).
    """
    jobs = tmp_path / "jobs"
    if not jobs.exists():
        shutil.copytree(REPO / "jobs", jobs)
    (tmp_path / "data" / "hm3dsem").mkdir(parents=True, exist_ok=True)
    (tmp_path / "data" / "clip").mkdir(parents=True, exist_ok=True)
    (tmp_path / "data" / "clip" / "ViT-L-14-openai.bin").write_bytes(b"")
    text = text if text is not None else (REPO / "jobs" / "mvpd.yaml").read_text()
    (jobs / "mvpd.yaml").write_text(text)
    if all(importlib.util.find_spec(m) for m in ("open_clip", "torch")):
        return load_job(jobs / "mvpd.yaml")
    with pytest.raises(ConfigError, match="split.zero_shot.encoder: clip needs .*or choose encoder tfidf"):
        load_job(jobs / "mvpd.yaml")
    assert "#   encoder: tfidf" in text  # the fallback is named where the encoder is chosen
    (jobs / "mvpd.yaml").write_text(text.replace("encoder: clip", "encoder: tfidf", 1))
    return load_job(jobs / "mvpd.yaml")


def test_mvpd_job_splits_as_the_release(tmp_path):
    split = load_mvpd_job(tmp_path).split
    assert split is not None
    assert (split.scenes.mode, split.scenes.val_share, split.empty_threshold) == ("hm3d", 0.5, 0.5)
    zero_shot = split.zero_shot
    assert (zero_shot.clusters, zero_shot.unseen_fraction, zero_shot.categories) == (20, 0.2, [39, 40])
    assert zero_shot.model == "ViT-L-14" and zero_shot.weights == tmp_path / "data" / "clip" / "ViT-L-14-openai.bin"
    assert load_mvpd_job(tmp_path / "again").evaluate == EvaluateConfig()  # the published protocol


def test_mvpd_job_spot_lights_are_one_uncomment_away(tmp_path):
    text = (REPO / "jobs" / "mvpd.yaml").read_text()
    lit = text.replace("  # - embodiments/mvpd_spot", "  - embodiments/mvpd_spot")
    job = load_mvpd_job(tmp_path, lit)
    assert [e.name for e in job.embodiments] == ["mvpd", "mvpd_spot20", "mvpd_spot200"]
    assert [e.illumination.power for e in job.embodiments[1:]] == [20.0, 200.0]


def test_one_percent_job_is_mvpd_at_one_percent():
    job = load_job(REPO / "jobs" / "mvpd-1pct.yaml")
    assert job.scenes.procedural is not None
    scenes, paths = job.scenes.procedural.count, job.plan.trajectories_per_scene
    heights = job.embodiments[0].placements
    assert scenes * paths * len(heights) == 180  # 1 % of MVPd's 18,000 videos
    assert (job.plan.min_frames, job.plan.max_frames) == (100, 600)
    assert (job.embodiments[0].sensor.width, job.embodiments[0].sensor.height) == (640, 480)
    split = job.split
    assert split is not None and split.zero_shot.clusters == 20
    fractions = split.scenes.fractions
    assert (fractions.train * scenes, fractions.val * scenes, fractions.test * scenes) == (8, 1, 1)  # 144/18/18


def test_fields_added_later_leave_the_hashes_of_existing_jobs_as_they_were():
    """Units of a run made before scan sources, materials and indirect light existed stay up to date after the
    upgrade when the job uses none of them: their hashed settings are those of fd326c4, literally."""
    from pipeline.config import Illumination, MeshFolderSource

    job = load_job(Path(__file__).resolve().parents[1] / "jobs" / "demo.yaml")
    assert job.scenes.hashed() == {"procedural": {"count": 3, "seed": 0, "detail": 0.1, "min_rooms": 3, "max_rooms": 8,
                                                  "floors": 1}, "hm3dsem": None, "meshes": None, "mvpd": None}
    assert [e.illumination.hashed() for e in job.embodiments] == [
        {"kind": "ambient", "power": 0.0, "cone": 180.0, "blend": 1.0},
        {"kind": "spot", "power": 20.0, "cone": 180.0, "blend": 1.0}]
    assert MeshFolderSource(root=Path("/scans")).hashed() == {"root": "/scans", "pattern": "*", "labels": "auto",
                                                             "up_axis": "y"}
    # A later field that is used is hashed, so changing it reruns what it changes.
    principled = Illumination(kind="spot", power=20.0, material="principled").hashed()
    assert principled["material"] == "principled" and "indirect" not in principled
    assert MeshFolderSource(root=Path("/scans"), scale=0.01).hashed()["scale"] == 0.01
