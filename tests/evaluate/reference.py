"""A slow, literal re-statement of the published evaluator on dense boolean arrays (tests only).

It follows the published code path step by step (per-id masks, per-frame mask stacks, tube tensors
grown frame by frame, pairwise F in a double loop) so that the fast implementation can be checked
against it on random inputs. Never used outside tests.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def _metrics(truth: np.ndarray, pred: np.ndarray) -> tuple[float, float]:
    intersection = int(np.logical_and(truth, pred).sum())
    pred_area, truth_area = int(pred.sum()), int(truth.sum())
    precision = intersection / pred_area if pred_area > 0 else 0
    recall = intersection / truth_area if truth_area > 0 else 0
    f_score = (2 * precision * recall) / (precision + recall) if (precision + recall) > 0 else 0
    union = pred_area + truth_area - intersection
    return float(f_score), float(intersection / union if union > 0 else 0)


def _match(true_segments: list[np.ndarray], pred_segments: list[np.ndarray]) -> tuple[list[int], list[int]]:
    matrix = np.zeros((len(true_segments), len(pred_segments)), dtype=np.float32)
    for a, truth in enumerate(true_segments):
        for b, pred in enumerate(pred_segments):
            matrix[a, b] = _metrics(truth, pred)[0]
    rows, cols = linear_sum_assignment(matrix, maximize=True)
    keep = [i for i in range(len(rows)) if matrix[rows[i], cols[i]] != 0]
    return [int(rows[i]) for i in keep], [int(cols[i]) for i in keep]


def _filter(label: np.ndarray, fraction: float) -> np.ndarray:
    out = np.zeros_like(label)
    minimum = label.shape[0] * label.shape[1] * fraction
    for value in np.unique(label):
        if (label == value).sum() >= minimum:
            out[label == value] = value
    return out


def reference_video(truth: np.ndarray, predictions: list[np.ndarray], zero_shot: set[int], ks: tuple[int, ...] = (1, 5, 10, 15),
                    window: int = 15, stride: int = 15, fraction: float = 0.001, step: int = 2) -> dict:
    """{bucket: {k: {"IOU", "TP", "FP", "FN"}}} of one video, the published way."""
    frames, height, width = truth.shape
    rows, cols = height // step, width // step
    result = {b: {k: {"IOU": 0.0, "TP": 0, "FP": 0, "FN": 0} for k in ks} for b in ("zero-shot", "non-zero-shot")}
    for start in range(0, frames - window, stride):
        labels = [_filter(truth[start + i], fraction)[: rows * step : step, : cols * step : step] for i in range(window)]
        masks = []
        for i in range(window):
            frame = predictions[start + i][:, : rows * step : step, : cols * step : step]
            masks.append(frame if len(frame) else np.zeros((1, rows, cols), dtype=bool))
        ids = [v for v in np.unique(np.stack(labels)) if v != 0]
        for k in ks:
            tubes: list[np.ndarray] = []  # each (k, rows, cols)
            previous: list[int] = []  # tube of each mask of the previous frame
            for i in range(k):
                current = [-1] * len(masks[i])
                if i > 0:
                    prev_masks = [tubes[t][i - 1] for t in previous]
                    r, c = _match(prev_masks, list(masks[i]))
                    for a, b in zip(r, c):
                        current[b] = previous[a]
                for b in range(len(masks[i])):
                    if current[b] < 0:
                        current[b] = len(tubes)
                        tubes.append(np.zeros((k, rows, cols), dtype=bool))
                    tubes[current[b]][i] = masks[i][b]
                previous = current
            truth_tubes = [(v, np.stack([lab == v for lab in labels[:k]])) for v in ids]
            truth_tubes = [(v, t) for v, t in truth_tubes if t.any()]
            r, c = _match([t for _, t in truth_tubes], tubes)
            for a, b in zip(r, c):
                bucket = "zero-shot" if truth_tubes[a][0] in zero_shot else "non-zero-shot"
                result[bucket][k]["IOU"] += _metrics(truth_tubes[a][1], tubes[b])[1]
                result[bucket][k]["TP"] += 1
            for bucket in result:
                result[bucket][k]["FP"] += len(tubes) - len(r)
            for a in set(range(len(truth_tubes))) - set(r):
                bucket = "zero-shot" if truth_tubes[a][0] in zero_shot else "non-zero-shot"
                result[bucket][k]["FN"] += 1
    return result
