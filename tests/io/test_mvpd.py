"""MVPd release export and import: pose convention, id encoding, round trip, the real example, bad input.

Imports run the `import` stage on Ray (the session's `ray_session`), one task per video.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import typer
from PIL import Image
from typer.testing import CliRunner

from pipeline.cli import mvpd_io
from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources, Sensor
from pipeline.io.mvpd import MvpdExportError, MvpdFormatError, export_release, import_release
from pipeline.io.mvpd import export as mvpd_export
from pipeline.io.mvpd.layout import (
    color_to_object_id,
    mvpd_categories,
    ids_to_png,
    matrix_to_quaternion,
    object_id_to_color,
    png_to_ids,
    pose_from_mvpd,
    pose_to_mvpd,
    quaternion_to_matrix,
)
from pipeline.io.mvpd.panoptic_json import PanopticJsonSpool
from pipeline.io.tables import to_table
from pipeline.io.zarr_video import VideoWriter, open_video
from pipeline.store.run_folder import RunFolder

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "vsq_small" / "MVPd"
WIDTH, HEIGHT, FRAMES = 64, 48, 5
SCENE = "00800-TINYscene01"
# Object ids are HM3DSem colours 0xRRGGBB; category 0 (unmapped) becomes void in MVPd.
OBJECTS = {0x1A2B3C: 1, 0x00FF00: 2, 0xC4FBAF: 39, 0x000007: 5, 0x808080: 0}
VIDEOS = {f"{SCENE}.0000000003.0000001000": False, f"{SCENE}.0000000003.0000000100": True}  # name: has an empty frame


def random_pose(rng: np.random.Generator) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = quaternion_to_matrix(rng.normal(size=4))
    pose[:3, 3] = rng.uniform(-5, 5, size=3)
    return pose


# ------------------------------------------------------------------------------------ conventions


def test_pose_conversion_round_trips_both_ways() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        pose = random_pose(rng)
        position, rotation = pose_to_mvpd(pose)
        np.testing.assert_allclose(pose_from_mvpd(position, rotation), pose, atol=1e-9)
        again = pose_to_mvpd(pose_from_mvpd(position, rotation))
        np.testing.assert_allclose(again[0], position, atol=1e-9)
        np.testing.assert_allclose(again[1], rotation, atol=1e-9)


def test_pose_conversion_sees_the_same_point_in_both_conventions() -> None:
    """A world point in front of our camera lies at (x, -y, -z) in MVPd's OpenGL-like camera frame."""
    rng = np.random.default_rng(1)
    pose = random_pose(rng)
    point_world = pose[:3, :3] @ np.array([0.3, -0.2, 2.0]) + pose[:3, 3]  # 2 m ahead, up-left in OpenCV
    position, rotation = pose_to_mvpd(pose)
    mvpd_world = np.array([1.0, -1.0, -1.0]) * point_world  # MVPd's world: ours turned 180 deg about X
    in_mvpd_camera = quaternion_to_matrix(np.array(rotation)).T @ (mvpd_world - np.array(position))
    np.testing.assert_allclose(in_mvpd_camera, [0.3, 0.2, -2.0], atol=1e-9)  # -Z forward, +Y up


def test_identity_pose_maps_to_identity_rotation_and_flipped_position() -> None:
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 1.5, -2.0]
    position, rotation = pose_to_mvpd(pose)
    assert position == [1.0, -1.5, 2.0]
    assert rotation == [1.0, 0.0, 0.0, 0.0]


def test_quaternion_from_matrix_is_canonical_near_180_degrees() -> None:
    half_turn = np.diag([1.0, -1.0, -1.0])  # 180 deg about X: the unstable case of the trace formula
    np.testing.assert_allclose(matrix_to_quaternion(half_turn), [0.0, 1.0, 0.0, 0.0], atol=1e-12)
    assert matrix_to_quaternion(quaternion_to_matrix(np.array([-0.5, 0.5, 0.5, 0.5])))[0] == pytest.approx(0.5)


