"""The fast metric against the published numbers (shared case) and a literal re-statement (random cases)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.evaluate.frames import LazyFrames, ground_truth_frame
from pipeline.evaluate.ground_truth import GroundTruthLoader, MvpdSplit
from pipeline.evaluate.predictions import PredictionSource
from pipeline.evaluate.vsq import VsqProtocol, evaluate_video, summarize
from tests.evaluate.helpers import evaluate_arrays
from tests.evaluate.reference import reference_video

CASE = Path(__file__).resolve().parents[1] / "data" / "vsq_small"


def _evaluate_case() -> dict:
    protocol = VsqProtocol()
    results = {}
    for spec in MvpdSplit(CASE / "MVPd", "test").videos():
        load = GroundTruthLoader(spec)
        shape = load(0).shape
        source = PredictionSource(CASE / "pred", spec.video_name, spec.stems)
        truth = LazyFrames(spec.frames, lambda i: ground_truth_frame(load(i), protocol.min_area_fraction, protocol.subsample))
        predictions = LazyFrames(spec.frames, lambda i: source.frame(i, shape, protocol.subsample))
        results[spec.key] = evaluate_video(truth, predictions, spec.zero_shot, protocol)
    return results


@pytest.mark.skipif(not CASE.is_dir(), reason="shared VSQ case not present")
def test_shared_case_reproduces_the_published_evaluator() -> None:
    expected = json.loads((CASE / "expected.json").read_text())
    results = _evaluate_case()
    assert sorted(results) == sorted(expected["per_video"])
    for video, counts in results.items():
        got = counts.as_dict()
        for bucket, per_k in expected["per_video"][video].items():
            for k, want in per_k.items():
                assert (got[bucket][k]["TP"], got[bucket][k]["FP"], got[bucket][k]["FN"]) == (want["TP"], want["FP"], want["FN"]), (video, bucket, k)
                assert got[bucket][k]["IOU"] == pytest.approx(want["IOU"], abs=1e-9), (video, bucket, k)
    summary = summarize(results.values(), VsqProtocol().ks)
    for bucket, values in expected["summary"].items():
        for key, value in values.items():
            assert summary[bucket][key] == pytest.approx(value, abs=1e-12), (bucket, key)


def _random_video(rng: np.random.Generator, frames: int, height: int, width: int) -> tuple[np.ndarray, list[np.ndarray]]:
    truth = np.zeros((frames, height, width), dtype=np.uint32)
    boxes = [(rng.integers(0, height), rng.integers(0, width), rng.integers(1, 9), rng.integers(1, 11), object_id)
             for object_id in rng.choice(np.arange(1, 1000), size=7, replace=False)]
    predictions = []
    for t in range(frames):
        for y, x, h, w, object_id in boxes:
            dy = int(rng.integers(-1, 2))
            truth[t, max(y + dy, 0): y + dy + h, x: x + w] = object_id
        masks = []
        for _ in range(int(rng.integers(0, 7))):
            kind = rng.random()
            if kind < 0.5 and truth[t].any():
                mask = truth[t] == rng.choice(np.unique(truth[t]))
                mask = np.roll(mask, int(rng.integers(-1, 2)), axis=int(rng.integers(0, 2)))
            elif kind < 0.6:
                mask = np.zeros((height, width), dtype=bool)  # an empty mask
            else:
                mask = np.zeros((height, width), dtype=bool)
                y, x = rng.integers(0, height), rng.integers(0, width)
                mask[y: y + rng.integers(1, 8), x: x + rng.integers(1, 8)] = True
            masks.append(mask)
            if rng.random() < 0.1:
                masks.append(mask.copy())  # duplicates make ties
        predictions.append(np.array(masks, dtype=bool).reshape(len(masks), height, width))
    return truth, predictions


@pytest.mark.parametrize("seed", range(6))
def test_fast_metric_equals_the_literal_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    truth, predictions = _random_video(rng, frames=32, height=16, width=21)
    zero_shot = set(int(v) for v in np.unique(truth)[1::2])
    protocol = VsqProtocol(min_area_fraction=0.01, subsample=2)
    fast = evaluate_arrays(truth, predictions, sorted(zero_shot), protocol).as_dict()
    slow = reference_video(truth, predictions, zero_shot, fraction=0.01, step=2)
    for bucket in slow:
        for k, want in slow[bucket].items():
            got = fast[bucket][str(k)]
            assert (got["TP"], got["FP"], got["FN"]) == (want["TP"], want["FP"], want["FN"]), (bucket, k)
            assert got["IOU"] == pytest.approx(want["IOU"], abs=1e-12), (bucket, k)
