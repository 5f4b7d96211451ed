"""`oracle`: the ground truth, optionally degraded in controlled, seeded ways (for studying VSQ, and tests).

Each frame's non-void panoptic ids become masks (ascending id). Degradations, applied in this order,
each with its own probability (all 0 by default, so the oracle returns the ground truth exactly):

- miss: an object is left out of the frame;
- merge: an object is merged into the next object of the frame (ascending id order);
- split: an object is cut in two along a random line through its centroid;
- boundary noise: every mask is dilated or eroded by `boundary_pixels` (a fair coin per mask);
- id flicker (tracked output only): an object gets a fresh id for this frame.

With `tracked: true` the oracle also emits ids (the object ids, or fresh ones where they flickered)
so predict writes tracked predictions. Draws come from the generator `reset` is given (the unit's,
seeded with the job seed, stage and video), frame by frame, so the same seed gives the same masks.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.models.segmenter import FrameInput, ModelError, Segmenter, parse_options

# Flickered ids start here: far above any object id of a generated scene or an HM3DSem colour.
FLICKER_ID_BASE = 1 << 25


class OracleOptions(BaseModel):
    """Options of the `oracle` segmenter (probabilities per object and frame)."""

    model_config = ConfigDict(extra="forbid")

    miss: float = Field(0.0, ge=0, le=1, description="probability an object is left out")
    merge: float = Field(0.0, ge=0, le=1, description="probability an object is merged into the next one")
    split: float = Field(0.0, ge=0, le=1, description="probability an object is cut in two")
    boundary_noise: float = Field(0.0, ge=0, le=1, description="probability a mask's boundary moves")
    boundary_pixels: int = Field(2, ge=1, le=50, description="how far a noisy boundary moves, pixels")
    flicker: float = Field(0.0, ge=0, le=1, description="tracked only: probability an object gets a fresh id")
    tracked: bool = Field(False, description="emit ids (tracked predictions) instead of per-frame masks")


class OracleSegmenter(Segmenter):
    """Ground-truth masks with seeded misses, merges, splits, boundary noise and id flicker."""

    name = "oracle"
    needs_ground_truth = True

    def __init__(self, **options: Any):
        self.options = parse_options(OracleOptions, "oracle", options)
        self._rng = np.random.default_rng(0)
        self._next_flicker = FLICKER_ID_BASE

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "options": self.options.model_dump()}

    @property
    def tracked(self) -> bool:
        return self.options.tracked

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._next_flicker = FLICKER_ID_BASE

    def segment(self, frame: FrameInput) -> np.ndarray:
        return self.segment_tracked(frame)[0]

    def segment_tracked(self, frame: FrameInput) -> tuple[np.ndarray, np.ndarray | None]:
        if frame.panoptic is None:
            raise ModelError("the oracle segmenter needs the ground-truth panoptic frame; predict from a rendered run")
        label = np.asarray(frame.panoptic)
        ids = np.unique(label)
        ids = ids[ids != 0].astype(np.int64)
        masks = [label == i for i in ids]
        out_ids = list(ids.tolist())
        options, rng = self.options, self._rng
        keep = rng.random(len(masks)) >= options.miss
        masks, out_ids = [m for m, k in zip(masks, keep) if k], [i for i, k in zip(out_ids, keep) if k]
        merged = rng.random(len(masks)) < options.merge
        for index in range(len(masks) - 1):
            if merged[index]:
                masks[index + 1] = masks[index + 1] | masks[index]
                masks[index] = np.zeros_like(masks[index])
        pieces: list[np.ndarray] = []
        piece_ids: list[int] = []
        for mask, object_id in zip(masks, out_ids):
            if not mask.any():
                continue
            if rng.random() < options.split:
                first, second = _split(mask, rng.uniform(0.0, np.pi))
                pieces += [first, second]
                piece_ids += [object_id, self._fresh_id()]
            else:
                pieces.append(mask)
                piece_ids.append(object_id)
        if options.boundary_noise > 0:
            pieces = [_move_boundary(m, options.boundary_pixels, rng.random() < 0.5) if rng.random() < options.boundary_noise
                      else m for m in pieces]
        if options.tracked and options.flicker > 0:
            piece_ids = [self._fresh_id() if rng.random() < options.flicker else i for i in piece_ids]
        kept = [k for k, m in enumerate(pieces) if m.any()]
        stack = np.stack([pieces[k] for k in kept]) if kept else np.zeros((0, *label.shape), bool)
        return stack, (np.asarray([piece_ids[k] for k in kept], np.int64) if options.tracked else None)

    def _fresh_id(self) -> int:
        self._next_flicker += 1
        return self._next_flicker


def _split(mask: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """The mask cut by the line through its centroid at `angle` (radians): two masks."""
    rows, columns = np.nonzero(mask)
    row0, column0 = rows.mean(), columns.mean()
    side = (columns - column0) * np.sin(angle) - (rows - row0) * np.cos(angle) >= 0
    first = np.zeros_like(mask)
    first[rows[side], columns[side]] = True
    return first, mask & ~first


def _move_boundary(mask: np.ndarray, pixels: int, grow: bool) -> np.ndarray:
    """The mask dilated (grow) or eroded by `pixels` with a square kernel."""
    kernel = np.ones((2 * pixels + 1, 2 * pixels + 1), np.uint8)
    operation = cv2.dilate if grow else cv2.erode
    return operation(mask.astype(np.uint8), kernel).astype(bool)