def test_png_encoding_is_coco_panoptic() -> None:
    ids = np.array([[0, 1, 256, 65536, 0xC4FBAF]], dtype=np.uint32)
    png = ids_to_png(ids)
    assert png[0, 1].tolist() == [1, 0, 0]  # id = R + 256 G + 256^2 B
    assert png[0, 2].tolist() == [0, 1, 0]
    assert png[0, 3].tolist() == [0, 0, 1]
    np.testing.assert_array_equal(png_to_ids(png), ids)
    assert object_id_to_color(0xC4FBAF) == [196, 251, 175]
    assert color_to_object_id([196, 251, 175]) == 0xC4FBAF


# ------------------------------------------------------------------------------- a tiny run


def tiny_job() -> Job:
    sensor = Sensor(width=WIDTH, height=HEIGHT, hfov=69.0)
    return Job(name="tiny", scenes=SceneSources(procedural=ProceduralSource(count=1)),
               embodiments=[Embodiment(name="cam", sensor=sensor, placements=[1.0, 0.1])])


def tiny_frames(rng: np.random.Generator, has_empty_frame: bool) -> list[dict[str, np.ndarray]]:
    """Smooth colour (so JPEG error is small), random depth, object blocks; optionally one mostly-void frame."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    frames = []
    for t in range(FRAMES):
        rgb = np.stack([(x * 4 + t * 10) % 256, (y * 5) % 256, np.full_like(x, 128)], axis=-1).astype(np.uint8)
        depth = rng.integers(0, 65536, size=(HEIGHT, WIDTH), dtype=np.uint16)
        panoptic = np.zeros((HEIGHT, WIDTH), np.uint32)
        panoptic[:, :40] = 0x1A2B3C  # wall
        panoptic[30:, :] = 0x00FF00  # floor
        panoptic[5:20, 45:60] = 0xC4FBAF
        panoptic[10 + t:14 + t, 2:9] = 0x000007
        panoptic[0:3, 60:64] = 0x808080  # unmapped: void after export
        if has_empty_frame and t == 2:
            panoptic[:40, :] = 0  # 40 of 48 rows void: more than half
        frames.append({"rgb": rgb, "depth": depth, "panoptic": panoptic})
    return frames


def write_video(run: RunFolder, job: Job, name: str, frames: list[dict[str, np.ndarray]],
                poses: list[np.ndarray]) -> None:
    embodiment = job.embodiments[0]
    fx, fy, cx, cy = embodiment.sensor.intrinsics()
    attributes = {"video_name": name, "scene_id": SCENE, "embodiment": embodiment.model_dump(mode="json"),
                  "height_m": int(name[-10:]) / 1000, "poses": [p.tolist() for p in poses],
                  "intrinsics": {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "width": WIDTH, "height": HEIGHT}}
    writer = VideoWriter(run.video_store(embodiment.name, name), FRAMES, WIDTH, HEIGHT, attributes, frames_per_shard=4)
    for frame in frames:
        writer.append(**frame)
    writer.close()
    row = {"embodiment": embodiment.name, "video_name": name, "scene_id": SCENE, "trajectory": 3,
           "height_m": attributes["height_m"], "illumination": "ambient", "sensor_model": "ideal", "frames": FRAMES,
           "width": WIDTH, "height": HEIGHT, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "exposure": float("nan"),
           "store_path": f"videos/{embodiment.name}/{name}.zarr", "bytes": 0, "render_seconds": 0.0}
    run.commit_tables("render", name, {"videos": to_table("videos", [row])})


def write_objects(run: RunFolder) -> None:
    nan = float("nan")
    rows = [{"scene_id": SCENE, "object_id": obj, "raw_name": f"thing {obj}", "mpcat40_index": cat,
             "mpcat40_name": "x", "is_stuff": cat in (1, 2, 17), "region": -1, "triangles": 10, "min_x": nan,
             "min_y": nan, "min_z": nan, "max_x": nan, "max_y": nan, "max_z": nan, "surface_area": 1.0}
            for obj, cat in OBJECTS.items()]
    run.commit_tables("shard", SCENE, {"objects": to_table("objects", rows)})


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunFolder, dict[str, dict]]:
    """A run with two videos of known pixels and poses (no rendering), and what went into it."""
    job = tiny_job()
    run = RunFolder.create(tmp_path_factory.mktemp("tiny") / "run", job)
    rng = np.random.default_rng(7)
    truth = {}
    for name, has_empty in VIDEOS.items():
        frames = tiny_frames(rng, has_empty)
        poses = [random_pose(rng) for _ in range(FRAMES)]
        write_video(run, job, name, frames, poses)
        truth[name] = {"frames": frames, "poses": poses}
    write_objects(run)
    return run, truth


@pytest.fixture(scope="module")
def exported(tiny_run: tuple[RunFolder, dict], tmp_path_factory: pytest.TempPathFactory) -> Path:
    run, _ = tiny_run
    out = tmp_path_factory.mktemp("release") / "MVPd"
    summary = export_release(run, out, split="test")
    assert summary.videos == 2 and summary.frames == 2 * FRAMES
    return out


@pytest.fixture(scope="module")
def reimported(exported: Path, tmp_path_factory: pytest.TempPathFactory, ray_session) -> RunFolder:
    run_root = tmp_path_factory.mktemp("back") / "run"
    summary = import_release(exported, "test", RunFolder(run_root), embodiment="cam")
    assert sorted(summary.imported) == sorted(VIDEOS) and summary.failed == []
    return RunFolder.open(run_root)


def test_export_writes_the_release_layout(exported: Path) -> None:
    split = exported / "test"
    name = next(iter(VIDEOS))
    for kind, suffix in (("panomasksRGB", "png"), ("imagesRGB", "jpg"), ("imagesDEPTH", "png")):
        assert sorted(p.name for p in (split / kind / name).iterdir()) == [f"{t:010d}.{suffix}" for t in range(FRAMES)]
    panoptic = json.loads((split / "panoptic_test.json").read_text())
    assert [v["video_name"] for v in panoptic["videos"]] == sorted(VIDEOS)
    assert panoptic["videos"][0]["images"][0]["file_name"] == "0000000000.jpg"
    assert [c["id"] for c in panoptic["categories"] if c["isthing"] == 0] == [1, 2, 17]
    instances = panoptic["annotations"][0]["instance_id_map"]
    # Unmapped 0x808080 is void in MVPd; the rest keep their id, their category and their colour.
    assert instances[str(0xC4FBAF)] == {"category_id": 39, "scene_name": SCENE, "color": [196, 251, 175]}
    assert sorted(int(k) for k in instances) == sorted(k for k, c in OBJECTS.items() if c > 0)


def test_export_applies_the_empty_rule_and_an_empty_zero_shot_list(exported: Path) -> None:
    empty = json.loads((exported / "test" / "empty_videos.json").read_text())
    assert empty == {"accepted": [f"{SCENE}.0000000003.0000001000"], "rejected": [f"{SCENE}.0000000003.0000000100"]}
    assert json.loads((exported / "test" / "zero_shot.json").read_text()) == {"zero-shot": []}


def test_export_depth_png_is_uint16_millimetres(exported: Path, tiny_run: tuple[RunFolder, dict]) -> None:
    import cv2

    _, truth = tiny_run
    name = next(iter(VIDEOS))
    depth = cv2.imread(str(exported / "test" / "imagesDEPTH" / name / "0000000001.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16
    np.testing.assert_array_equal(depth, truth[name]["frames"][1]["depth"])


def test_round_trip_preserves_pixels_poses_ids_and_categories(tiny_run: tuple[RunFolder, dict],
                                                              reimported: RunFolder) -> None:
    _, truth = tiny_run
    for name, expected in truth.items():
        video = open_video(reimported.video_store("cam", name))
        assert video.attrs["absent_arrays"] == []
        for t, frame in enumerate(expected["frames"]):
            voided = np.where(frame["panoptic"] == 0x808080, 0, frame["panoptic"])
            np.testing.assert_array_equal(video.panoptic[t], voided)
            np.testing.assert_array_equal(video.depth[t], frame["depth"])
            error = np.abs(video.rgb[t].astype(int) - frame["rgb"].astype(int)).mean()
            assert error < 2.0, f"JPEG error {error} too large at frame {t}"
        np.testing.assert_allclose(video.poses(), np.stack(expected["poses"]), atol=1e-9)
    objects = reimported.read("objects").to_pylist()
    assert {(o["object_id"], o["mpcat40_index"]) for o in objects} == {(k, c) for k, c in OBJECTS.items() if c > 0}
    segments = reimported.read("segments").to_pylist()
    assert {(s["object_id"], s["category"]) for s in segments} == {(k, c) for k, c in OBJECTS.items() if c > 0}


def test_reimported_tables_describe_the_video(tiny_run: tuple[RunFolder, dict], reimported: RunFolder) -> None:
    _, truth = tiny_run
    name = f"{SCENE}.0000000003.0000000100"
    video = next(v for v in reimported.read("videos").to_pylist() if v["video_name"] == name)
    assert (video["scene_id"], video["trajectory"], video["height_m"], video["frames"]) == (SCENE, 3, 0.1, FRAMES)
    assert (video["width"], video["height"]) == (WIDTH, HEIGHT)
    frames = [f for f in reimported.read("frames").to_pylist() if f["video_name"] == name]
    pose = truth[name]["poses"][4]
    row = next(f for f in frames if f["frame"] == 4)
    np.testing.assert_allclose([row["px"], row["py"], row["pz"]], pose[:3, 3], atol=1e-9)
    np.testing.assert_allclose(quaternion_to_matrix(np.array([row["qw"], row["qx"], row["qy"], row["qz"]])),
                               pose[:3, :3], atol=1e-9)
    # Object 7 covers rows 10+t .. 13+t, columns 2..8 at frame t: area 4 x 7, box exclusive at the end.
    segment = next(s for s in reimported.read("segments").to_pylist()
                   if s["video_name"] == name and s["frame"] == 1 and s["object_id"] == 7)
    assert (segment["area"], segment["x0"], segment["y0"], segment["x1"], segment["y1"]) == (4 * 7, 2, 11, 9, 15)
    job = reimported.job()
    assert job.scenes.mvpd is not None and job.scenes.mvpd.split == "test"
    assert job.embodiments[0].placements == [1.0, 0.1]


def test_export_is_deterministic_and_train_keeps_every_video(tiny_run: tuple[RunFolder, dict], tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    run, _ = tiny_run
    first, second = tmp_path / "a", tmp_path / "b"
    # One process per core: the same files whether the videos go to one process or to two workers.
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    export_release(run, first, split="train")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr(mvpd_export, "FRAMES_PER_WORKER", 1)  # the tiny run's videos are worth a worker each
    export_release(run, second, split="train")
    files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file())
    assert len(files) == 2 * FRAMES * 3 + 3  # three files per frame, three JSON files
    assert all((first / f).read_bytes() == (second / f).read_bytes() for f in files)
    zero_shot = json.loads((first / "train" / "zero_shot.json").read_text())
    assert zero_shot == {"accepted": sorted(VIDEOS), "rejected": []}


def test_export_refuses_to_overwrite_and_leaves_no_partial_folder(tiny_run: tuple[RunFolder, dict],
                                                                  exported: Path) -> None:
    run, _ = tiny_run
    with pytest.raises(MvpdExportError, match="--overwrite"):
        export_release(run, exported, split="test")
    assert sorted(p.name for p in exported.iterdir()) == ["test"]


def test_export_of_an_object_missing_from_the_objects_table_fails_cleanly(tiny_run: tuple[RunFolder, dict],
                                                                         tmp_path: Path) -> None:
    run, _ = tiny_run
    copy = tmp_path / "run"
    shutil.copytree(run.root, copy)
    shutil.rmtree(copy / "objects")
    with pytest.raises(MvpdExportError, match="not in the objects table"):
        export_release(RunFolder(copy), tmp_path / "out", split="val")
    assert not (tmp_path / "out" / "val").exists()
    assert [p.name for p in (tmp_path / "out").iterdir()] == []  # the staging folder was removed


# ----------------------------------------------------------------------------- the real example


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory: pytest.TempPathFactory, ray_session) -> RunFolder:
    run_root = tmp_path_factory.mktemp("sample") / "run"
    summary = import_release(SAMPLE, "test", RunFolder(run_root))
    assert len(summary.imported) == 3 and summary.failed == []
    return RunFolder.open(run_root)


def test_import_of_the_shared_example(sample_run: RunFolder) -> None:
    release = json.loads((SAMPLE / "test" / "panoptic_test.json").read_text())
    expected_frames = {v["video_name"]: len(v["images"]) for v in release["videos"]}
    videos = {v["video_name"]: v for v in sample_run.read("videos").to_pylist()}
    assert {name: v["frames"] for name, v in videos.items()} == expected_frames  # 3 videos: 36, 33, 32 frames
    assert sample_run.read("frames").num_rows == sum(expected_frames.values())
    annotation = release["annotations"][0]
    name = annotation["video_name"]
    video = open_video(sample_run.video_store("mvpd", name))
    assert video.attrs["absent_arrays"] == ["rgb", "depth"]
    assert int(np.asarray(video.rgb[0]).max()) == 0
    png = np.asarray(Image.open(SAMPLE / "test" / "panomasksRGB" / name / "0000000005.png")).astype(np.int64)
    segment_ids = png[..., 0] + 256 * png[..., 1] + 65536 * png[..., 2]
    colour_of = {int(k): color_to_object_id(v["color"]) for k, v in annotation["instance_id_map"].items()}
    expected = np.vectorize(lambda s: colour_of.get(int(s), 0))(segment_ids)
    np.testing.assert_array_equal(video.panoptic[5], expected)


def test_stats_describe_the_imported_example(sample_run: RunFolder) -> None:
    from pipeline.io.dataset_stats import dataset_stats

    found = dataset_stats(sample_run)
    (row,) = found.per_embodiment  # imported videos all belong to the one `mvpd` embodiment
    assert (row["embodiment"], row["scenes"], row["videos"], row["frames"]) == ("mvpd", 1, 3, 36 + 33 + 32)
    assert row["masks"] == sample_run.read("segments").num_rows > 0
    assert found.instances == len(set(sample_run.read("segments").column("object_id").to_pylist()))


def test_reimport_is_idempotent(sample_run: RunFolder) -> None:
    before = {d: sample_run.read(d).num_rows for d in ("videos", "frames", "segments", "objects")}
    summary = import_release(SAMPLE, "test", RunFolder(sample_run.root))
    assert summary.imported == [] and len(summary.up_to_date) == 3
    assert summary.report.outcomes == [] and summary.report.skipped == 5  # nothing ran: 3 videos + 1 scene + split flags
    assert {d: sample_run.read(d).num_rows for d in before} == before
    videos = [f"00903-SAMPLEsc0003.{t:010d}.{h:010d}" for t, h in ((0, 100), (1, 1000), (2, 100))]
    # one per video, one per scene, one for the split files
    assert sorted(sample_run.markers("import")) == ["00903-SAMPLEsc0003", *videos, "split-flags"]


def test_export_of_the_imported_example_reproduces_its_masks_and_instances(sample_run: RunFolder,
                                                                           tmp_path: Path) -> None:
    export_release(sample_run, tmp_path, split="test")
    original = json.loads((SAMPLE / "test" / "panoptic_test.json").read_text())
    again = json.loads((tmp_path / "test" / "panoptic_test.json").read_text())
    # The export writes the full layout (ids, sizes, depth file names): a superset of the sample's compact form.
    assert [v["video_name"] for v in again["videos"]] == [v["video_name"] for v in original["videos"]]
    for ours, theirs in zip(again["videos"], original["videos"]):
        assert [{key: image[key] for key in old} for image, old in zip(ours["images"], theirs["images"])] == theirs["images"]
    instance_maps = [a["instance_id_map"] for a in original["annotations"]]
    assert [a["instance_id_map"] for a in again["annotations"]] == instance_maps  # unseen instances included
    for mask in sorted((SAMPLE / "test" / "panomasksRGB").glob("*/000000000[07].png")):
        copy = tmp_path / "test" / "panomasksRGB" / mask.parent.name / mask.name
        np.testing.assert_array_equal(np.asarray(Image.open(copy)), np.asarray(Image.open(mask)))
    assert not (tmp_path / "test" / "imagesRGB").exists()  # absent in the release: not invented


def test_spooled_panoptic_json_equals_the_whole_object_written_at_once(sample_run: RunFolder,
                                                                     tmp_path: Path) -> None:
    export_release(sample_run, tmp_path, split="test")
    written = (tmp_path / "test" / "panoptic_test.json").read_bytes()
    data = json.loads(written)
    assert len(data["videos"]) == 3 and len(data["instances"]) > 0
    assert written == json.dumps(data, separators=(", ", ": ")).encode()  # the bytes write_json gives
    assert not list((tmp_path / "test").glob(".*spool"))  # the spools are gone
    empty = PanopticJsonSpool(tmp_path, "empty.json")
    empty.finish()
    assert (tmp_path / "empty.json").read_text() == json.dumps(
        {"videos": [], "annotations": [], "categories": mvpd_categories(), "instances": []}, separators=(", ", ": "))


# ------------------------------------------------------------------------------------ bad input


def test_missing_panoptic_json_is_a_one_line_error_naming_the_file(tmp_path: Path) -> None:
    (tmp_path / "MVPd" / "test").mkdir(parents=True)
    with pytest.raises(MvpdFormatError) as caught:
        import_release(tmp_path / "MVPd", "test", RunFolder(tmp_path / "run"))
    message = str(caught.value)
    assert str(tmp_path / "MVPd" / "test" / "panoptic_test.json") in message and "\n" not in message
    assert not (tmp_path / "run").exists()


def test_a_broken_video_fails_alone_and_leaves_nothing_half_written(tmp_path: Path, ray_session) -> None:
    root = tmp_path / "MVPd"
    shutil.copytree(SAMPLE, root)
    broken = f"00903-SAMPLEsc0003.{1:010d}.{1000:010d}"
    (root / "test" / "panomasksRGB" / broken / "0000000004.png").unlink()
    summary = import_release(root, "test", RunFolder(tmp_path / "run"))
    assert [(o.unit, o.error_type) for o in summary.failed] == [(broken, "MvpdFormatError")]
    message = summary.failed[0].message
    assert "0000000004.png: no such file" in message and "\n" not in message
    run = RunFolder.open(tmp_path / "run")
    others = [f"00903-SAMPLEsc0003.{t:010d}.{h:010d}" for t, h in ((0, 100), (2, 100))]
    assert sorted(v["video_name"] for v in run.read("videos").to_pylist()) == others  # the others imported
    assert broken not in {f["video_name"] for f in run.read("frames").to_pylist()}
    assert not run.video_store("mvpd", broken).exists() and run.marker("import", broken) is None
    staging = run.root / "_staging" / "import"
    assert not staging.exists() or list(staging.iterdir()) == []
    status = {row["unit"]: row for row in run.read("status").to_pylist()}
    assert status[broken]["state"] == "failed" and status[broken]["error_type"] == "MvpdFormatError"
    assert status[broken]["message"] == message and (run.root / status[broken]["log_path"]).is_file()
    assert all(status[video]["state"] == "done" for video in others)


def test_cli_lists_a_failed_video_exits_1_and_a_fixed_release_imports_only_it(tmp_path: Path, ray_session) -> None:
    root = tmp_path / "MVPd"
    shutil.copytree(SAMPLE, root)
    broken = f"00903-SAMPLEsc0003.{1:010d}.{1000:010d}"
    mask = root / "test" / "panomasksRGB" / broken / "0000000004.png"
    mask.unlink()
    app = typer.Typer()
    mvpd_io.register(app)
    arguments = ["import-mvpd", str(root), "--split", "test", str(tmp_path / "run")]
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 1
    output = result.output.replace("\n", "")
    assert f"{broken}: MvpdFormatError" in output and "0000000004.png: no such file" in output
    shutil.copy(SAMPLE / "test" / "panomasksRGB" / broken / mask.name, mask)
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 0, result.output
    summary = import_release(root, "test", RunFolder(tmp_path / "run"))  # everything is done now: nothing runs
    assert summary.report.outcomes == [] and summary.failed == []
    run = RunFolder.open(tmp_path / "run")
    assert run.marker("import", broken).attempt == 2  # the failed attempt, then the one that imported it
    assert [m.attempt for u, m in sorted(run.markers("import").items()) if u != broken] == [1, 1, 1, 1]  # 2 videos, 1 scene, split flags
    assert sorted(v["video_name"] for v in run.read("videos").to_pylist()) == sorted(
        [f"00903-SAMPLEsc0003.{t:010d}.{h:010d}" for t, h in ((0, 100), (1, 1000), (2, 100))])


def test_cli_reports_the_missing_file_and_exits_2(tmp_path: Path) -> None:
    app = typer.Typer()
    mvpd_io.register(app)
    result = CliRunner().invoke(app, ["import-mvpd", str(tmp_path), "--split", "val", str(tmp_path / "run")])
    assert result.exit_code == 2
    assert "panoptic_val.json: no such file" in result.output.replace("\n", "")
