"""The segmenter contract: one RGB-D frame in, class-agnostic "everything" masks out.

Every image segmenter the project runs (the weight-free `geometric`, `oracle`, `ultralytics`, `sam`)
implements `Segmenter`; FastSPAM wraps any of them. Built-ins are looked up by name in `SEGMENTERS`
and imported lazily, so naming a model never imports torch unless that model needs it.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numpy as np
from pydantic import BaseModel, ValidationError

OptionsT = TypeVar("OptionsT", bound=BaseModel)


class ModelError(ValueError):
    """An unusable model choice (unknown name, missing extra or weights file); one line naming the fix."""


@dataclass(frozen=True)
class FrameInput:
    """What a segmenter may look at for one frame.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) uint16 millimetres, planar z, 0 = no return; None when the video has no depth.
        intrinsics: (fx, fy, cx, cy) in pixels, pixel centres at u + 0.5; None when unknown.
        panoptic: (H, W) uint32 ground-truth ids; only the `oracle` segmenter reads it.
        index: frame index t within the video (for seeded per-frame draws).
        pose: (4, 4) camera-to-world (OpenCV camera axes); None when unknown. FastSPAM needs it.
    """

    rgb: np.ndarray
    depth: np.ndarray | None = None
    intrinsics: tuple[float, float, float, float] | None = None
    panoptic: np.ndarray | None = None
    index: int = 0
    pose: np.ndarray | None = None


class Segmenter(ABC):
    """An "everything" image segmenter: every mask it finds in one frame, no classes, no ids."""

    name: ClassVar[str]
    needs_ground_truth: ClassVar[bool] = False

    @abstractmethod
    def segment(self, frame: FrameInput) -> np.ndarray:
        """Masks of one frame as an (N, H, W) bool array (N may be 0); order carries no meaning."""

    def describe(self) -> dict[str, Any]:
        """Name and options, recorded with the predictions (JSON-able)."""
        return {"name": self.name}

    @property
    def tracked(self) -> bool:
        """Whether `segment_tracked` gives ids (a tracker); per-frame segmenters give None."""
        return False

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new video: forget any memory; `rng` (seeded per video) is the only source of randomness."""

    def segment_tracked(self, frame: FrameInput) -> tuple[np.ndarray, np.ndarray | None]:
        """(masks, ids): the masks of `segment` and, for trackers, one positive id per mask (else None)."""
        return self.segment(frame), None


def parse_options(model: type[OptionsT], segmenter: str, options: dict[str, Any]) -> OptionsT:
    """A segmenter's typed options from keyword arguments; ModelError naming the option and listing the valid ones."""
    try:
        return model(**options)
    except ValidationError as error:
        first = error.errors()[0]
        raise ModelError(f"{segmenter} option {'.'.join(str(p) for p in first['loc'])}: {first['msg']}; "
                         f"options are {', '.join(model.model_fields)}") from None


# name -> "module:Class"; each class takes its options as keyword arguments.
SEGMENTERS: dict[str, str] = {
    "geometric": "pipeline.models.geometric:GeometricSegmenter",
    "oracle": "pipeline.models.oracle:OracleSegmenter",
    "ultralytics": "pipeline.models.ultralytics_segmenter:UltralyticsSegmenter",
    "sam": "pipeline.models.sam_segmenter:SamSegmenter",
}


def make_segmenter(name: str, **options: Any) -> Segmenter:
    """The segmenter called `name`, built with `options`; ModelError when the name is unknown."""
    if name not in SEGMENTERS:
        raise ModelError(f"unknown model {name!r}; models are {', '.join(SEGMENTERS)}")
    module, _, attribute = SEGMENTERS[name].partition(":")
    try:
        implementation = importlib.import_module(module)
    except ModuleNotFoundError as error:
        raise ModelError(f"model {name!r} needs the Python package {error.name!r}, which is not installed; "
                         f"install the model's extra (see README, Models)") from None
    return getattr(implementation, attribute)(**options)
