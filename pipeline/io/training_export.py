"""What the COCO and YOLO training exports share: input checks, the output folder, frame iteration, objects.

`mvpd export RUN --coco OUT` and `--yolo OUT` walk the same frames in the same order: the run's videos
grouped by split (a mapping split -> (embodiment, video_name) list, from the split stage when the run
has one), every n-th frame of each video. Per frame an exporter gets the RGB image (written here as
`images/<split>/<embodiment>.<video_name>.<frame:010d>.jpg`) and the frame's objects:

- void (panoptic id 0) and objects whose mpcat40 category is 0 (unmapped raw names) are never
  annotated, as in the MVPd release;
- stuff (wall, floor, ceiling) is kept and flagged (`isthing` 0), or left out with `drop_stuff`;
- every object is one instance, whole (never `iscrowd`), in one piece or several.

Bad input (an unknown embodiment or video, an output that is a file or already holds files) raises
`TrainingExportError` before anything is written. Every file is written to a temporary name and
renamed, so an interrupted export never leaves a half-written file under its final name.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image

from pipeline.io.mvpd.layout import JPEG_QUALITY
from pipeline.io.reader import LoadedVideo, list_videos, load_video
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.categories import STUFF_CATEGORIES, VOID, categories

log = logging.getLogger(__name__)

NO_SPLIT = "all"  # the one split of a run that has no split stage output
IMAGES = "images"
CategoryMode = Literal["agnostic", "mpcat40"]
VideoKey = tuple[str, str]  # (embodiment, video_name)


class TrainingExportError(ValueError):
    """A training export that cannot run as asked; the message names the input and the fix."""


@dataclass(frozen=True)
class ExportOptions:
    """How a training export samples frames and labels objects.

    Attributes:
        every: keep frames 0, every, 2 * every, ... of each video (a full run has millions of frames).
        categories: "agnostic" (one class, `object`: what MVPd's class-agnostic task trains) or "mpcat40"
            (the Matterport table: 1..40 and 41 `unlabeled`, as the MVPd release lists them; ids 1..41 in COCO,
            classes 0..40 in YOLO).
        drop_stuff: leave wall, floor and ceiling out (kept and flagged by default).
        embodiment: export only this embodiment's videos (default: all of them).
        overwrite: replace an earlier export in a non-empty output folder.
    """

    every: int = 1
    categories: CategoryMode = "agnostic"
    drop_stuff: bool = False
    embodiment: str | None = None
    overwrite: bool = False


@dataclass(frozen=True)
class ExportObject:
    """One labelled object of one frame: its run id, mpcat40 category and full-resolution mask."""

    object_id: int
    category: int
    mask: np.ndarray  # (H, W) bool

    @property
    def is_stuff(self) -> bool:
        """Wall, floor or ceiling."""
        return self.category in STUFF_CATEGORIES


@dataclass(frozen=True)
class ExportFrame:
    """One sampled frame as the exporters see it."""

    split: str
    embodiment: str
    video_name: str
    frame: int
    rgb: np.ndarray  # (H, W, 3) uint8
    objects: list[ExportObject]

    @property
    def stem(self) -> str:
        """File name without suffix, unique over the export (two embodiments may share a video name)."""
        return f"{self.embodiment}.{self.video_name}.{self.frame:010d}"

    @property
    def size(self) -> tuple[int, int]:
        """(height, width) in pixels."""
        return int(self.rgb.shape[0]), int(self.rgb.shape[1])


@dataclass
class ExportSummary:
    """What an export wrote, for the CLI's one-line summary."""

    out: Path
    frames: dict[str, int] = field(default_factory=dict)  # split -> frames written
    objects: int = 0
    seconds: float = 0.0


def category_names() -> dict[int, str]:
    """mpcat40 index -> name, 1..41 (void excluded; 41 is `unlabeled`)."""
    return {index: c.name for index, c in sorted(categories().items()) if index != VOID}


class TrainingExporter(ABC):
    """One output format: told about each split and frame in order; writes its own label files.

    `layout` names the top-level entries the format owns inside OUT: `--overwrite` removes exactly these.
    """

    layout: tuple[str, ...] = ()

    def __init__(self, out: Path, options: ExportOptions):
        self.out = out
        self.options = options

    def begin_split(self, split: str) -> None:
        """Called before the first frame of a split (also for a split with no frames)."""

    @abstractmethod
    def add_frame(self, frame: ExportFrame, image: Path) -> None:
        """Record one frame whose image is already written at `image`."""

    def end_split(self, split: str) -> None:
        """Called after the last frame of a split."""

    def finish(self, splits: Sequence[str]) -> None:
        """Called once after every split (dataset-level files)."""

    def abort(self) -> None:
        """Called when the export fails part-way: remove temporary files."""


def export_training_data(run: RunFolder, out: Path, splits: Mapping[str, Sequence[VideoKey]],
                         exporter_class: type[TrainingExporter], options: ExportOptions,
                         on_start: Callable[[int], None] | None = None,
                         on_video: Callable[[str], None] | None = None) -> ExportSummary:
    """Write the frames of `splits` with `exporter_class` into `out`.

    Args:
        run: the run folder.
        out: the output folder (created; must be absent or empty unless `options.overwrite`).
        splits: split name -> (embodiment, video_name) of the videos in it, in export order.
        exporter_class: `CocoExporter` or `YoloExporter`.
        options: frame sampling, categories, stuff, embodiment, overwrite.
        on_start, on_video: progress callbacks (number of videos; each finished video's name).
    """
    started = time.monotonic()
    chosen = _checked_splits(run, splits, options)
    out = _prepare_output(Path(out), exporter_class.layout, options.overwrite)
    exporter = exporter_class(out, options)
    summary = ExportSummary(out)
    if on_start is not None:
        on_start(sum(len(videos) for videos in chosen.values()))
    try:
        for split, videos in chosen.items():
            exporter.begin_split(split)
            images = out / IMAGES / split
            images.mkdir(parents=True, exist_ok=True)
            summary.frames[split] = 0
            for embodiment, name in videos:
                for frame in _sampled_frames(load_video(run, name, embodiment), split, options):
                    image = images / f"{frame.stem}.jpg"
                    write_jpeg(image, frame.rgb)
                    exporter.add_frame(frame, image)
                    summary.frames[split] += 1
                    summary.objects += len(frame.objects)
                if on_video is not None:
                    on_video(name)
            exporter.end_split(split)
        exporter.finish(list(chosen))
    except BaseException:
        exporter.abort()
        raise
    summary.seconds = time.monotonic() - started
    log.info("exported %s frames, %s objects to %s", sum(summary.frames.values()), summary.objects, out)
    return summary


def _checked_splits(run: RunFolder, splits: Mapping[str, Sequence[VideoKey]],
                    options: ExportOptions) -> dict[str, list[VideoKey]]:
    """The videos to export per split, restricted to the chosen embodiment; every name checked."""
    if options.every < 1:
        raise TrainingExportError(f"--every {options.every}: the frame step must be at least 1")
    if options.categories not in ("agnostic", "mpcat40"):
        raise TrainingExportError(f"--categories {options.categories}: choose agnostic or mpcat40")
    stored = set(list_videos(run))
    if options.embodiment is not None and options.embodiment not in {e for e, _ in stored}:
        known = sorted({e for e, _ in stored})
        raise TrainingExportError(f"{run.root}: no videos of embodiment {options.embodiment!r}; "
                                  f"choose one of {', '.join(known) or '(none rendered)'}")
    chosen: dict[str, list[VideoKey]] = {}
    for split, videos in splits.items():
        for key in videos:
            if tuple(key) not in stored:
                raise TrainingExportError(f"{run.root}: split {split!r} lists video {key[1]!r} of embodiment "
                                          f"{key[0]!r}, which the run's videos table does not hold; "
                                          "rerun the split stage")
        chosen[split] = [tuple(k) for k in videos if options.embodiment in (None, k[0])]  # type: ignore[misc]
    if not any(chosen.values()):
        raise TrainingExportError(f"{run.root}: no videos to export; run the render stage first")
    return chosen


def _prepare_output(out: Path, layout: tuple[str, ...], overwrite: bool) -> Path:
    """Create `out`; refuse a file, or a non-empty folder unless `overwrite` (then remove the format's own entries)."""
    out = out.expanduser().resolve()
    if out.exists() and not out.is_dir():
        raise TrainingExportError(f"{out}: is a file; give a folder for the export")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise TrainingExportError(f"{out}: exists and is not empty; choose a new folder or pass --overwrite")
        for entry in layout:  # only what an export of this format writes: never the user's other files
            path = out / entry
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _sampled_frames(video: LoadedVideo, split: str, options: ExportOptions) -> Iterator[ExportFrame]:
    """Every `options.every`-th frame of one video with its labelled objects."""
    for index in range(0, video.frames, options.every):
        panoptic = np.asarray(video.panoptic[index])
        yield ExportFrame(split, video.embodiment, video.name, index, np.asarray(video.rgb[index]),
                          frame_objects(panoptic, video, options.drop_stuff))


def frame_objects(panoptic: np.ndarray, video: LoadedVideo, drop_stuff: bool) -> list[ExportObject]:
    """The labelled objects of one frame in id order: void and unmapped objects left out, stuff optionally."""
    objects = []
    for object_id in (int(i) for i in np.unique(panoptic)):
        if object_id == 0:
            continue
        if object_id not in video.categories:
            raise TrainingExportError(f"{video.path}: object {object_id} has no category in the video's "
                                      "object_categories or the run's objects table; rerun the shard stage")
        category = video.categories[object_id]
        if category == VOID or (drop_stuff and category in STUFF_CATEGORIES):
            continue
        objects.append(ExportObject(object_id, category, panoptic == object_id))
    return objects


# ------------------------------------------------------------------------------------- atomic files


def _temporary(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def write_jpeg(path: Path, rgb: np.ndarray) -> None:
    """An RGB frame as JPEG (MVPd's quality, no chroma subsampling), by temporary file and rename."""
    temporary = _temporary(path)
    Image.fromarray(rgb).save(temporary, format="JPEG", quality=JPEG_QUALITY, subsampling=0)
    os.replace(temporary, path)


def write_text(path: Path, text: str) -> None:
    """A text file by temporary file and rename."""
    temporary = _temporary(path)
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)


def run_splits(accepted: Callable[[str], Sequence[VideoKey] | None] | None,
               names: Sequence[str] = ("train", "val", "test")) -> dict[str, list[VideoKey]] | None:
    """split -> videos from the split stage's `accepted(split)`; None when the run has no split."""
    if accepted is None:
        return None
    found = {name: accepted(name) for name in names}
    if all(videos is None for videos in found.values()):
        return None
    return {name: list(videos) for name, videos in found.items() if videos is not None}


def unsplit(run: RunFolder) -> dict[str, list[VideoKey]]:
    """Every video of the run as one split named `all` (a run without a split stage)."""
    return {NO_SPLIT: list_videos(run)}
