"""Dice-Hungarian matching and tube linking, exactly as the published MVPd evaluator does them.

The assignment's tie-breaking depends on the matrix's values and order, so both are reproduced: F in
double precision (P = I / |pred|, R = I / |truth|, F = 2PR / (P + R), 0 where a denominator is 0),
stored in a float32 matrix, solved by `scipy.optimize.linear_sum_assignment(..., maximize=True)`,
and assigned pairs whose stored F is 0 dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from pipeline.evaluate.frames import PredictionFrame, mask_overlap


def dice_matrix(intersections: np.ndarray, row_areas: np.ndarray, column_areas: np.ndarray) -> np.ndarray:
    """Published F-score matrix (rows are the 'true' side, columns the 'predicted' side) as float32."""
    inter = intersections.astype(np.float64)
    columns = np.broadcast_to(column_areas.astype(np.float64)[None, :], inter.shape)
    rows = np.broadcast_to(row_areas.astype(np.float64)[:, None], inter.shape)
    precision = np.divide(inter, columns, out=np.zeros_like(inter), where=columns > 0)
    recall = np.divide(inter, rows, out=np.zeros_like(inter), where=rows > 0)
    total = precision + recall
    # Same operation order as the published code: (2 * P * R) / (P + R).
    f_score = np.divide(2 * precision * recall, total, out=np.zeros_like(inter), where=total > 0)
    return f_score.astype(np.float32)


def iou_values(intersections: np.ndarray, row_areas: np.ndarray, column_areas: np.ndarray) -> np.ndarray:
    """IoU = I / (|truth| + |pred| - I) in double precision, 0 where the union is empty."""
    union = (row_areas + column_areas - intersections).astype(np.float64)
    return np.divide(intersections.astype(np.float64), union, out=np.zeros(union.shape), where=union > 0)


def match_by_dice(intersections: np.ndarray, row_areas: np.ndarray, column_areas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hungarian assignment maximising F; returns (rows, columns) of the kept pairs, rows ascending."""
    if intersections.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    f_score = dice_matrix(intersections, row_areas, column_areas)
    rows, columns = linear_sum_assignment(f_score, maximize=True)
    keep = f_score[rows, columns] != 0
    return rows[keep].astype(np.int64), columns[keep].astype(np.int64)


@dataclass
class TubeLinker:
    """Links a window's per-frame masks into tubes, one frame at a time (published step 6).

    The first frame's masks start tubes 0..n-1. Each later frame's masks are matched to the previous
    frame's masks by `match_by_dice`; a matched mask continues its partner's tube, unmatched masks
    start new tubes in ascending mask order, and a tube whose mask found no partner ends. Tubes are
    numbered in the order they start, which is the column order of the final assignment.
    """

    tubes: int = 0
    _previous: PredictionFrame | None = None
    _previous_tubes: np.ndarray | None = None
    _previous_areas: np.ndarray | None = None

    def add(self, frame: PredictionFrame, areas: np.ndarray) -> np.ndarray:
        """Tube index of each mask of the next frame; `areas` are the masks' pixel counts."""
        tube_of_mask = np.full(frame.masks, -1, dtype=np.int64)
        if self._previous is not None and self._previous_tubes is not None and self._previous_areas is not None:
            overlap = mask_overlap(self._previous, frame)
            rows, columns = match_by_dice(overlap, self._previous_areas, areas)
            tube_of_mask[columns] = self._previous_tubes[rows]
        new = np.flatnonzero(tube_of_mask < 0)
        tube_of_mask[new] = self.tubes + np.arange(new.size)
        self.tubes += new.size
        self._previous, self._previous_tubes, self._previous_areas = frame, tube_of_mask, areas
        return tube_of_mask


@dataclass
class IdTubes:
    """Tubes of a tracker that already carries ids: one tube per id, numbered in order of first sight.

    Column order in the assignment is ascending id among the tubes seen so far (see `VideoScorer`).
    """

    index: dict[int, int]

    def __init__(self) -> None:
        self.index = {}

    @property
    def tubes(self) -> int:
        return len(self.index)

    def add(self, frame: PredictionFrame, areas: np.ndarray) -> np.ndarray:
        """Tube index of each mask (id) of the next frame."""
        assert frame.ids is not None
        for tracker_id in frame.ids.tolist():
            self.index.setdefault(int(tracker_id), len(self.index))
        return np.array([self.index[int(i)] for i in frame.ids.tolist()], dtype=np.int64)

    def column_order(self) -> np.ndarray:
        """Tube indices sorted by ascending tracker id."""
        ids = np.array(list(self.index), dtype=np.int64)
        return np.array(list(self.index.values()), dtype=np.int64)[np.argsort(ids, kind="stable")]
