"""COCO RLE decoding straight to subsampled runs equals pycocotools' decode + slicing."""

from __future__ import annotations

import numpy as np
import pycocotools.mask as mask_utils
import pytest

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:pycocotools")

from pipeline.evaluate.errors import PredictionError
from pipeline.evaluate.rle import decode_counts, runs_from_lengths, subsample_runs


def _dense(runs, mask: int, rows: int, columns: int) -> np.ndarray:
    flat = np.zeros(rows * columns, dtype=bool)
    for start, end in zip(runs.start[runs.mask == mask], runs.end[runs.mask == mask]):
        flat[start:end] = True
    return flat.reshape(columns, rows).T


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_runs_equal_pycocotools_decode_then_slicing(stride: int) -> None:
    rng = np.random.default_rng(stride)
    height, width = 31, 40  # odd height: the last row is dropped as torch's nearest resize does
    masks = np.zeros((height, width, 5), dtype=np.uint8, order="F")
    masks[..., 0] = rng.random((height, width)) < 0.5  # many short runs
    masks[3:20, 5:33, 1] = 1  # one block
    masks[..., 2] = 1  # runs spanning every column
    masks[0, 0, 4] = masks[-1, -1, 4] = 1  # first and last pixel; mask 3 stays empty
    rles = mask_utils.encode(masks)
    lengths, offsets = decode_counts([r["counts"] for r in rles], "test")
    runs = subsample_runs(runs_from_lengths(lengths, offsets, height * width, "test"), height, width, stride)
    rows, columns = height // stride, width // stride
    for index in range(5):
        expected = mask_utils.decode(rles[index])[: rows * stride: stride, : columns * stride: stride].astype(bool)
        assert np.array_equal(_dense(runs, index, rows, columns), expected), index


@pytest.mark.parametrize("counts, message", [
    (b"\x7f\x7f", "outside the COCO alphabet"),
    (b"0Q", "ends inside a number"),  # 'Q' - 48 = 33 has the continuation bit set
    (b"52", "add up to"),  # 5 + 2 pixels, not 12
])
def test_corrupt_counts_raise_with_the_file_name(counts: bytes, message: str) -> None:
    with pytest.raises(PredictionError, match=message) as error:
        lengths, offsets = decode_counts([counts], "pred/v/0000000000.json")
        runs_from_lengths(lengths, offsets, 12, "pred/v/0000000000.json")
    assert "pred/v/0000000000.json" in str(error.value)
