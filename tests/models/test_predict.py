"""`mvpd predict` on a tiny rendered run (Ray): perfect scores, determinism, bad input, a failing video."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.evaluate.api import evaluate_run
from pipeline.io.zarr_video import open_video
from pipeline.models.predict import ModelConfig, predict_run
from pipeline.store.run_folder import RunFolder
from tests.evaluate.reference import reference_video

runner = CliRunner()
from tests.models.conftest import FRAMES


def invoke(*args: object):
    return runner.invoke(app, [str(a) for a in args])


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted((folder / "panomasksRLE").rglob("*.json"))}


def small_and_thin_run(root: Path) -> Path:
    """A hand-made 64 x 48 run: a large object, a 2-pixel one (< 0.1 % of the frame) and a one-pixel-wide
    line on an odd column (gone at half resolution), drifting right one pixel per frame."""
    from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources
    from pipeline.io.tables import to_table
    from pipeline.io.zarr_video import VideoWriter
    from pipeline.store.run_folder import RunFolder

    name = "hand.0000000000.0000001000"
    job = Job(name="hand", scenes=SceneSources(procedural=ProceduralSource(count=1)), embodiments=[Embodiment(name="cam")])
    run = RunFolder.create(root, job)
    attributes = {"video_name": name, "poses": np.tile(np.eye(4), (FRAMES, 1, 1)).tolist(),
                  "intrinsics": {"fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 24.0, "width": 64, "height": 48}}
    writer = VideoWriter(run.video_store("cam", name), FRAMES, 64, 48, attributes, frames_per_shard=4)
    for t in range(FRAMES):
        panoptic = np.zeros((48, 64), np.uint32)
        panoptic[5:40, 2 + t:30 + t] = 5
        panoptic[10:12, 50] = 6  # 2 pixels: void under the 0.1 % rule
        panoptic[5:45, 45 + 2 * (t % 2)] = 7  # odd column: dropped by the subsampling
        writer.append(rgb=np.zeros((48, 64, 3), np.uint8), depth=np.full((48, 64), 2000, np.uint16), panoptic=panoptic)
    writer.close()
    row = {"embodiment": "cam", "video_name": name, "scene_id": "hand", "trajectory": 0, "height_m": 1.0,
           "illumination": "ambient", "sensor_model": "ideal", "frames": FRAMES, "width": 64, "height": 48, "fx": 50.0,
           "fy": 50.0, "cx": 32.0, "cy": 24.0, "exposure": 1.0, "store_path": f"videos/cam/{name}.zarr", "bytes": 0,
           "render_seconds": 0.0}
    run.commit_tables("render", f"cam.{name}", {"videos": to_table("videos", [row])})
    return run.root


def test_perfect_tracked_predictions_score_1_without_filter_and_the_published_value_with_it(run_root, tmp_path, ray_session) -> None:
    out = tmp_path / "oracle"
    perfect = ModelConfig(name="oracle", options={"tracked": True})
    report = predict_run(RunFolder(run_root), out, perfect, "ambient")
    assert not report.failed and report.done == 2
    exact = evaluate_run(RunFolder(run_root), out, "ambient", overrides={"min_area_fraction": 0.0, "subsample": 1})
    assert exact.summary["aggregate"] == {"1": 1.0, "5": 1.0, "10": 1.0, "15": 1.0, "VSQ": 1.0}
    hand = small_and_thin_run(tmp_path / "hand")
    assert not predict_run(RunFolder(hand), tmp_path / "hand-tracked", perfect).failed
    assert evaluate_run(RunFolder(hand), tmp_path / "hand-tracked", overrides={"min_area_fraction": 0.0, "subsample": 1}
                        ).summary["aggregate"]["VSQ"] == 1.0
    # The published evaluator reads per-frame masks (no ids): the same ground truth, untracked.
    assert not predict_run(RunFolder(hand), tmp_path / "hand-oracle", ModelConfig(name="oracle")).failed
    published = evaluate_run(RunFolder(hand), tmp_path / "hand-oracle")
    truth = np.asarray(open_video(hand / "videos" / "cam" / "hand.0000000000.0000001000.zarr").panoptic[:])
    masks = [np.stack([frame == i for i in np.unique(frame) if i]) for frame in truth]
    expected = reference_video(truth, masks, set())["non-zero-shot"]
    counts = published.per_video["cam/hand.0000000000.0000001000"]["non-zero-shot"]
    for k in (1, 5, 10, 15):
        assert (counts[k].tp, counts[k].fp, counts[k].fn) == (expected[k]["TP"], expected[k]["FP"], expected[k]["FN"])
        assert counts[k].iou == pytest.approx(expected[k]["IOU"], abs=1e-9)
    # The 2-pixel object is void in the ground truth but predicted (an FP); the line vanishes on both sides.
    assert counts[1].fp >= 1 and published.summary["aggregate"]["VSQ"] < 1.0


def test_same_seed_same_predictions_byte_for_byte(run_root, tmp_path, ray_session) -> None:
    degraded = ModelConfig(name="oracle", options={"miss": 0.3, "split": 0.3, "merge": 0.2, "boundary_noise": 0.5},
                           self_prompting=True)
    for name in ("a", "b"):
        assert not predict_run(RunFolder(run_root), tmp_path / name, degraded, "ambient").failed
    first = _files(tmp_path / "a")
    assert len(first) == 2 * FRAMES and first == _files(tmp_path / "b")
    assert not predict_run(RunFolder(run_root), tmp_path / "clean", ModelConfig(name="oracle"), "ambient").failed
    assert _files(tmp_path / "clean") != first  # the degradations did draw


def test_unknown_model_or_missing_extra_exits_2_and_writes_nothing(run_root, tmp_path) -> None:
    for model in ("segformer", "ultralytics"):
        result = invoke("predict", run_root, "--model", model, "--embodiment", "ambient", "--out", tmp_path / "out")
        assert result.exit_code == 2, result.output
        assert len(result.output.strip().splitlines()) == 1
        assert not (tmp_path / "out").exists()
    result = invoke("predict", run_root, "--model-file", tmp_path / "none.yaml", "--embodiment", "ambient",
                    "--out", tmp_path / "out")
    assert result.exit_code == 2 and "none.yaml: model file not found" in result.output
    (tmp_path / "bad.yaml").write_text("name: geometric\noptions: {scale: -3}\n")
    result = invoke("predict", run_root, "--model-file", tmp_path / "bad.yaml", "--embodiment", "ambient",
                    "--out", tmp_path / "out")
    assert result.exit_code == 2 and "geometric option scale" in result.output
    assert not (tmp_path / "out").exists()


def reseal(root: Path, stage: str, unit: str) -> None:
    """Record a unit's edited outputs in its marker, as if the unit had committed them so."""
    from dataclasses import replace

    from pipeline.store.markers import describe_files
    from pipeline.store.run_folder import RunFolder

    run = RunFolder(root)
    marker = run.marker(stage, unit)
    assert marker is not None
    run.write_marker(replace(marker, files=describe_files(run.root, marker.outputs)))


