"""Per-frame segment statistics shared by the renderer and the MVPd importer: hand-counted cases."""

from __future__ import annotations

import numpy as np

from pipeline.io.segments import DenseLabels, frame_segments


def test_areas_boxes_and_categories_of_a_hand_drawn_frame() -> None:
    ids = np.zeros((4, 6), np.uint32)
    ids[0:2, 1:4] = 0xC4FBAF  # rows 0..1, columns 1..3
    ids[3, 5] = 7  # one pixel in the corner
    labels = DenseLabels.from_categories({7: 5, 0xC4FBAF: 39, 0x00FF00: 2})  # 0x00FF00 is not in this frame
    found = frame_segments(ids, labels)
    assert found.object_ids.tolist() == [7, 0xC4FBAF]  # by id; absent objects give no row
    assert found.categories.tolist() == [5, 39]
    assert found.areas.tolist() == [1, 2 * 3]
    assert found.boxes.tolist() == [[5, 3, 6, 4], [1, 0, 4, 2]]  # x0, y0, x1, y1 with x1, y1 exclusive
    assert found.void_pixels == 4 * 6 - 1 - 6


def test_an_all_void_frame_has_no_segments() -> None:
    found = frame_segments(np.zeros((3, 2), np.uint32), DenseLabels.from_categories({9: 1}))
    assert found.object_ids.tolist() == [] and found.boxes.shape == (0, 4) and found.void_pixels == 6


def test_random_frames_match_a_brute_force_count() -> None:
    rng = np.random.default_rng(3)
    pool = np.array([0, 3, 0x1A2B3C, 0xFFFFFF], np.uint32)
    labels = DenseLabels.from_categories({3: 1, 0x1A2B3C: 2, 0xFFFFFF: 40})
    for _ in range(20):
        ids = rng.choice(pool, size=(7, 9))
        found = frame_segments(ids, labels)
        assert found.object_ids.tolist() == [i for i in np.unique(ids).tolist() if i != 0]
        for k, object_id in enumerate(found.object_ids):
            rows, columns = np.nonzero(ids == object_id)
            assert found.areas[k] == len(rows)
            assert found.boxes[k].tolist() == [columns.min(), rows.min(), columns.max() + 1, rows.max() + 1]
        assert found.void_pixels == int((ids == 0).sum())


def _brute_force(ids: np.ndarray) -> dict[int, tuple[int, list[int]]]:
    """{id: (area, [x0, y0, x1, y1])} of every id in `ids`, void included, counted pixel by pixel."""
    out = {}
    for object_id in np.unique(ids).tolist():
        rows, columns = np.nonzero(ids == object_id)
        out[object_id] = (len(rows), [columns.min(), rows.min(), columns.max() + 1, rows.max() + 1])
    return out


def test_frames_of_long_runs_match_a_brute_force_count() -> None:
    # Rendered frames are runs of one id along each row (frame_segments counts by runs): overlapping
    # rectangles, runs that end at a row's last pixel, a row of one run, one-column and one-row frames.
    rng = np.random.default_rng(5)
    pool = np.array([3, 0x1A2B3C, 0xFFFFFF, 0xC4FBAF], np.uint32)
    labels = DenseLabels.from_categories({int(i): 1 for i in pool})
    for height, width in [(16, 23)] * 12 + [(1, 17), (13, 1), (1, 1)]:
        ids = np.zeros((height, width), np.uint32)
        for object_id in rng.choice(pool, 3):
            y0, x0 = rng.integers(0, height), rng.integers(0, width)
            ids[y0:y0 + rng.integers(1, height + 1), x0:x0 + rng.integers(1, width + 1)] = object_id
        found = frame_segments(ids, labels)
        expected = _brute_force(ids)
        assert found.void_pixels == expected.get(0, (0, []))[0]
        assert {int(i): (int(a), b.tolist()) for i, a, b in zip(found.object_ids, found.areas, found.boxes)} == {
            i: e for i, e in expected.items() if i != 0}



def test_runs_around_whole_blocks_match_a_brute_force_count() -> None:
    # Runs are followed RUN_BLOCK pixels at a time: runs one short of, equal to and one past whole blocks, a
    # block that breaks at its last pixel, and rows whose last block is partial.
    from pipeline.io.segments import RUN_BLOCK

    pool = np.array([3, 0x1A2B3C, 0xFFFFFF], np.uint32)
    labels = DenseLabels.from_categories({int(i): 1 for i in pool})
    lengths = [RUN_BLOCK - 1, RUN_BLOCK, RUN_BLOCK + 1, 2 * RUN_BLOCK, 2 * RUN_BLOCK + 1, 1, 3 * RUN_BLOCK - 1]
    rng = np.random.default_rng(11)
    for width in (RUN_BLOCK, 3 * RUN_BLOCK + 5, 64):
        ids = np.zeros((len(lengths), width), np.uint32)
        for row, first in enumerate(lengths):
            column, k = 0, row
            while column < width:
                length = first if column == 0 else lengths[k % len(lengths)]
                ids[row, column:column + length] = pool[k % len(pool)] if k % 4 else 0
                column, k = column + length, k + 1
        ids[rng.integers(0, len(lengths)), rng.integers(0, width)] = pool[0]  # a lone pixel inside some block
        found = frame_segments(ids, labels)
        expected = _brute_force(ids)
        assert found.void_pixels == expected.get(0, (0, []))[0]
        assert {int(i): (int(a), b.tolist()) for i, a, b in zip(found.object_ids, found.areas, found.boxes)} == {
            i: e for i, e in expected.items() if i != 0}


def test_unique_with_inverse_is_numpys_unique():
    from pipeline.io.segments import unique_with_inverse

    ids = np.random.default_rng(0).choice(np.array([0, 7, 70000, 2**31 + 5], np.uint32), size=(48, 64))
    unique, inverse = unique_with_inverse(ids)
    expected_unique, expected_inverse = np.unique(ids, return_inverse=True)
    assert np.array_equal(unique, expected_unique) and unique.dtype == ids.dtype
    assert inverse.shape == ids.shape and np.array_equal(inverse, expected_inverse.reshape(ids.shape))
    assert np.array_equal(unique[inverse], ids)
