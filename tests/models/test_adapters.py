"""The `ultralytics` and `sam` adapters: one-line errors without their extra or file (run in CI), and real
inference with randomly initialised networks saved to a local file (only where torch and the extra are
installed; nothing is downloaded)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.models.segmenter import FrameInput, ModelError, make_segmenter

EXTRAS = {"ultralytics": ("ultralytics", "FastSAM-x.pt"), "sam": ("segment_anything", "sam_vit_h_4b8939.pth")}


@pytest.mark.parametrize("model", sorted(EXTRAS))
def test_no_checkpoint_is_a_one_line_error_naming_the_option(model: str) -> None:
    with pytest.raises(ModelError) as caught:
        make_segmenter(model)
    message = str(caught.value)
    assert "checkpoint=PATH" in message and EXTRAS[model][1] in message and "\n" not in message


@pytest.mark.parametrize("model", sorted(EXTRAS))
def test_a_missing_checkpoint_file_is_named(model: str, tmp_path: Path) -> None:
    missing = tmp_path / "weights.pt"
    with pytest.raises(ModelError, match=f"{missing}: no such checkpoint file"):
        make_segmenter(model, checkpoint=missing)


@pytest.mark.parametrize("model", sorted(EXTRAS))
def test_a_missing_extra_says_what_to_install(model: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    checkpoint = tmp_path / "weights.pt"
    checkpoint.write_bytes(b"not used")
    monkeypatch.setitem(sys.modules, EXTRAS[model][0], None)  # what `import` sees when the extra is absent
    with pytest.raises(ModelError) as caught:
        make_segmenter(model, checkpoint=checkpoint)
    message = str(caught.value)
    assert f"pip install 'mvpd-pipeline[{model}]'" in message and "\n" not in message


def test_bad_options_are_refused_before_loading(tmp_path: Path) -> None:
    checkpoint = tmp_path / "weights.pt"
    checkpoint.write_bytes(b"x")
    with pytest.raises(ModelError, match="choose auto, fastsam or yolo"):
        make_segmenter("ultralytics", checkpoint=checkpoint, architecture="detr")
    with pytest.raises(ModelError, match="choose auto, vit_h"):
        make_segmenter("sam", checkpoint=checkpoint, model_type="vit_g")


def test_sam_reads_the_backbone_from_the_official_file_names() -> None:
    from pipeline.models.sam_segmenter import model_type_of

    assert [model_type_of(Path(n)) for n in ("sam_vit_b_01ec64.pth", "SAM_VIT_L.pth", "mine.pth")] == [
        "vit_b", "vit_l", "vit_h"]


# ------------------------------------------------------------------ real inference (torch + extra)


@pytest.fixture(scope="module")
def tiny_frame(tmp_path_factory: pytest.TempPathFactory) -> FrameInput:
    """Frame 2 of the rendered room at 1.0 m (64 x 48)."""
    from pipeline.io.reader import load_video
    from tests.render.tiny_run import render_tiny_run

    run = render_tiny_run(tmp_path_factory.mktemp("adapters") / "run")
    video = load_video(run, "room.0000000000.0000001000", "ambient")
    return FrameInput(rgb=np.asarray(video.rgb[2]), depth=np.asarray(video.depth[2]), index=2)


@pytest.fixture(scope="module")
def yolo_checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A randomly initialised YOLOv8n-seg built from the yaml that ships inside ultralytics, saved locally."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("ultralytics")
    from pipeline.models.ultralytics_segmenter import _import_ultralytics

    ultralytics = _import_ultralytics()
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("weights") / "random-yolov8n-seg.pt"
    ultralytics.YOLO("yolov8n-seg.yaml", task="segment").save(str(path))
    return path


@pytest.mark.parametrize("architecture, retina", [("yolo", True), ("fastsam", True), ("yolo", False)])
def test_ultralytics_segments_a_rendered_frame(yolo_checkpoint: Path, tiny_frame: FrameInput, architecture: str,
                                               retina: bool) -> None:
    # conf 0: an untrained network's scores are low; every candidate that survives NMS is a mask.
    segmenter = make_segmenter("ultralytics", checkpoint=yolo_checkpoint, architecture=architecture, imgsz=64,
                               conf=0.0, retina_masks=retina)
    masks = segmenter.segment(tiny_frame)
    assert masks.dtype == np.bool_ and masks.ndim == 3 and masks.shape[1:] == (48, 64)
    assert masks.shape[0] > 0 and masks.any()
    np.testing.assert_array_equal(segmenter.segment(tiny_frame), masks)  # same frame, same masks
    assert segmenter.describe()["architecture"] == architecture


def test_ultralytics_defaults_are_the_papers_fastsam_x_settings(yolo_checkpoint: Path, tmp_path: Path) -> None:
    fastsam = tmp_path / "FastSAM-random.pt"
    fastsam.write_bytes(yolo_checkpoint.read_bytes())
    described = make_segmenter("ultralytics", checkpoint=fastsam).describe()
    assert {k: described[k] for k in ("architecture", "imgsz", "conf", "iou", "retina_masks")} == {
        "architecture": "fastsam", "imgsz": 1024, "conf": 0.4, "iou": 0.9, "retina_masks": True}


@pytest.mark.parametrize("model, package, message", [
    ("ultralytics", "ultralytics", "not a loadable ultralytics segmentation checkpoint"),
    ("sam", "segment_anything", "not a vit_h SAM checkpoint"),
])
def test_a_file_that_is_not_a_checkpoint_is_refused(tmp_path: Path, model: str, package: str, message: str) -> None:
    pytest.importorskip("torch")
    pytest.importorskip(package)
    broken = tmp_path / "broken.pt"
    broken.write_bytes(b"this is not a checkpoint")
    with pytest.raises(ModelError, match=message) as caught:
        make_segmenter(model, checkpoint=broken)
    assert "\n" not in str(caught.value)


@pytest.fixture
def sam_checkpoint(tmp_path: Path) -> Path:
    """A randomly initialised SAM ViT-B (the smallest official backbone), saved locally."""
    torch = pytest.importorskip("torch")
    segment_anything = pytest.importorskip("segment_anything")
    torch.manual_seed(0)
    checkpoint = tmp_path / "sam_vit_b_random.pth"
    torch.save(segment_anything.sam_model_registry["vit_b"]().state_dict(), checkpoint)
    return checkpoint


def test_sam_segments_a_rendered_frame(sam_checkpoint: Path, tiny_frame: FrameInput) -> None:
    checkpoint = sam_checkpoint
    # A 2 x 2 prompt grid and no quality filter: an untrained network's masks would all be filtered out.
    segmenter = make_segmenter("sam", checkpoint=checkpoint, points_per_side=2, pred_iou_thresh=0.0,
                               stability_score_thresh=0.0)
    masks = segmenter.segment(tiny_frame)
    assert masks.dtype == np.bool_ and masks.ndim == 3 and masks.shape[1:] == (48, 64)
    assert segmenter.describe()["model_type"] == "vit_b"
