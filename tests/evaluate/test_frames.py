"""Per-frame arrays: atom partitions of overlapping masks, tracker id images, unique rows."""

from __future__ import annotations

import numpy as np

from pipeline.evaluate import frames
from pipeline.evaluate.frames import ground_truth_frame, ground_truth_overlap, prediction_frame_from_ids, prediction_frame_from_masks


def test_overlapping_masks_give_exact_intersections_and_areas() -> None:
    truth = np.zeros((4, 6), dtype=np.uint32)
    truth[:, :3] = 8
    a = np.zeros((4, 6), dtype=bool)
    a[:2, :] = True  # 12 px, 6 on object 8
    b = np.zeros((4, 6), dtype=bool)
    b[:, 2:4] = True  # 8 px, 4 on object 8; overlaps a on 4 px
    prediction = prediction_frame_from_masks(np.stack([a, b]), stride=1)
    inter, truth_areas, mask_areas = ground_truth_overlap(ground_truth_frame(truth, 0.0, 1), prediction)
    assert inter.tolist() == [[6, 4]]
    assert truth_areas.tolist() == [12]
    assert mask_areas.tolist() == [12, 8]
    assert prediction.membership.shape[0] == 4  # atoms: neither, a only, b only, both


def test_tracker_id_image_gives_one_mask_per_id_in_ascending_order() -> None:
    ids = np.array([[0, 9, 9], [4, 4, 0]], dtype=np.uint32)
    frame = prediction_frame_from_ids(ids, stride=1)
    assert frame.ids.tolist() == [4, 9]
    _, _, areas = ground_truth_overlap(ground_truth_frame(np.zeros_like(ids), 0.0, 1), frame)
    assert areas.tolist() == [2, 2]


def test_unique_rows_hash_path_and_exact_path_agree() -> None:
    rows = np.random.default_rng(0).integers(0, 3, size=(500, 3)).astype(np.uint64)
    for unique, inverse in (frames._unique_rows(rows), frames._unique_rows_exact(rows)):
        assert np.array_equal(unique[inverse], rows)
        assert len(unique) == len(np.unique(rows, axis=0))  # 27 at most
