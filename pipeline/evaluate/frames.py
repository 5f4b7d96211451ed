"""Per-frame arrays the VSQ metric works on: subsampled ground truth and predictions, and their overlaps.

Everything is in the subsampled image, flattened column-major (the order of COCO RLE runs).

Predicted masks may overlap, so a frame's masks are stored as a partition of the pixels into *atoms*:
maximal sets of pixels covered by exactly the same masks. `atoms` labels every pixel with its atom and
`membership` says which masks contain which atom. Every intersection count the metric needs (ground
truth x masks, masks of frame t-1 x masks of frame t) is then one `np.bincount` over the pixels and a
small matrix product: exact integer counts at a fraction of the cost of per-mask pixel loops.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Generic, Sequence, TypeVar

import numpy as np

from pipeline.evaluate.rle import Runs, runs_from_masks, subsample_runs

T = TypeVar("T")
# Above this many (atom x atom) bins a joint histogram is counted sparsely instead.
_DENSE_JOINT_LIMIT = 1 << 22


class TooManyMasksError(ValueError):
    """A frame with more masks than its reader allows (the argument: how many); the reader names the file."""


@dataclass(frozen=True)
class GroundTruthFrame:
    """One ground-truth frame after the small-segment filter and subsampling.

    Attributes:
        labels: (pixels,) int64; 0 = void, i + 1 = the object ids[i].
        ids: (n,) int64 object ids present in the subsampled frame, ascending.
    """

    labels: np.ndarray
    ids: np.ndarray


@dataclass(frozen=True)
class PredictionFrame:
    """One frame's predicted masks after subsampling, as an atom partition.

    Attributes:
        atoms: (pixels,) int64 atom index of every pixel.
        membership: (atoms, masks) float64 0/1: which masks contain each atom.
        ids: (masks,) int64 tracker ids (ascending, unique), or None for per-frame masks to be linked.
    """

    atoms: np.ndarray
    membership: np.ndarray
    ids: np.ndarray | None = None

    @property
    def masks(self) -> int:
        return int(self.membership.shape[1])


class LazyFrames(Sequence[T], Generic[T]):
    """A sequence whose items are built on access (frames are read only when a window needs them)."""

    def __init__(self, length: int, load: Callable[[int], T]):
        self._length = length
        self._load = load

    def __len__(self) -> int:
        return self._length

    def __getitem__(self, index: int) -> T:  # type: ignore[override]
        if not 0 <= index < self._length:
            raise IndexError(index)
        return self._load(index)


def subsampled_shape(height: int, width: int, stride: int) -> tuple[int, int]:
    """(rows, columns) kept by nearest-neighbour subsampling with scale 1 / stride, as torch does."""
    return height // stride, width // stride


def _compact(flat: np.ndarray, keep_ids: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Label image -> (labels 0..n, present ids) with 0 for void and for ids not in `keep_ids`.

    Works on runs of equal values, so the per-pixel work is one comparison and one `np.repeat`.
    """
    starts = np.concatenate([[0], np.flatnonzero(flat[1:] != flat[:-1]) + 1])
    lengths = np.diff(np.append(starts, flat.size))
    values = flat[starts].astype(np.int64)
    candidates = np.unique(values)
    candidates = candidates[candidates != 0]
    if keep_ids is not None:
        candidates = candidates[np.isin(candidates, keep_ids)]
    index = np.searchsorted(candidates, values)
    hit = (index < candidates.size) & (candidates[np.minimum(index, max(candidates.size - 1, 0))] == values) \
        if candidates.size else np.zeros(values.shape, dtype=bool)
    labels = np.repeat(np.where(hit, index + 1, 0), lengths)
    return labels, candidates


