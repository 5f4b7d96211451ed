"""Video Segmentation Quality (VSQ), exactly as the published MVPd evaluator computes it.

The metric works on arrays (`GroundTruthFrame`, `PredictionFrame`) and never reads files. Per video
it returns integer counts plus IoU sums that add up (`Counts`, `VideoCounts`); ratios are computed
once, at the end, by `summarize` (zero-guarded). The protocol, step by step (DESIGN.md):

1. ground truth ids below `min_area_fraction` of the full frame become void; both sides keep every
   `subsample`-th row and column (done when the frames are built, see `frames.py`);
2. windows of `window` frames start every `stride` frames while start < T - window (exclusive);
   for each k in `ks` only the first k frames of a window are used;
3. ground-truth tubes are the ids present in those frames (ascending id); predicted tubes are the
   per-frame masks linked from the window's first frame (`linking.TubeLinker`);
4. intersections and areas are pixel counts summed over the k frames;
5. Dice-Hungarian assignment, F = 0 pairs dropped, every pair a TP adding its IoU; unassigned
   predictions are FP, unassigned ground truth FN;
7. counts go to the ground-truth object's bucket; every FP goes to both buckets;
8. pooled over videos (a video adds to a bucket only if TP + FN > 0 there);
   VSQ^k = sum IoU / (TP + FP / 2 + FN / 2); VSQ = mean over K.

Speed: each frame is read and reduced once per window to small count matrices; the k prefixes are
running sums over the window's frames, not recomputations.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from contextlib import nullcontext
from typing import Collection, ContextManager, Iterable, Sequence

import numpy as np

from pipeline.evaluate.frames import GroundTruthFrame, PredictionFrame, ground_truth_overlap
from pipeline.evaluate.linking import IdTubes, TubeLinker, iou_values, match_by_dice

ZERO_SHOT, NON_ZERO_SHOT, AGGREGATE = "zero-shot", "non-zero-shot", "aggregate"
BUCKETS = (ZERO_SHOT, NON_ZERO_SHOT)
SUMMARY_BUCKETS = (AGGREGATE, ZERO_SHOT, NON_ZERO_SHOT)


class ProtocolError(ValueError):
    """Inconsistent protocol options (e.g. a k longer than the window)."""


@dataclass(frozen=True)
class VsqProtocol:
    """The knobs of the protocol; every default is the published evaluator's value.

    Attributes:
        ks: prefix lengths k: only the first k frames of each window are scored.
        window: window length; windows start while start < T - window.
        stride: frames between window starts.
        min_area_fraction: ground-truth ids covering less than this fraction of the full-resolution
            frame become void.
        subsample: keep every n-th row and column of ground truth and predictions.
    """

    ks: tuple[int, ...] = (1, 5, 10, 15)
    window: int = 15
    stride: int = 15
    min_area_fraction: float = 0.001
    subsample: int = 2

    def __post_init__(self) -> None:
        if not self.ks or list(self.ks) != sorted(set(self.ks)) or self.ks[0] < 1:
            raise ProtocolError(f"evaluate.ks = {list(self.ks)}: give distinct positive frame counts in ascending order")
        if self.ks[-1] > self.window:
            raise ProtocolError(f"evaluate.ks: k = {self.ks[-1]} exceeds evaluate.window = {self.window}; lower k or lengthen the window")
        if self.stride < 1 or self.subsample < 1:
            raise ProtocolError("evaluate.stride and evaluate.subsample must be at least 1")

    @classmethod
    def from_config(cls, config: object) -> "VsqProtocol":
        """From `pipeline.config.EvaluateConfig` (or anything with the same attributes)."""
        return cls(ks=tuple(config.ks), window=config.window, stride=config.stride,  # type: ignore[attr-defined]
                   min_area_fraction=config.min_area_fraction, subsample=config.subsample)  # type: ignore[attr-defined]

    def window_starts(self, frames: int) -> range:
        """Published loop: range(0, T - window, stride); the bound is exclusive (T = 30 -> [0])."""
        return range(0, frames - self.window, self.stride)

    def frames_used(self, frames: int) -> list[int]:
        """Every frame index any window reads (the first max(ks) frames of each window)."""
        return [start + j for start in self.window_starts(frames) for j in range(self.ks[-1])]


@dataclass
class Counts:
    """Counts of one bucket at one k: TP, FP, FN and the sum of the TPs' IoU. They add up."""

    iou: float = 0.0
    tp: int = 0
    fp: int = 0
    fn: int = 0

    def __iadd__(self, other: "Counts") -> "Counts":
        self.iou += other.iou
        self.tp += other.tp
        self.fp += other.fp
        self.fn += other.fn
        return self

    @property
    def denominator(self) -> float:
        return self.tp + 0.5 * self.fp + 0.5 * self.fn

    def quality(self) -> float | None:
        """sum IoU / (TP + FP/2 + FN/2), or None when nothing was counted."""
        return self.iou / self.denominator if self.denominator > 0 else None

    def as_dict(self) -> dict[str, float | int]:
        return {"IOU": self.iou, "TP": self.tp, "FP": self.fp, "FN": self.fn}


