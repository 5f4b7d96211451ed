"""Ultralytics YOLO segmentation export (`mvpd export RUN --yolo OUT`).

Layout (what `yolo segment train data=OUT/data.yaml` reads):

    OUT/data.yaml                       path, train / val / test image folders, names
    OUT/images/<split>/<stem>.jpg       stem = <embodiment>.<video_name>.<frame:010d>
    OUT/labels/<split>/<stem>.txt       one line per object: `class x1 y1 x2 y2 ...`, normalised to 0..1

Classes are `0: object` (class-agnostic) or the mpcat40 categories 1..41 as 0..40 (category index - 1).

Polygons come from `cv2.findContours` over the object's mask, outer boundaries and holes alike. An object
in several pieces (seen through a chair's legs, say) or with holes (a wall behind a picture) is still ONE
instance: its rings are joined into one polygon by zero-width bridges between their nearest vertices, as
ultralytics' own COCO converter joins multi-part objects. Filled back with `cv2.fillPoly` (how
ultralytics rasterises a label), the joined polygon reproduces the mask up to the one-pixel bridge lines;
one line per piece would instead teach the model that each piece is a separate object. Vertices are pixel
indices divided by the width and height, so denormalising gives back the exact pixel.

Without a split (`all`), train and val both name the one image folder, so the file trains as it is;
give the run a split stage for a real validation set.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import yaml

from pipeline.io.training_export import (
    NO_SPLIT,
    ExportFrame,
    ExportOptions,
    TrainingExporter,
    category_names,
    write_text,
)

LABELS = "labels"
DATA_FILE = "data.yaml"


def mask_polygon(mask: np.ndarray) -> np.ndarray | None:
    """One (K, 2) int polygon (x, y pixel indices) tracing every piece and hole of a mask; None if < 3 vertices."""
    contours, _ = cv2.findContours(np.ascontiguousarray(mask, dtype=np.uint8), cv2.RETR_CCOMP,
                                   cv2.CHAIN_APPROX_SIMPLE)
    rings = [c.reshape(-1, 2) for c in contours]
    if not rings:
        return None
    polygon = rings[0]
    for ring in rings[1:]:
        polygon = _bridge(polygon, ring)
    return polygon if len(polygon) >= 3 else None


def _bridge(polygon: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Splice `ring` into `polygon` at their nearest vertices: out along a bridge, around the ring, back."""
    distances = ((polygon[:, None, :] - ring[None, :, :]) ** 2).sum(axis=-1)
    at, start = np.unravel_index(int(np.argmin(distances)), distances.shape)
    around = np.concatenate([ring[start:], ring[:start + 1]])  # closes the ring at its start vertex
    return np.concatenate([polygon[:at + 1], around, polygon[at:]])


def polygon_line(class_index: int, polygon: np.ndarray, width: int, height: int) -> str:
    """One label line: the class, then x / width and y / height of each vertex (6 decimals)."""
    coordinates = (polygon / np.array([width, height], dtype=np.float64)).ravel()
    return " ".join([str(class_index), *(f"{value:.6f}" for value in coordinates)])


def yolo_names(mode: str) -> dict[int, str]:
    """Class index -> name: `object`, or mpcat40 category index - 1 -> its name."""
    if mode == "agnostic":
        return {0: "object"}
    return {index - 1: name for index, name in category_names().items()}


class YoloExporter(TrainingExporter):
    """Writes one polygon label file per image and `data.yaml` (images are written by the driver)."""

    layout = ("images", LABELS, DATA_FILE)

    def __init__(self, out: Path, options: ExportOptions):
        super().__init__(out, options)
        self.skipped = 0  # objects too small to trace as a polygon (fewer than 3 vertices)

    def begin_split(self, split: str) -> None:
        (self.out / LABELS / split).mkdir(parents=True, exist_ok=True)

    def add_frame(self, frame: ExportFrame, image: Path) -> None:
        height, width = frame.size
        lines = []
        for item in frame.objects:
            polygon = mask_polygon(item.mask)
            if polygon is None:
                self.skipped += 1
                continue
            class_index = 0 if self.options.categories == "agnostic" else item.category - 1
            lines.append(polygon_line(class_index, polygon, width, height))
        # An image without objects still gets its (empty) label file: a background image, not a missing label.
        write_text(self.out / LABELS / frame.split / f"{frame.stem}.txt", "".join(f"{line}\n" for line in lines))

    def finish(self, splits: Sequence[str]) -> None:
        data: dict[str, object] = {"path": str(self.out)}
        if list(splits) == [NO_SPLIT]:
            data.update(train=f"images/{NO_SPLIT}", val=f"images/{NO_SPLIT}")
            note = "# The run has no split: train and val are the same images.\n"
        else:
            data.update({split: f"images/{split}" for split in ("train", "val", "test") if split in splits})
            note = ""
        data["names"] = yolo_names(self.options.categories)
        header = (f"# mvpd-pipeline YOLO segmentation export; every {self.options.every}. frame; "
                  f"stuff {'dropped' if self.options.drop_stuff else 'kept'}.\n")
        write_text(self.out / DATA_FILE, header + note + yaml.safe_dump(data, sort_keys=False))
