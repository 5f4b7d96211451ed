"""Ground-truth and prediction readers, and bad input: one-line errors that name the file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.evaluate.errors import GroundTruthError, MissingPredictionError, PredictionError
from pipeline.evaluate.ground_truth import MvpdSplit
from pipeline.evaluate.stage import evaluate_spec
from pipeline.evaluate.vsq import NON_ZERO_SHOT, ZERO_SHOT, VsqProtocol
from tests.evaluate.helpers import counts, write_mvpd_case

PROTOCOL = VsqProtocol(ks=(1, 2), window=2, stride=2, min_area_fraction=0.0, subsample=2)
VIDEO = "00001-TEST.0000000000.0000000100"


def small_video(frames: int = 3) -> tuple[np.ndarray, list[np.ndarray]]:
    """Two objects (ids 70000 and 3); predictions are exact copies of both."""
    truth = np.zeros((frames, 8, 10), dtype=np.uint32)
    truth[:, :, :4], truth[:, :, 6:] = 70000, 3
    return truth, [np.stack([truth[t] == 70000, truth[t] == 3]) for t in range(frames)]


@pytest.fixture
def case(tmp_path):
    gt, pred = write_mvpd_case(tmp_path, {VIDEO: small_video(), "00001-TEST.0000000001.0000000100": small_video()},
                               zero_shot={VIDEO: [70000]}, accepted=[VIDEO])
    return gt, pred


def test_mvpd_split_lists_accepted_videos_with_zero_shot_ids_from_colours(case) -> None:
    gt, pred = case
    specs = MvpdSplit(gt, "test").videos()
    assert [s.key for s in specs] == [VIDEO]  # the other video is not in empty_videos.json "accepted"
    assert specs[0].zero_shot == [70000]
    video, missing = evaluate_spec(specs[0], pred, PROTOCOL)
    assert missing == []
    assert counts(video, ZERO_SHOT, 1) == (1, 0, 0)
    assert counts(video, NON_ZERO_SHOT, 1) == (1, 0, 0)
    assert video[ZERO_SHOT][2].iou == 1.0


def test_split_folder_without_panoptic_json_names_the_file(tmp_path) -> None:
    with pytest.raises(GroundTruthError, match=r"panoptic_val\.json: missing") as error:
        MvpdSplit(tmp_path, "val")
    assert "\n" not in str(error.value)


def _rewrite(pred, frame: int, payload: object) -> str:
    path = pred / "panomasksRLE" / VIDEO / f"{frame:010d}.json"
    path.write_text(json.dumps(payload))
    return str(path)


def test_wrong_mask_size_names_the_file_and_both_sizes(case) -> None:
    gt, pred = case
    path = _rewrite(pred, 1, {"coco_rle": [{"size": [4, 5], "counts": "0d0"}]})
    with pytest.raises(PredictionError, match=r"size \[4, 5\], the ground truth is 8x10") as error:
        evaluate_spec(MvpdSplit(gt, "test").videos()[0], pred, PROTOCOL)
    assert path in str(error.value)


def test_corrupt_rle_names_the_file(case) -> None:
    gt, pred = case
    path = _rewrite(pred, 0, {"coco_rle": [{"size": [8, 10], "counts": "~~"}]})
    with pytest.raises(PredictionError, match="corrupt RLE") as error:
        evaluate_spec(MvpdSplit(gt, "test").videos()[0], pred, PROTOCOL)
    assert path in str(error.value)


def test_video_missing_from_the_predictions_names_the_folder(case) -> None:
    gt, pred = case
    import shutil

    shutil.rmtree(pred / "panomasksRLE" / VIDEO)
    with pytest.raises(MissingPredictionError, match=f"panomasksRLE/{VIDEO}: no predictions"):
        evaluate_spec(MvpdSplit(gt, "test").videos()[0], pred, PROTOCOL)


def test_missing_frame_fails_unless_allowed_then_counts_as_empty_and_is_reported(case) -> None:
    gt, pred = case
    (pred / "panomasksRLE" / VIDEO / "0000000001.json").unlink()
    spec = MvpdSplit(gt, "test").videos()[0]
    with pytest.raises(MissingPredictionError, match=r"0000000001\.json: prediction frame missing.*--allow-missing"):
        evaluate_spec(spec, pred, PROTOCOL)
    video, missing = evaluate_spec(spec, pred, PROTOCOL, allow_missing=True)
    assert missing == [1]
    # k = 2: frame 1 is one empty mask (a tube of its own), so 3 tubes for 2 objects.
    assert counts(video, NON_ZERO_SHOT, 2) == (1, 1, 0)
    assert video[NON_ZERO_SHOT][2].iou == 0.5  # the tube's 8 px (frame 0) of the object's 16 px (2 frames)


def test_pt_predictions_without_torch_give_a_clear_error(case) -> None:
    try:
        import torch  # noqa: F401
        pytest.skip("torch is installed")
    except ModuleNotFoundError:
        pass
    gt, pred = case
    folder = pred / "panomasksRLE" / VIDEO
    (folder / "0000000000.json").unlink()
    (folder / "0000000000.pt").write_bytes(b"not really a torch file")
    with pytest.raises(PredictionError, match=r"0000000000\.pt: \.pt predictions need PyTorch"):
        evaluate_spec(MvpdSplit(gt, "test").videos()[0], pred, PROTOCOL)


def test_pt_predictions_score_exactly_like_the_same_json(case) -> None:
    torch = pytest.importorskip("torch")
    gt, pred = case
    spec = MvpdSplit(gt, "test").videos()[0]
    expected, _ = evaluate_spec(spec, pred, PROTOCOL)
    for path in sorted((pred / "panomasksRLE" / VIDEO).glob("*.json")):
        rles = json.loads(path.read_text())["coco_rle"]
        # The published containers hold pycocotools' own output: counts as bytes.
        torch.save({"coco_rle": [{**rle, "counts": rle["counts"].encode()} for rle in rles]}, path.with_suffix(".pt"))
        path.unlink()
    video, missing = evaluate_spec(spec, pred, PROTOCOL)
    assert missing == [] and video == expected and counts(video, ZERO_SHOT, 1) == (1, 0, 0)


def test_empty_coco_rle_list_is_an_empty_frame(case) -> None:
    gt, pred = case
    _rewrite(pred, 0, {"coco_rle": []})
    video, _ = evaluate_spec(MvpdSplit(gt, "test").videos()[0], pred, PROTOCOL)
    assert counts(video, NON_ZERO_SHOT, 1) == (0, 1, 1)  # one empty mask (FP), object 3 unmatched (FN)
    assert counts(video, ZERO_SHOT, 1) == (0, 1, 1)


def test_zarr_id_predictions_are_used_as_tracks(tmp_path) -> None:
    import zarr

    truth, _ = small_video()
    gt, pred = write_mvpd_case(tmp_path, {VIDEO: (truth, [np.zeros((0, 8, 10), bool)] * 3)})
    import shutil

    shutil.rmtree(pred / "panomasksRLE" / VIDEO)
    ids = zarr.open_array(str(pred / f"{VIDEO}.zarr"), mode="w", shape=truth.shape, dtype="uint32", zarr_format=3)
    ids[:] = np.where(truth == 70000, 11, 0)
    video, _ = evaluate_spec(MvpdSplit(gt, "test").videos()[0], pred, PROTOCOL)
    assert counts(video, NON_ZERO_SHOT, 2) == (1, 0, 1)  # track 11 is object 70000; object 3 missed
    assert video[NON_ZERO_SHOT][2].iou == 1.0


def test_png_colour_to_id_is_r_plus_256_g_plus_65536_b() -> None:
    from pipeline.evaluate.ground_truth import rgb_to_id

    rgb = np.array([[[1, 2, 3], [255, 0, 0]], [[0, 0, 255], [0, 0, 0]]], dtype=np.uint8)
    assert rgb_to_id(rgb).tolist() == [[1 + 2 * 256 + 3 * 65536, 255], [255 * 65536, 0]]