@dataclass
class VideoCounts:
    """Per-bucket, per-k counts of one video (or a sum of videos)."""

    ks: tuple[int, ...]
    buckets: dict[str, dict[int, Counts]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for bucket in BUCKETS:
            self.buckets.setdefault(bucket, {k: Counts() for k in self.ks})

    def __getitem__(self, bucket: str) -> dict[int, Counts]:
        return self.buckets[bucket]

    def __iadd__(self, other: "VideoCounts") -> "VideoCounts":
        for bucket in BUCKETS:
            for k in self.ks:
                self.buckets[bucket][k] += other.buckets[bucket][k]
        return self

    def as_dict(self) -> dict[str, dict[str, dict[str, float | int]]]:
        """The published per-video layout: {bucket: {"k": {"IOU", "TP", "FP", "FN"}}}."""
        return {bucket: {str(k): self.buckets[bucket][k].as_dict() for k in self.ks} for bucket in BUCKETS}


# ------------------------------------------------------------------------------------- one video


def evaluate_video(truth: Sequence[GroundTruthFrame], predictions: Sequence[PredictionFrame],
                   zero_shot: Collection[int], protocol: VsqProtocol = VsqProtocol()) -> VideoCounts:
    """Counts of one video. Frames are accessed by index, once per window, only where windows need them.

    Args:
        truth: filtered, subsampled ground-truth frames (`frames.ground_truth_frame`).
        predictions: the same video's predictions (`frames.prediction_frame_from_*`), same length.
        zero_shot: object ids of the video that count as zero-shot; all others are non-zero-shot.
        protocol: the knobs (defaults: published values).
    """
    if len(truth) != len(predictions):
        raise ValueError(f"ground truth has {len(truth)} frames but predictions have {len(predictions)}")
    counts = VideoCounts(protocol.ks)
    zero_shot_ids = np.array(sorted(int(i) for i in zero_shot), dtype=np.int64)
    # The matrices are small (objects x atoms): a multi-threaded BLAS spends far more time waking and
    # spinning its threads than computing, and on a busy 2-core node that costs 10-50x.
    with _single_threaded_blas():
        for start in protocol.window_starts(len(truth)):
            _score_window(truth, predictions, start, protocol.ks, zero_shot_ids, counts)
    return counts


def _single_threaded_blas() -> ContextManager[object]:
    """Limit BLAS to one thread while a video is scored (threadpoolctl; a no-op when it is missing)."""
    try:
        from threadpoolctl import threadpool_limits
    except ModuleNotFoundError:
        return nullcontext()
    return threadpool_limits(1, user_api="blas")


@dataclass
class _FrameCounts:
    ids: np.ndarray
    intersections: np.ndarray
    truth_areas: np.ndarray
    tube_of_mask: np.ndarray
    mask_areas: np.ndarray
    tubes_so_far: int


def _score_window(truth: Sequence[GroundTruthFrame], predictions: Sequence[PredictionFrame], start: int,
                  ks: tuple[int, ...], zero_shot_ids: np.ndarray, counts: VideoCounts) -> None:
    frames: list[_FrameCounts] = []
    tubes: TubeLinker | IdTubes | None = None
    for offset in range(ks[-1]):
        gt, prediction = truth[start + offset], predictions[start + offset]
        if tubes is None:
            tubes = TubeLinker() if prediction.ids is None else IdTubes()
        elif (prediction.ids is None) != isinstance(tubes, TubeLinker):
            raise ValueError(f"frame {start + offset}: predictions mix tracked (with ids) and untracked frames")
        intersections, truth_areas, mask_areas = ground_truth_overlap(gt, prediction)
        tube_of_mask = tubes.add(prediction, mask_areas)
        frames.append(_FrameCounts(gt.ids, intersections, truth_areas, tube_of_mask, mask_areas, tubes.tubes))
    assert tubes is not None
    window_ids = np.unique(np.concatenate([f.ids for f in frames]))
    inter = np.zeros((window_ids.size, tubes.tubes), dtype=np.int64)
    truth_areas = np.zeros(window_ids.size, dtype=np.int64)
    tube_areas = np.zeros(tubes.tubes, dtype=np.int64)
    order = tubes.column_order() if isinstance(tubes, IdTubes) else np.arange(tubes.tubes)
    for offset, frame in enumerate(frames):
        rows = np.searchsorted(window_ids, frame.ids)
        # A tube holds at most one mask per frame, so these fancy-indexed additions never collide.
        inter[np.ix_(rows, frame.tube_of_mask)] += frame.intersections
        truth_areas[rows] += frame.truth_areas
        tube_areas[frame.tube_of_mask] += frame.mask_areas
        k = offset + 1
        if k in ks:
            columns = order[order < frame.tubes_so_far]
            _score_prefix(inter, truth_areas, tube_areas, window_ids, columns, zero_shot_ids, k, counts)


def _score_prefix(inter: np.ndarray, truth_areas: np.ndarray, tube_areas: np.ndarray, window_ids: np.ndarray,
                  columns: np.ndarray, zero_shot_ids: np.ndarray, k: int, counts: VideoCounts) -> None:
    """Steps 5 and 7 for the first k frames of one window."""
    present = np.flatnonzero(truth_areas > 0)
    matrix = inter[np.ix_(present, columns)]
    rows_area, columns_area = truth_areas[present], tube_areas[columns]
    rows, cols = match_by_dice(matrix, rows_area, columns_area)
    ious = iou_values(matrix[rows, cols], rows_area[rows], columns_area[cols])
    is_zero_shot = np.isin(window_ids[present], zero_shot_ids)
    false_positives = columns.size - rows.size
    for bucket, in_bucket in ((ZERO_SHOT, is_zero_shot), (NON_ZERO_SHOT, ~is_zero_shot)):
        matched = in_bucket[rows]
        target = counts.buckets[bucket][k]
        # Added one by one in assignment order, as published, so IoU sums agree to the last bit.
        for value in ious[matched].tolist():
            target.iou += value
        target.tp += int(matched.sum())
        target.fn += int(in_bucket.sum() - matched.sum())
        target.fp += false_positives


# ------------------------------------------------------------------------------------- summary


def pooled(videos: Iterable[VideoCounts], ks: tuple[int, ...]) -> dict[str, dict[int, Counts]]:
    """Step 8: counts pooled over videos per bucket; a video adds to a bucket only if TP + FN > 0 there.

    "aggregate" pools both buckets with each FP counted once (FPs are the same in both buckets).
    """
    totals = {bucket: {k: Counts() for k in ks} for bucket in SUMMARY_BUCKETS}
    for video in videos:
        for k in ks:
            for bucket in BUCKETS:
                own = video.buckets[bucket][k]
                if own.tp + own.fn > 0:
                    totals[bucket][k] += own
            zero, other = video.buckets[ZERO_SHOT][k], video.buckets[NON_ZERO_SHOT][k]
            both = Counts(zero.iou + other.iou, zero.tp + other.tp, other.fp, zero.fn + other.fn)
            if both.tp + both.fn > 0:
                totals[AGGREGATE][k] += both
    return totals


def summarize(videos: Iterable[VideoCounts], ks: tuple[int, ...]) -> dict[str, dict[str, float]]:
    """{"aggregate"|"zero-shot"|"non-zero-shot": {"1", "5", ..., "VSQ"}} as fractions.

    A bucket no video adds to (e.g. the zero-shot bucket of a split without zero-shot objects) is 0.0
    for every k and VSQ, as the published summary reports it.
    """
    summary: dict[str, dict[str, float]] = {}
    for bucket, per_k in pooled(videos, ks).items():
        values = {str(k): per_k[k].quality() or 0.0 for k in ks}
        values["VSQ"] = sum(values.values()) / len(ks)
        summary[bucket] = values
    return summary