def test_self_prompting_on_a_run_without_poses_exits_2_and_writes_nothing(run_root, tmp_path) -> None:
    copy = tmp_path / "run"
    shutil.copytree(run_root, copy)
    store = next((copy / "videos" / "ambient").glob("*.zarr"))
    group = zarr.open_group(str(store), mode="r+")
    attributes = dict(group.attrs)
    del attributes["poses"]
    group.attrs.put(attributes)
    reseal(copy, "render", f"ambient.{store.stem}")  # a run rendered without poses, not a damaged one
    result = invoke("predict", copy, "--model", "geometric", "--self-prompting", "--embodiment", "ambient",
                    "--out", tmp_path / "out")
    assert result.exit_code == 2 and "no poses" in result.output and "drop --self-prompting" in result.output
    assert not (tmp_path / "out").exists()


def test_an_output_folder_of_another_run_or_model_is_refused_untouched(run_root, tmp_path, ray_session) -> None:
    out = tmp_path / "out"
    first = invoke("predict", run_root, "--model", "geometric", "--embodiment", "ambient", "--out", out)
    assert first.exit_code == 0, first.output
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    other_run = tmp_path / "other"
    shutil.copytree(run_root, other_run)
    for args in ((other_run, "--model", "geometric"), (run_root, "--model", "oracle"),
                 (run_root, "--model", "geometric", "--self-prompting")):
        result = invoke("predict", *args, "--embodiment", "ambient", "--out", out)
        assert result.exit_code == 2 and "holds predictions of another" in result.output, result.output
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == before
    again = invoke("predict", run_root, "--model", "geometric", "--embodiment", "ambient", "--out", out)
    assert again.exit_code == 0 and "2 up to date" in again.output
    assert invoke("predict", run_root, "--model", "geometric", "--embodiment", "ambient", "--out", run_root).exit_code == 2


def test_a_segmenter_failing_on_one_video_fails_that_unit_only(run_root, tmp_path, ray_session) -> None:
    copy = tmp_path / "run"
    shutil.copytree(run_root, copy)
    broken = sorted((copy / "videos" / "ambient").glob("*.zarr"))[0]
    shutil.rmtree(broken / "panoptic")  # the oracle cannot read this video's ground truth
    reseal(copy, "render", f"ambient.{broken.stem}")  # committed so: the failure is the segmenter's, not damage
    result = invoke("predict", copy, "--model", "oracle", "--embodiment", "ambient", "--out", tmp_path / "out")
    assert result.exit_code == 1, result.output
    assert "1 done, 1 failed" in result.output
    written = {p.name for p in (tmp_path / "out" / "panomasksRLE").iterdir()}
    assert written == {sorted((copy / "videos" / "ambient").glob("*.zarr"))[1].stem}
