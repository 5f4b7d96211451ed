"""`sam`: Segment Anything's automatic mask generator from a local checkpoint.

Install with `pip install 'mvpd-pipeline[sam]'` (Meta's `segment-anything`, Apache-2.0; it needs torch
and torchvision). The checkpoint (sam_vit_h_4b8939.pth, sam_vit_l_0b3195.pth or sam_vit_b_01ec64.pth)
is a file the user downloads once and names; nothing is fetched at run time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pipeline.models.checkpoints import CHECKPOINT_LOAD_ERRORS, import_extra, one_line, require_checkpoint
from pipeline.models.segmenter import FrameInput, ModelError, Segmenter

MODEL_TYPES = ("vit_h", "vit_l", "vit_b")


def model_type_of(checkpoint: Path) -> str:
    """The SAM backbone a checkpoint's official file name announces (sam_vit_b_01ec64.pth -> vit_b); vit_h else."""
    return next((kind for kind in MODEL_TYPES if kind in checkpoint.name.lower()), "vit_h")


class SamSegmenter(Segmenter):
    """Every mask of SAM's automatic ("everything") mode: a grid of point prompts, filtered and de-duplicated.

    Args:
        checkpoint: local SAM checkpoint file.
        model_type: vit_h, vit_l or vit_b; "auto" reads it from the file name.
        points_per_side: the prompt grid (32 x 32 in SAM's default).
        pred_iou_thresh, stability_score_thresh: SAM's mask quality filters (its defaults).
        min_mask_region_area: holes and islands smaller than this many pixels are removed (0: off).
        device: torch device.
    """

    name = "sam"

    def __init__(self, checkpoint: str | Path | None = None, model_type: str = "auto", points_per_side: int = 32,
                 pred_iou_thresh: float = 0.88, stability_score_thresh: float = 0.95,
                 min_mask_region_area: int = 0, device: str = "cpu"):
        self.checkpoint = require_checkpoint(checkpoint, self.name, "sam_vit_h_4b8939.pth")
        self.model_type = model_type_of(self.checkpoint) if model_type == "auto" else model_type
        if self.model_type not in MODEL_TYPES:
            raise ModelError(f"model_type={model_type!r}: choose auto, {', '.join(MODEL_TYPES)}")
        segment_anything = import_extra("segment_anything", "sam", self.name)
        try:
            network = segment_anything.sam_model_registry[self.model_type](checkpoint=str(self.checkpoint))
        except CHECKPOINT_LOAD_ERRORS as error:
            raise ModelError(f"{self.checkpoint}: not a {self.model_type} SAM checkpoint ({one_line(error)}); "
                             "pass model_type= to match the file") from None
        self.options = {"points_per_side": points_per_side, "pred_iou_thresh": pred_iou_thresh,
                        "stability_score_thresh": stability_score_thresh, "min_mask_region_area": min_mask_region_area}
        self.generator = segment_anything.SamAutomaticMaskGenerator(network.to(device), **self.options)

    def segment(self, frame: FrameInput) -> np.ndarray:
        """(N, H, W) bool masks of the frame, in SAM's output order."""
        height, width = frame.rgb.shape[:2]
        found = self.generator.generate(np.ascontiguousarray(frame.rgb))
        if not found:
            return np.zeros((0, height, width), dtype=bool)
        return np.stack([np.asarray(item["segmentation"], dtype=bool) for item in found])

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "checkpoint": str(self.checkpoint), "model_type": self.model_type, **self.options}
