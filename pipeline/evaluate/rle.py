"""COCO run-length encodings straight to subsampled runs, without decoding full-resolution masks.

A COCO RLE lists alternating background / foreground run lengths over the column-major (Fortran)
flattened H x W image. Decoding 70 full-resolution masks per frame only to keep every second row and
column would cost most of an evaluation, so the counts are decoded (vectorised, all masks of a frame
at once) and the foreground runs are mapped directly to runs of the subsampled image. The result is
bit-identical to `pycocotools.mask.decode(rle)[:h*s:s, :w*s:s]` with h = H // s, w = W // s, which is
what the published evaluator's nearest-neighbour `F.interpolate(scale_factor=0.5)` keeps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.evaluate.errors import PredictionError

# Characters of the compressed alphabet are 48 ('0') .. 111 ('o'): 6 bits each.
_FIRST_CHAR, _LAST_CHAR = 48, 111
# Longest token that fits in int64: 12 characters of 5 value bits.
_MAX_TOKEN_CHARS = 12


@dataclass(frozen=True)
class Runs:
    """Foreground runs [start, end) of several masks in one column-major flattened image.

    Attributes:
        start: (n,) int64 first flat index of each run.
        end: (n,) int64 one past the last flat index.
        mask: (n,) int64 index of the mask the run belongs to.
    """

    start: np.ndarray
    end: np.ndarray
    mask: np.ndarray


def _segmented_cumsum(values: np.ndarray, segment_start: np.ndarray, segment_of: np.ndarray) -> np.ndarray:
    """Cumulative sum of `values` restarting at every segment (segments are contiguous and ordered)."""
    total = np.cumsum(values)
    before = np.concatenate([[0], total])[segment_start]
    return total - before[segment_of]


def decode_counts(counts: list[bytes], source: str) -> tuple[np.ndarray, np.ndarray]:
    """Decode COCO compressed RLE strings (all masks of a frame at once) into run lengths.

    Mirrors pycocotools' `rleFrString`: 5 value bits per character, 0x20 = more characters follow,
    0x10 in a token's last character = negative, and from the fourth count on a count is stored as the
    difference to the count two places before.

    Args:
        counts: one compressed `counts` string per mask (bytes).
        source: file name used in error messages.

    Returns:
        (lengths, offsets): all run lengths concatenated (int64), and offsets (n + 1,) so that mask i
        owns lengths[offsets[i]:offsets[i + 1]].
    """
    return decode_joined_counts(b"".join(counts), [len(c) for c in counts], source)


def decode_joined_counts(joined: bytes, lengths_of_strings: list[int], source: str) -> tuple[np.ndarray, np.ndarray]:
    """`decode_counts` of the strings concatenated in `joined`, string i being lengths_of_strings[i] long."""
    count = len(lengths_of_strings)
    sizes = np.array(lengths_of_strings, dtype=np.int64)
    if np.any(sizes == 0):
        raise PredictionError(f"{source}: an RLE has empty 'counts'; re-encode the mask with pycocotools")
    chars = np.frombuffer(joined, dtype=np.uint8).astype(np.int64)
    if chars.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(count + 1, dtype=np.int64)
    if chars.min() < _FIRST_CHAR or chars.max() > _LAST_CHAR:
        raise PredictionError(f"{source}: corrupt RLE (character outside the COCO alphabet); re-encode the mask with pycocotools")
    chars -= _FIRST_CHAR
    ends = (chars & 0x20) == 0
    string_last = np.cumsum(sizes) - 1
    if not np.all(ends[string_last]):
        raise PredictionError(f"{source}: corrupt RLE (counts string ends inside a number); re-encode the mask with pycocotools")
    end_index = np.flatnonzero(ends)
    token_start = np.concatenate([[0], end_index[:-1] + 1])
    token_of_char = np.cumsum(ends) - ends
    position = np.arange(chars.size) - token_start[token_of_char]
    if position.max() >= _MAX_TOKEN_CHARS:
        raise PredictionError(f"{source}: corrupt RLE (a run length with too many digits); re-encode the mask with pycocotools")
    tokens = np.add.reduceat((chars & 0x1F) << (5 * position), token_start)
    negative = (chars[end_index] & 0x10) != 0
    tokens[negative] |= np.left_shift(np.int64(-1), 5 * (position[end_index][negative] + 1))

    tokens_per_string = np.bincount(np.searchsorted(string_last, end_index), minlength=count)
    offsets = np.concatenate([[0], np.cumsum(tokens_per_string)])
    string_of_token = np.repeat(np.arange(count), tokens_per_string)
    j = np.arange(tokens.size) - offsets[string_of_token]
    # From the fourth count on (j >= 3) a count is a delta to count j - 2: a cumulative sum per parity.
    odd = _segmented_cumsum(np.where(j % 2 == 1, tokens, 0), offsets[:-1], string_of_token)
    even = _segmented_cumsum(np.where((j % 2 == 0) & (j >= 2), tokens, 0), offsets[:-1], string_of_token)
    lengths = np.where(j == 0, tokens, np.where(j % 2 == 1, odd, even))
    return lengths, offsets


def runs_from_lengths(lengths: np.ndarray, offsets: np.ndarray, pixels: int, source: str) -> Runs:
    """Foreground runs of masks given as run lengths (background first), validated against the size."""
    n = len(offsets) - 1
    string_of = np.repeat(np.arange(n), np.diff(offsets))
    if lengths.size and lengths.min() < 0:
        raise PredictionError(f"{source}: corrupt RLE (negative run length); re-encode the mask with pycocotools")
    totals = np.bincount(string_of, weights=lengths, minlength=n) if n else np.zeros(0)
    if np.any(totals != pixels):
        bad = int(np.flatnonzero(totals != pixels)[0])
        raise PredictionError(f"{source}: corrupt RLE (mask {bad}: run lengths add up to {int(totals[bad])}, "
                              f"not {pixels} pixels); re-encode the mask with pycocotools")
    end = _segmented_cumsum(lengths, offsets[:-1], string_of)
    j = np.arange(lengths.size) - offsets[string_of]
    foreground = (j % 2 == 1) & (lengths > 0)
    return Runs(start=(end - lengths)[foreground], end=end[foreground], mask=string_of[foreground])


def subsample_runs(runs: Runs, height: int, width: int, stride: int) -> Runs:
    """Map full-resolution column-major runs to runs of the image keeping every `stride`-th row and column.

    Kept pixels are rows r * stride (r < height // stride) of columns c * stride (c < width // stride);
    a run may span several columns, so it is split per kept column first.
    """
    if stride == 1:
        return runs
    rows, columns = height // stride, width // stride
    first_col = runs.start // height
    last_col = (runs.end - 1) // height
    spans = last_col - first_col + 1
    piece_of = np.repeat(np.arange(runs.start.size), spans)
    column = first_col[piece_of] + (np.arange(piece_of.size) - np.repeat(np.cumsum(spans) - spans, spans))
    keep = (column % stride == 0) & (column // stride < columns)
    piece_of, column = piece_of[keep], column[keep]
    top = np.maximum(runs.start[piece_of] - column * height, 0)
    bottom = np.minimum(runs.end[piece_of] - column * height, height)
    # Kept rows r satisfy top <= r * stride < bottom.
    row_start = -(-top // stride)
    row_end = np.minimum(-(-bottom // stride), rows)
    nonempty = row_end > row_start
    base = (column // stride) * rows
    return Runs(start=(base + row_start)[nonempty], end=(base + row_end)[nonempty], mask=runs.mask[piece_of][nonempty])


def runs_from_masks(masks: np.ndarray) -> Runs:
    """Foreground runs of dense boolean masks (n, H, W), column-major like COCO RLE."""
    count, height, width = masks.shape
    flat = np.ascontiguousarray(masks.transpose(0, 2, 1)).reshape(count, height * width).astype(np.int8)
    padded = np.zeros((count, flat.shape[1] + 2), dtype=np.int8)
    padded[:, 1:-1] = flat
    change = np.diff(padded, axis=1)
    mask_of_start, start = np.nonzero(change == 1)
    _, end = np.nonzero(change == -1)
    return Runs(start=start.astype(np.int64), end=end.astype(np.int64), mask=mask_of_start.astype(np.int64))
