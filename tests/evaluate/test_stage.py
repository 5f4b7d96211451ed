"""The evaluate stage on a tiny run of ours, and `mvpd evaluate` end to end (Ray) on the shared case."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pycocotools.mask as mask_utils
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources
from pipeline.evaluate.errors import GroundTruthError
from pipeline.evaluate.report import result_from_table
from pipeline.evaluate.stage import EvaluationInputs, VsqEvaluator
from pipeline.io.tables import to_table
from pipeline.io.zarr_video import VideoWriter
from pipeline.runtime.executor import plan_stage, run_unit_locally
from pipeline.store.run_folder import RunFolder

CASE = Path(__file__).resolve().parents[1] / "data" / "vsq_small"
NAME = "proc-000000.0000000000.0000001000"


def tiny_run(root: Path, frames: int = 17) -> RunFolder:
    """A run with one rendered 8 x 10 video: object 5 on the left, object 6 on the right."""
    job = Job(name="tiny", scenes=SceneSources(procedural=ProceduralSource(count=1)), embodiments=[Embodiment(name="cam")])
    run = RunFolder.create(root, job)
    panoptic = np.zeros((frames, 8, 10), dtype=np.uint32)
    panoptic[:, :, :4], panoptic[:, :, 6:] = 5, 6
    writer = VideoWriter(run.video_store("cam", NAME), frames, 10, 8, {"video_name": NAME}, arrays=("panoptic",), frames_per_shard=4)
    for frame in panoptic:
        writer.append(panoptic=frame)
    writer.close()
    row = {"embodiment": "cam", "video_name": NAME, "scene_id": "proc-000000", "trajectory": 0, "height_m": 1.0,
           "illumination": "ambient", "sensor_model": "ideal", "frames": frames, "width": 10, "height": 8, "fx": 1.0,
           "fy": 1.0, "cx": 5.0, "cy": 4.0, "exposure": 1.0, "store_path": f"videos/cam/{NAME}.zarr", "bytes": 0,
           "render_seconds": 0.0}
    # Committed as a render unit would, so `evaluate` may run after it and readers trust the part.
    run.commit_tables("render", f"cam.{NAME}", {"videos": to_table("videos", [row])})
    return run


def write_predictions(pred: Path, masks: np.ndarray) -> None:
    """Per-frame JSON files `<pred>/panomasksRLE/<video>/<frame:010d>.json` of one mask per frame."""
    folder = pred / "panomasksRLE" / NAME
    folder.mkdir(parents=True)
    for t, mask in enumerate(masks):
        rle = mask_utils.encode(np.asfortranarray(mask[:, :, None].astype(np.uint8)))[0]
        (folder / f"{t:010d}.json").write_text(json.dumps({"coco_rle": [{"size": rle["size"], "counts": rle["counts"].decode()}]}))


def test_run_videos_are_evaluated_with_every_object_non_zero_shot(tmp_path) -> None:
    run = tiny_run(tmp_path / "run")
    left = np.zeros((17, 8, 10), dtype=bool)
    left[:, :, :4] = True
    write_predictions(tmp_path / "pred", left)
    stage = VsqEvaluator(run.job(), EvaluationInputs(str(tmp_path / "pred")))
    units = stage.units(run)
    assert [u.id for u in units] == [f"cam.{NAME}"]
    marker = run_unit_locally(stage, run, units[0])
    assert marker.rows == {"metrics": 8}  # 2 buckets x 4 k
    result = result_from_table(run.read("metrics"), stage.protocol)
    video = result.per_video[f"cam/{NAME}"]
    # T = 17: one window (start 0). k = 1: object 5 found, object 6 missed; no zero-shot ground truth.
    assert (video["non-zero-shot"][1].tp, video["non-zero-shot"][1].fp, video["non-zero-shot"][1].fn) == (1, 0, 1)
    assert video["non-zero-shot"][15].iou == 1.0
    assert (video["zero-shot"][15].tp, video["zero-shot"][15].fn) == (0, 0)
    assert result.summary["non-zero-shot"]["1"] == pytest.approx(1 / (1 + 0.5))
    # No video has zero-shot ground truth: the bucket is 0.0 for every k, as the published summary reports it.
    assert result.summary["zero-shot"] == {"1": 0.0, "5": 0.0, "10": 0.0, "15": 0.0, "VSQ": 0.0}


def test_a_prediction_file_rewritten_in_place_makes_its_video_stale(tmp_path) -> None:
    run = tiny_run(tmp_path / "run")
    write_predictions(tmp_path / "pred", np.zeros((17, 8, 10), dtype=bool))
    stage = VsqEvaluator(run.job(), EvaluationInputs(str(tmp_path / "pred")))
    run_unit_locally(stage, run, stage.units(run)[0])
    assert plan_stage(stage, run).to_run == []
    folder = tmp_path / "pred" / "panomasksRLE" / NAME
    before = os.stat(folder)
    rewritten = folder / "0000000003.json"
    rewritten.write_text(rewritten.read_text())  # same bytes, a new modification time
    os.utime(rewritten, ns=(before.st_atime_ns, before.st_mtime_ns + 1))
    assert os.stat(folder).st_mtime_ns == before.st_mtime_ns  # the folder itself looks untouched
    assert [unit.id for unit in plan_stage(stage, run).to_run] == [f"cam.{NAME}"]


def test_run_without_rendered_videos_is_a_clear_error(tmp_path) -> None:
    job = Job(name="tiny", scenes=SceneSources(procedural=ProceduralSource(count=1)), embodiments=[Embodiment(name="cam")])
    run = RunFolder.create(tmp_path / "run", job)
    with pytest.raises(GroundTruthError, match="no rendered videos; run the render stage first"):
        VsqEvaluator(job, EvaluationInputs(str(tmp_path / "pred"))).units(run)


def test_cli_without_panoptic_json_prints_one_line_and_exits_2(tmp_path) -> None:
    result = CliRunner().invoke(app, ["evaluate", "--gt-mvpd", str(tmp_path), "--split", "test", "--pred", str(tmp_path),
                                      "--out", str(tmp_path / "r.json")])
    assert result.exit_code == 2
    assert "panoptic_test.json: missing" in result.output
    assert not (tmp_path / "r.run").exists()


@pytest.mark.skipif(not CASE.is_dir(), reason="shared VSQ case not present")
def test_cli_on_the_shared_case_writes_the_published_numbers(ray_session, tmp_path) -> None:
    out = tmp_path / "vsq.json"
    result = CliRunner().invoke(app, ["evaluate", "--gt-mvpd", str(CASE / "MVPd"), "--split", "test",
                                      "--pred", str(CASE / "pred"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    got, expected = json.loads(out.read_text()), json.loads((CASE / "expected.json").read_text())
    for video, buckets in expected["per_video"].items():
        for bucket, per_k in buckets.items():
            for k, want in per_k.items():
                assert {key: got["per_video"][video][bucket][k][key] for key in ("TP", "FP", "FN")} == \
                    {key: want[key] for key in ("TP", "FP", "FN")}
                assert got["per_video"][video][bucket][k]["IOU"] == pytest.approx(want["IOU"], abs=1e-9)
    for bucket, values in expected["summary"].items():
        assert got["summary"][bucket] == pytest.approx(values, abs=1e-12)
    assert (tmp_path / "vsq.run" / "metrics").is_dir()
    assert "aggregate" in result.output


def test_cli_on_a_run_writes_metrics_and_prints_the_table(ray_session, tmp_path) -> None:
    run = tiny_run(tmp_path / "run")
    masks = np.zeros((17, 8, 10), dtype=bool)
    masks[:, :, 6:] = True
    write_predictions(tmp_path / "pred", masks)
    result = CliRunner().invoke(app, ["evaluate", str(run.root), "--pred", str(tmp_path / "pred"), "--out", str(tmp_path / "r.json")])
    assert result.exit_code == 0, result.output
    rows = run.read("metrics").to_pylist()
    assert {(r["bucket"], r["k"], r["tp"], r["fn"]) for r in rows if r["bucket"] == "non-zero-shot"} == \
        {("non-zero-shot", k, 1, 1) for k in (1, 5, 10, 15)}  # object 6 found, object 5 missed, every k
    summary = json.loads((tmp_path / "r.json").read_text())["summary"]
    assert summary["non-zero-shot"]["VSQ"] == pytest.approx(1 / (1 + 0.5))
    assert json.loads((tmp_path / "r.json").read_text())["split"] == "all"


def test_cli_reports_a_corrupt_prediction_file_of_a_failed_video_and_exits_2(ray_session, tmp_path) -> None:
    run = tiny_run(tmp_path / "run")
    write_predictions(tmp_path / "pred", np.ones((17, 8, 10), dtype=bool))
    bad = tmp_path / "pred" / "panomasksRLE" / NAME / "0000000003.json"
    bad.write_text(json.dumps({"coco_rle": [{"size": [8, 10], "counts": "~~~"}]}))
    result = CliRunner().invoke(app, ["evaluate", str(run.root), "--pred", str(tmp_path / "pred")])
    assert result.exit_code == 2
    assert "PredictionError" in result.output and "0000000003.json" in result.output and "corrupt RLE" in result.output
