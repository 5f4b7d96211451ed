"""Tube linking (published step 6) and tracked predictions."""

from __future__ import annotations

import numpy as np

from pipeline.evaluate.frames import ground_truth_overlap, ground_truth_frame, prediction_frame_from_masks
from pipeline.evaluate.linking import TubeLinker, dice_matrix, match_by_dice
from pipeline.evaluate.vsq import NON_ZERO_SHOT, VsqProtocol, evaluate_video
from tests.evaluate.helpers import counts, evaluate_arrays

H, W = 4, 8


def box(x0: int, x1: int) -> np.ndarray:
    mask = np.zeros((H, W), dtype=bool)
    mask[:, x0:x1] = True
    return mask


def link(*frames: list[np.ndarray]) -> list[list[int]]:
    linker, out = TubeLinker(), []
    empty_truth = ground_truth_frame(np.zeros((H, W), dtype=np.uint32), 0.0, 1)
    for masks in frames:
        frame = prediction_frame_from_masks(np.array(masks, dtype=bool).reshape(len(masks), H, W), 1)
        _, _, areas = ground_truth_overlap(empty_truth, frame)
        out.append(linker.add(frame, areas).tolist())
    return out


def test_unmatched_masks_start_new_tubes_in_mask_order() -> None:
    # Frame 1: mask 1 continues tube 1 (B); masks 0 and 2 are new and numbered in mask order.
    assert link([box(0, 2), box(4, 6)], [box(2, 3), box(4, 6), box(7, 8)]) == [[0, 1], [2, 1, 3]]


def test_a_tube_that_loses_its_match_ends() -> None:
    # A is absent in frame 1; when it comes back in frame 2 it cannot rejoin tube 0.
    assert link([box(0, 2)], [box(5, 7)], [box(0, 2)]) == [[0], [1], [2]]


def test_a_frame_without_masks_is_one_empty_mask_that_starts_a_tube() -> None:
    assert link([box(0, 2)], [], [box(0, 2)]) == [[0], [1], [2]]


def test_ties_go_to_the_first_column_as_scipy_resolves_them() -> None:
    # Two identical masks compete for tube 0: the Hungarian solver keeps the first.
    assert link([box(0, 2)], [box(0, 2), box(0, 2)]) == [[0], [0, 1]]


def test_dice_matrix_is_float32_and_zero_where_areas_are_zero() -> None:
    f = dice_matrix(np.array([[2, 0]]), np.array([4]), np.array([2, 0]))
    assert f.dtype == np.float32
    assert f.tolist() == [[np.float32(2 * 1.0 * 0.5 / 1.5), 0.0]]
    rows, cols = match_by_dice(np.array([[0]]), np.array([3]), np.array([3]))
    assert rows.size == cols.size == 0  # an F = 0 assignment is dropped


def test_tracked_predictions_use_their_ids_instead_of_linking() -> None:
    """The object jumps from the left to the right half after frame 0: linking breaks the tube, an id keeps it."""
    truth = np.zeros((4, H, W), dtype=np.uint32)
    truth[0, :, :4] = 1
    truth[1:, :, 4:] = 1
    masks = [np.stack([truth[t] == 1]) for t in range(4)]
    protocol = VsqProtocol(ks=(1, 3), window=3, stride=3, min_area_fraction=0.0, subsample=1)
    gt = [ground_truth_frame(frame, 0.0, 1) for frame in truth]
    tracked = evaluate_video(gt, [prediction_frame_from_masks(m, 1, np.array([5])) for m in masks], (), protocol)
    assert counts(tracked, NON_ZERO_SHOT, 3) == (1, 0, 0)
    assert tracked[NON_ZERO_SHOT][3].iou == 1.0
    linked = evaluate_arrays(truth, masks, protocol=protocol)
    assert counts(linked, NON_ZERO_SHOT, 3) == (1, 1, 0)  # two tubes: 16 px (frame 0) and 32 px (frames 1-2)
    assert linked[NON_ZERO_SHOT][3].iou == 32 / 48
