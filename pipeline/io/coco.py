"""COCO instance segmentation export (`mvpd export RUN --coco OUT`).

Layout (one annotation file per split, the images beside them):

    OUT/annotations/instances_<split>.json
    OUT/images/<split>/<embodiment>.<video_name>.<frame:010d>.jpg

Each annotation is one object of one frame: `segmentation` is a compressed COCO RLE of its full-resolution
mask (pycocotools), `area` its pixel count, `bbox` [x, y, w, h], `iscrowd` 0. Beyond the COCO fields an
image carries `video_name`, `embodiment` and `frame`, and an annotation `object_id` (the run's id, stable
over a video: enough to rebuild tracks) and `isthing` (0 for wall, floor, ceiling). Categories are one
`object` class (class-agnostic, id 1) or the mpcat40 categories (ids 1..41, 41 = `unlabeled`, with `isthing`).

Images and annotations are streamed to temporary files while the frames are read, so memory stays flat
on runs of millions of frames; the JSON file appears under its final name only once complete.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import IO, Any

import numpy as np
from pycocotools import mask as mask_utils

from pipeline.io.training_export import ExportFrame, ExportObject, ExportOptions, TrainingExporter, category_names
from pipeline.scenes.categories import STUFF_CATEGORIES

ANNOTATIONS = "annotations"
AGNOSTIC_CATEGORY = {"id": 1, "name": "object", "supercategory": "object", "isthing": 1}


def annotation_file(out: Path, split: str) -> Path:
    """Where the COCO file of one split lives."""
    return out / ANNOTATIONS / f"instances_{split}.json"


def coco_categories(mode: str) -> list[dict[str, Any]]:
    """The `categories` list: one class-agnostic `object`, or mpcat40 1..41 (wall, floor, ceiling not things)."""
    if mode == "agnostic":
        return [dict(AGNOSTIC_CATEGORY)]
    return [{"id": index, "name": name, "supercategory": "stuff" if index in STUFF_CATEGORIES else "thing",
             "isthing": 0 if index in STUFF_CATEGORIES else 1} for index, name in category_names().items()]


def encode_mask(mask: np.ndarray) -> dict[str, Any]:
    """A boolean (H, W) mask as a JSON-able compressed COCO RLE {"size": [H, W], "counts": str}."""
    rle = mask_utils.encode(np.asfortranarray(mask, dtype=np.uint8))
    return {"size": [int(v) for v in rle["size"]], "counts": rle["counts"].decode("ascii")}


def _bbox(mask: np.ndarray) -> list[float]:
    """[x, y, width, height] of the mask's pixels (COCO's box convention, exclusive at the far side)."""
    rows, columns = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return [float(columns[0]), float(rows[0]), float(columns[-1] - columns[0] + 1), float(rows[-1] - rows[0] + 1)]


class _JsonArrayWriter:
    """Appends JSON objects to a temporary file as the items of one array (written without brackets)."""

    def __init__(self, path: Path):
        self.path = path
        self.file: IO[str] = path.open("w", encoding="utf-8")
        self.count = 0

    def append(self, item: dict[str, Any]) -> None:
        self.file.write((", " if self.count else "") + json.dumps(item, separators=(", ", ": ")))
        self.count += 1

    def close(self) -> None:
        self.file.close()


class CocoExporter(TrainingExporter):
    """Writes `annotations/instances_<split>.json` for each split (images are written by the driver)."""

    layout = (ANNOTATIONS, "images")

    def __init__(self, out: Path, options: ExportOptions):
        super().__init__(out, options)
        (out / ANNOTATIONS).mkdir(parents=True, exist_ok=True)
        self.categories = coco_categories(options.categories)
        self.parts: dict[str, _JsonArrayWriter] = {}

    def begin_split(self, split: str) -> None:
        target = annotation_file(self.out, split)
        self.parts = {kind: _JsonArrayWriter(target.with_name(f".{target.name}.{kind}-{os.getpid()}"))
                      for kind in ("images", "annotations")}

    def add_frame(self, frame: ExportFrame, image: Path) -> None:
        images, annotations = self.parts["images"], self.parts["annotations"]
        image_id = images.count + 1
        height, width = frame.size
        images.append({"id": image_id, "file_name": image.name, "height": height, "width": width,
                       "video_name": frame.video_name, "embodiment": frame.embodiment, "frame": frame.frame})
        for item in frame.objects:
            annotations.append(self._annotation(annotations.count + 1, image_id, item))

    def _annotation(self, annotation_id: int, image_id: int, item: ExportObject) -> dict[str, Any]:
        return {"id": annotation_id, "image_id": image_id,
                "category_id": 1 if self.options.categories == "agnostic" else item.category,
                "segmentation": encode_mask(item.mask), "area": int(item.mask.sum()), "bbox": _bbox(item.mask),
                "iscrowd": 0, "object_id": item.object_id, "isthing": 0 if item.is_stuff else 1}

    def end_split(self, split: str) -> None:
        """Join the streamed parts into the split's JSON file, then rename it into place."""
        for part in self.parts.values():
            part.close()
        target = annotation_file(self.out, split)
        temporary = target.with_name(f".{target.name}.tmp-{os.getpid()}")
        head = {"info": {"description": f"mvpd-pipeline export, split {split}", "frame_step": self.options.every,
                         "categories": self.options.categories, "stuff": not self.options.drop_stuff},
                "categories": self.categories}
        with temporary.open("w", encoding="utf-8") as file:
            file.write(json.dumps(head, separators=(", ", ": "))[:-1])  # leave the object open
            for kind, part in self.parts.items():
                file.write(f', "{kind}": [')
                with part.path.open(encoding="utf-8") as source:
                    shutil.copyfileobj(source, file)
                file.write("]")
            file.write("}")
        os.replace(temporary, target)
        self._remove_parts()

    def abort(self) -> None:
        for part in self.parts.values():
            part.close()
        self._remove_parts()

    def _remove_parts(self) -> None:
        for part in self.parts.values():
            part.path.unlink(missing_ok=True)
        self.parts = {}
