"""Hand-computable cases, one per step of the published VSQ protocol (DESIGN.md)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluate.frames import ground_truth_frame, prediction_frame_from_masks
from pipeline.evaluate.vsq import NON_ZERO_SHOT, ZERO_SHOT, ProtocolError, VsqProtocol, summarize
from tests.evaluate.helpers import counts, evaluate_arrays, masks_of, no_masks

H, W = 4, 6
FULL = np.ones((H, W), dtype=bool)
TINY = VsqProtocol(ks=(1, 3), window=3, stride=3, min_area_fraction=0.0, subsample=1)


def constant_video(frames: int, object_id: int = 7) -> np.ndarray:
    return np.full((frames, H, W), object_id, dtype=np.uint32)


@pytest.mark.parametrize("frames, windows", [(30, 1), (31, 2), (15, 0), (16, 1)])
def test_windows_start_while_start_is_below_t_minus_15(frames: int, windows: int) -> None:
    """range(0, T - 15, 15): T = 30 has one window (start 0), T = 31 two (0 and 15); the bound is exclusive."""
    video = evaluate_arrays(constant_video(frames), [masks_of(FULL)] * frames,
                            protocol=VsqProtocol(min_area_fraction=0.0, subsample=1))
    for k in (1, 5, 10, 15):
        assert counts(video, NON_ZERO_SHOT, k) == (windows, 0, 0)  # one perfect TP per window
        assert video[NON_ZERO_SHOT][k].iou == pytest.approx(windows * 1.0)


def test_first_k_frames_of_each_window_only() -> None:
    """The object appears at frame 2: k = 1 sees no ground truth, only the prediction (an FP)."""
    truth = constant_video(4)
    truth[:2] = 0
    video = evaluate_arrays(truth, [masks_of(FULL)] * 4, protocol=TINY)
    assert counts(video, NON_ZERO_SHOT, 1) == (0, 1, 0)  # frame 0 only: one predicted tube, no truth
    assert counts(video, NON_ZERO_SHOT, 3) == (1, 0, 0)
    assert video[NON_ZERO_SHOT][3].iou == pytest.approx(24 / 72)  # truth 24 px (frame 2), tube 72 px (3 frames)


def test_empty_prediction_frame_counts_as_one_empty_mask_and_breaks_tubes() -> None:
    """Frame 1 has no masks: it becomes one empty mask, a tube of its own; frame 2 cannot link across it."""
    predictions = [masks_of(FULL), no_masks(H, W), masks_of(FULL)]
    video = evaluate_arrays(constant_video(4), predictions + [masks_of(FULL)], protocol=TINY)
    assert counts(video, NON_ZERO_SHOT, 1) == (1, 0, 0)
    # Three tubes (frame 0, the empty mask, frame 2); the truth tube (72 px) takes one 24-px tube.
    assert counts(video, NON_ZERO_SHOT, 3) == (1, 2, 0)  # FP = 3 - 1
    assert video[NON_ZERO_SHOT][3].iou == pytest.approx(24 / 72)


def test_split_object_matches_one_half_and_the_other_is_a_false_positive() -> None:
    left, right = FULL.copy(), FULL.copy()
    left[:, W // 2:] = False
    right[:, : W // 2] = False
    video = evaluate_arrays(constant_video(4), [masks_of(left, right)] * 4, protocol=TINY)
    for k in (1, 3):
        assert counts(video, NON_ZERO_SHOT, k) == (1, 1, 0)  # two tubes, one object
        assert video[NON_ZERO_SHOT][k].iou == pytest.approx(12 / 24)  # half of the object


def test_zero_shot_false_positive_counts_in_both_buckets() -> None:
    """Truth: A (zero-shot) in columns 0-1, B in 2-3, void in 4-5; a third mask on the void is an FP."""
    truth = np.zeros((4, H, W), dtype=np.uint32)
    truth[:, :, 0:2], truth[:, :, 2:4] = 1, 2
    a, b, on_void = (truth[0] == 1), (truth[0] == 2), (truth[0] == 0)
    video = evaluate_arrays(truth, [masks_of(a, b, on_void)] * 4, zero_shot=[1], protocol=TINY)
    assert counts(video, ZERO_SHOT, 1) == (1, 1, 0)
    assert counts(video, NON_ZERO_SHOT, 1) == (1, 1, 0)
    summary = summarize([video], TINY.ks)
    assert summary[ZERO_SHOT]["1"] == pytest.approx(1 / (1 + 0.5))
    assert summary["aggregate"]["1"] == pytest.approx(2 / (2 + 0.5))  # the FP counted once


def test_video_without_ground_truth_in_a_bucket_does_not_add_its_false_positives_there() -> None:
    zero_shot_video = evaluate_arrays(constant_video(4, 5), [masks_of(FULL)] * 4, zero_shot=[5], protocol=TINY)
    other = FULL.copy()
    other[:, 3:] = False
    truth = constant_video(4, 9)
    truth[:, :, 3:] = 0
    plain_video = evaluate_arrays(truth, [masks_of(other, ~other)] * 4, protocol=TINY)
    assert counts(plain_video, ZERO_SHOT, 1) == (0, 1, 0)  # its FP is in the zero-shot bucket too ...
    summary = summarize([zero_shot_video, plain_video], TINY.ks)
    assert summary[ZERO_SHOT]["1"] == pytest.approx(1.0)  # ... but TP + FN = 0 there, so it is left out
    assert summary[NON_ZERO_SHOT]["1"] == pytest.approx(1 / (1 + 0.5))


def test_assigned_pairs_with_zero_dice_are_dropped() -> None:
    """The only possible assignment pairs disjoint tubes (F = 0): it is not a TP but an FP and an FN."""
    truth = constant_video(4)
    truth[:, :, 3:] = 0
    elsewhere = truth[0] == 0
    video = evaluate_arrays(truth, [masks_of(elsewhere)] * 4, protocol=TINY)
    assert counts(video, NON_ZERO_SHOT, 1) == (0, 1, 1)
    assert video[NON_ZERO_SHOT][1].iou == 0.0


def test_predicted_pixels_on_void_count_against_iou() -> None:
    truth = constant_video(4)
    truth[:, :, 3:] = 0  # object 12 px, prediction covers the whole 24-px frame
    video = evaluate_arrays(truth, [masks_of(FULL)] * 4, protocol=TINY)
    assert video[NON_ZERO_SHOT][1].iou == pytest.approx(12 / 24)


def test_small_segments_become_void_at_full_resolution() -> None:
    """20 x 50 = 1000 px and 1 %: an id needs at least 10 px (count >= H * W * fraction)."""
    label = np.full((20, 50), 1, dtype=np.uint32)
    label[0, :9] = 2  # 9 px: void
    label[1, :10] = 3  # 10 px: kept
    frame = ground_truth_frame(label, min_area_fraction=0.01, stride=1)
    assert frame.ids.tolist() == [1, 3]
    assert int((frame.labels == 0).sum()) == 9


def test_subsampling_keeps_even_rows_and_columns() -> None:
    label = np.full((4, 6), 1, dtype=np.uint32)
    label[1, :] = 2  # odd row: gone after subsampling
    label[:, 3] = 3  # odd column: gone
    frame = ground_truth_frame(label, min_area_fraction=0.0, stride=2)
    assert frame.ids.tolist() == [1]
    assert frame.labels.size == (4 // 2) * (6 // 2)
    odd_rows = np.zeros((1, 4, 6), dtype=bool)
    odd_rows[0, 1::2] = True
    prediction = prediction_frame_from_masks(odd_rows, stride=2)
    assert prediction.membership[prediction.atoms].sum() == 0  # the mask is empty after subsampling


def test_vsq_is_the_mean_of_vsq_k_over_k() -> None:
    video = evaluate_arrays(constant_video(4), [masks_of(FULL), no_masks(H, W), masks_of(FULL), masks_of(FULL)], protocol=TINY)
    summary = summarize([video], TINY.ks)[NON_ZERO_SHOT]
    assert summary["1"] == pytest.approx(1.0)
    assert summary["3"] == pytest.approx((24 / 72) / (1 + 0.5 * 2))  # TP 1, FP 2
    assert summary["VSQ"] == pytest.approx((summary["1"] + summary["3"]) / 2)


def test_bucket_no_video_adds_to_is_zero_for_every_k_as_published() -> None:
    video = evaluate_arrays(constant_video(4), [masks_of(FULL)] * 4, protocol=TINY)
    # The video's FPs exist, but with TP + FN = 0 in the zero-shot bucket it does not add there (step 8).
    assert summarize([video], TINY.ks)[ZERO_SHOT] == {"1": 0.0, "3": 0.0, "VSQ": 0.0}


def test_protocol_rejects_k_longer_than_the_window() -> None:
    with pytest.raises(ProtocolError, match="exceeds evaluate.window"):
        VsqProtocol(ks=(1, 20), window=15)
