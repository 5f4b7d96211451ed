"""The built-in segmenters: `geometric` finds the rendered room's objects; `oracle` degrades the truth as told."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.models.geometric import GeometricSegmenter
from pipeline.models.oracle import FLICKER_ID_BASE, OracleSegmenter
from pipeline.models.segmenter import FrameInput, ModelError, make_segmenter
from pipeline.render.renderer import VideoRenderer
from tests.render.tiny_scenes import CHAIR, FLOOR, TABLE, embodiment, look_at, room_scene


@pytest.fixture(scope="module")
def frame() -> FrameInput:
    renderer = VideoRenderer(room_scene(), embodiment(width=320, height=240), exposure=1.0)
    pose = look_at(np.array([0.3, 1.0, -1.5]), np.array([0.3, 0.7, 0.0]))
    rendered = renderer.render(pose)
    return FrameInput(rendered.rgb, rendered.depth, renderer.camera.intrinsics, rendered.panoptic, 0, pose)


def _best_iou(masks: np.ndarray, truth: np.ndarray) -> float:
    intersection = (masks & truth).reshape(len(masks), -1).sum(1)
    union = (masks | truth).reshape(len(masks), -1).sum(1)
    return float((intersection / union).max())


def test_geometric_separates_the_rooms_objects_and_partitions_the_frame(frame: FrameInput) -> None:
    masks = GeometricSegmenter().segment(frame)
    assert masks.dtype == bool and masks.shape[1:] == frame.rgb.shape[:2]
    assert np.array_equal(masks.sum(axis=0), np.ones(frame.rgb.shape[:2]))  # every pixel in exactly one region
    for object_id in (FLOOR, TABLE, CHAIR):
        truth = frame.panoptic == object_id
        assert truth.sum() > 0.01 * truth.size
        # A box's faces meet at creases and may become separate regions: the best one still covers most of it.
        assert _best_iou(masks, truth) > 0.5, object_id


def test_geometric_uses_depth_where_colour_alone_cannot_separate(frame: FrameInput) -> None:
    grey = FrameInput(np.full_like(frame.rgb, 128), frame.depth, frame.intrinsics)
    masks = GeometricSegmenter().segment(grey)
    # Same colour everywhere: only depth and normals separate the table from the floor behind it.
    assert len(masks) > 1 and _best_iou(masks, frame.panoptic == TABLE) > 0.5
    assert len(GeometricSegmenter().segment(FrameInput(grey.rgb))) == 1  # no depth, no colour: one region


def test_geometric_options_are_checked() -> None:
    with pytest.raises(ModelError, match="geometric option scale"):
        make_segmenter("geometric", scale=-1)
    with pytest.raises(ModelError, match="geometric option colour"):
        make_segmenter("geometric", colour=3)


def test_oracle_without_degradation_returns_the_ground_truth_exactly(frame: FrameInput) -> None:
    oracle = OracleSegmenter(tracked=True)
    masks, ids = oracle.segment_tracked(frame)
    expected = [i for i in np.unique(frame.panoptic) if i]
    assert ids is not None and ids.tolist() == expected
    for mask, object_id in zip(masks, ids):
        assert np.array_equal(mask, frame.panoptic == object_id)
    assert OracleSegmenter().segment_tracked(frame)[1] is None


def test_oracle_degradations_are_seeded_and_do_what_they_say(frame: FrameInput) -> None:
    objects = len([i for i in np.unique(frame.panoptic) if i])
    assert len(OracleSegmenter(miss=1.0).segment(frame)) == 0
    assert len(OracleSegmenter(split=1.0).segment(frame)) == 2 * objects
    assert len(OracleSegmenter(merge=1.0).segment(frame)) == 1
    assert OracleSegmenter(merge=1.0).segment(frame)[0].sum() == (frame.panoptic != 0).sum()
    grown = OracleSegmenter(boundary_noise=1.0, boundary_pixels=3)
    grown.reset(np.random.default_rng(1))
    changed = [not np.array_equal(m, frame.panoptic == i) for m, i in zip(grown.segment(frame), np.unique(frame.panoptic)[1:])]
    assert all(changed)
    flicker = OracleSegmenter(flicker=1.0, tracked=True)
    assert all(i > FLICKER_ID_BASE for i in flicker.segment_tracked(frame)[1])

    def draw(seed: int) -> list[bytes]:
        oracle = OracleSegmenter(miss=0.3, split=0.3, boundary_noise=0.5)
        oracle.reset(np.random.default_rng(seed))
        return [np.packbits(m).tobytes() for m in oracle.segment(frame)]

    assert draw(5) == draw(5) and draw(5) != draw(6)