def _value_counts(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sorted distinct values, pixel counts) via runs of equal values: ids come in long runs."""
    starts = np.concatenate([[0], np.flatnonzero(flat[1:] != flat[:-1]) + 1])
    lengths = np.diff(np.append(starts, flat.size))
    values, inverse = np.unique(flat[starts], return_inverse=True)
    return values, np.bincount(inverse.reshape(-1), weights=lengths, minlength=values.size).astype(np.int64)


def ground_truth_frame(label: np.ndarray, min_area_fraction: float, stride: int) -> GroundTruthFrame:
    """Filter and subsample one full-resolution id image (the published evaluator's steps 1).

    Ids covering fewer than `min_area_fraction` of the full-resolution pixels become void (the
    comparison `count >= H * W * fraction` in double precision, as published); then every
    `stride`-th row and column is kept.
    """
    height, width = label.shape
    ids, counts = _value_counts(label.ravel())
    kept = ids[(ids != 0) & (counts >= height * width * min_area_fraction)].astype(np.int64)
    rows, columns = subsampled_shape(height, width, stride)
    sub = label[: rows * stride : stride, : columns * stride : stride]
    labels, present = _compact(np.ascontiguousarray(sub.T).ravel(), kept)
    return GroundTruthFrame(labels=labels, ids=present)


def prediction_frame_from_ids(label: np.ndarray, stride: int, max_masks: int | None = None) -> PredictionFrame:
    """A tracker's id image (0 = no prediction) -> one mask per id, carrying the ids.

    Raises:
        TooManyMasksError: more than `max_masks` ids (None: no bound), found before the (ids x ids) arrays
            are built.
    """
    rows, columns = subsampled_shape(*label.shape, stride)
    sub = label[: rows * stride : stride, : columns * stride : stride]
    labels, ids = _compact(np.ascontiguousarray(sub.T).ravel(), None)
    if max_masks is not None and ids.size > max_masks:
        raise TooManyMasksError(ids.size)
    membership = np.vstack([np.zeros((1, ids.size)), np.eye(ids.size)])
    return PredictionFrame(atoms=labels, membership=membership, ids=ids)


def prediction_frame_from_runs(runs: Runs, masks: int, pixels: int, ids: np.ndarray | None = None) -> PredictionFrame:
    """Per-frame masks given as subsampled runs -> atom partition.

    A frame without masks becomes one empty mask (the published evaluator's rule), unless the masks
    carry tracker ids. With `ids`, masks sharing an id are merged into one.
    """
    if masks == 0 and ids is None:
        return PredictionFrame(atoms=np.zeros(pixels, dtype=np.int64), membership=np.zeros((1, 1)))
    words = max(1, (masks + 63) // 64)
    positions = np.concatenate([runs.start, runs.end])
    owner = np.concatenate([runs.mask, runs.mask])
    # Events at one position are XOR-combined and only the state after the last one is kept, so
    # their order does not matter and an unstable (faster) sort will do.
    order = np.argsort(positions)
    positions, owner = positions[order], owner[order]
    toggles = np.zeros((positions.size + 1, words), dtype=np.uint64)
    toggles[np.arange(1, positions.size + 1), owner // 64] = np.left_shift(np.uint64(1), (owner % 64).astype(np.uint64))
    # Runs of one mask never overlap, so entering and leaving a run both flip the mask's bit: the
    # membership of the pixels after an event is the running XOR of the flips.
    signatures = np.bitwise_xor.accumulate(toggles, axis=0)
    last_at_position = np.append(positions[1:] != positions[:-1], True)[: positions.size]
    starts = np.concatenate([[0], positions[last_at_position]])
    signatures = np.vstack([signatures[:1], signatures[1:][last_at_position]])
    lengths = np.diff(np.append(starts, pixels))
    unique, inverse = _unique_rows(signatures)
    atoms = np.repeat(inverse, lengths)
    bits = np.unpackbits(unique.astype("<u8").view(np.uint8).reshape(unique.shape[0], -1), axis=1, bitorder="little")
    membership = bits[:, :masks].astype(np.float64)
    if ids is not None:
        membership, ids = _merge_by_id(membership, ids)
    return PredictionFrame(atoms=atoms, membership=membership, ids=ids)


def prediction_frame_from_masks(masks: np.ndarray, stride: int, ids: np.ndarray | None = None) -> PredictionFrame:
    """Dense full-resolution boolean masks (n, H, W) -> PredictionFrame (as if read from RLE files)."""
    count, height, width = masks.shape
    rows, columns = subsampled_shape(height, width, stride)
    runs = subsample_runs(runs_from_masks(masks), height, width, stride)
    return prediction_frame_from_runs(runs, count, rows * columns, ids)


def _unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique rows, inverse) of a 2-D uint64 array.

    Rows are hashed to one uint64 and uniqued in 1-D (much faster than `np.unique(axis=0)`); the
    result is verified, and on the (never yet seen) hash collision the exact per-column path is taken.
    """
    if rows.shape[1] == 1:
        values, inverse = np.unique(rows[:, 0], return_inverse=True)
        return values[:, None], inverse.reshape(-1)
    with np.errstate(over="ignore"):
        hashed = rows[:, 0].copy()
        for column in range(1, rows.shape[1]):
            hashed = hashed * np.uint64(0x9E3779B97F4A7C15) ^ rows[:, column]
    _, first, inverse = np.unique(hashed, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    unique = rows[first]
    if np.array_equal(unique[inverse], rows):
        return unique, inverse
    return _unique_rows_exact(rows)


def _unique_rows_exact(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique rows, inverse) by combining per-column inverses, without hashing."""
    inverse = np.zeros(rows.shape[0], dtype=np.int64)
    for column in range(rows.shape[1]):
        values, column_inverse = np.unique(rows[:, column], return_inverse=True)
        _, inverse = np.unique(inverse * values.size + column_inverse.reshape(-1), return_inverse=True)
        inverse = inverse.reshape(-1)
    first = np.zeros(int(inverse.max()) + 1, dtype=np.int64)
    first[inverse] = np.arange(rows.shape[0])
    return rows[first], inverse


def _merge_by_id(membership: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Union of the masks that share a tracker id; columns in ascending id order."""
    unique, column = np.unique(np.asarray(ids, dtype=np.int64), return_inverse=True)
    merge = np.zeros((ids.size, unique.size))
    merge[np.arange(ids.size), column] = 1.0
    return np.minimum(membership @ merge, 1.0), unique


def _joint_histogram(first: np.ndarray, first_count: int, second: np.ndarray, second_count: int) -> np.ndarray:
    """(first_count, second_count) pixel counts of every pair of labels, as float64 (exact integers)."""
    key = first * second_count + second
    if first_count * second_count <= _DENSE_JOINT_LIMIT:
        counts = np.bincount(key, minlength=first_count * second_count)
        return counts.reshape(first_count, second_count).astype(np.float64)
    values, counts = np.unique(key, return_counts=True)
    joint = np.zeros((first_count, second_count))
    joint[values // second_count, values % second_count] = counts
    return joint


def ground_truth_overlap(truth: GroundTruthFrame, prediction: PredictionFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel counts of one frame: (truth x masks intersections, truth areas, mask areas), int64."""
    atoms = prediction.membership.shape[0]
    joint = _joint_histogram(truth.labels, truth.ids.size + 1, prediction.atoms, atoms)
    intersections = joint[1:] @ prediction.membership
    mask_areas = joint.sum(axis=0) @ prediction.membership
    return (np.rint(intersections).astype(np.int64), joint[1:].sum(axis=1).astype(np.int64),
            np.rint(mask_areas).astype(np.int64))


def mask_overlap(previous: PredictionFrame, current: PredictionFrame) -> np.ndarray:
    """(previous masks x current masks) intersection pixel counts, int64."""
    joint = _joint_histogram(previous.atoms, previous.membership.shape[0], current.atoms, current.membership.shape[0])
    return np.rint(previous.membership.T @ joint @ current.membership).astype(np.int64)
