"""`ultralytics`: FastSAM or any YOLO-seg checkpoint from a local file, in "everything" mode.

The paper's segmenter is FastSAM-x (a YOLOv8x-seg network trained on SA-1B) run with imgsz 1024,
conf 0.4, iou 0.9 and retina masks (masks at the frame's full resolution): these are the defaults.
Install with `pip install 'mvpd-pipeline[ultralytics]'` (the `ultralytics-opencv-headless` build, so it
shares our opencv-python-headless; ultralytics is AGPL-3.0). Weights come only from `checkpoint`:
ultralytics is put in offline mode (no hub or telemetry calls, no package auto-install) before it is
imported, and nothing here draws labels, which is what would fetch its font.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.models.checkpoints import CHECKPOINT_LOAD_ERRORS, import_extra, one_line, require_checkpoint
from pipeline.models.segmenter import FrameInput, ModelError, Segmenter

# Read by ultralytics when it is first imported: no network checks, no pip installs, no banner per call.
OFFLINE_ENVIRONMENT = {"YOLO_OFFLINE": "true", "YOLO_AUTOINSTALL": "false", "YOLO_VERBOSE": "false"}
Architecture = Literal["auto", "fastsam", "yolo"]


def _import_ultralytics() -> Any:
    for key, value in OFFLINE_ENVIRONMENT.items():
        os.environ.setdefault(key, value)
    return import_extra("ultralytics", "ultralytics", "ultralytics")


class UltralyticsSegmenter(Segmenter):
    """Every mask an ultralytics segmentation model finds in a frame (class labels ignored).

    Args:
        checkpoint: local `.pt` file (FastSAM-x.pt, FastSAM-s.pt, yolov8x-seg.pt, a fine-tuned model, ...).
        architecture: "fastsam" (FastSAM's predictor), "yolo" (plain YOLO-seg), or "auto": FastSAM when the
            file name contains "fastsam".
        imgsz, conf, iou: inference size, confidence and NMS IoU thresholds (the paper's FastSAM-x values).
        retina_masks: masks computed at the frame's resolution (else upsampled from the network's).
        max_det: most masks per frame.
        device: torch device ("cpu", "cuda:0").
    """

    name = "ultralytics"

    def __init__(self, checkpoint: str | Path | None = None, architecture: Architecture = "auto", imgsz: int = 1024,
                 conf: float = 0.4, iou: float = 0.9, retina_masks: bool = True, max_det: int = 300,
                 device: str = "cpu"):
        if architecture not in ("auto", "fastsam", "yolo"):
            raise ModelError(f"architecture={architecture!r}: choose auto, fastsam or yolo")
        self.checkpoint = require_checkpoint(checkpoint, self.name, "FastSAM-x.pt")
        ultralytics = _import_ultralytics()
        self.architecture = architecture if architecture != "auto" else (
            "fastsam" if "fastsam" in self.checkpoint.name.lower() else "yolo")
        self.options = {"imgsz": imgsz, "conf": conf, "iou": iou, "retina_masks": retina_masks, "max_det": max_det,
                        "device": device, "verbose": False}
        try:
            if self.architecture == "fastsam":
                self.model = ultralytics.FastSAM(str(self.checkpoint))
            else:
                self.model = ultralytics.YOLO(str(self.checkpoint), task="segment")
        except CHECKPOINT_LOAD_ERRORS as error:
            raise ModelError(f"{self.checkpoint}: not a loadable ultralytics segmentation checkpoint "
                             f"({one_line(error)})") from None

    def segment(self, frame: FrameInput) -> np.ndarray:
        """(N, H, W) bool masks of the frame (ultralytics reads numpy images as BGR, so the channels flip)."""
        height, width = frame.rgb.shape[:2]
        bgr = np.ascontiguousarray(frame.rgb[..., ::-1])
        result = self.model.predict(bgr, **self.options)[0]
        if result.masks is None:
            return np.zeros((0, height, width), dtype=bool)
        masks = result.masks.data
        if tuple(masks.shape[1:]) != (height, width):  # not retina: masks at the letterboxed network size
            from ultralytics.utils.ops import scale_masks

            masks = scale_masks(masks[None].float(), (height, width))[0]
        return masks.cpu().numpy() > 0.5

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "checkpoint": str(self.checkpoint), "architecture": self.architecture,
                **{k: v for k, v in self.options.items() if k != "verbose"}}
