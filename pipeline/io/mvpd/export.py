"""Export a run's videos as one split of an MVPd release (`mvpd export RUN --mvpd OUT`).

The split is built in a hidden folder beside its final place and renamed into place at the end, so
`<OUT>/<split>` is either absent, the previous export, or a complete new export: never half-written.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from PIL import Image

from pipeline.io.mvpd.layout import (
    EMPTY_VIDEOS,
    EMPTY_VOID_FRACTION,
    IMAGES_DEPTH,
    IMAGES_RGB,
    JPEG_QUALITY,
    MAX_MVPD_ID,
    MVPD_FX,
    PANOMASKS,
    ZERO_SHOT,
    SplitPaths,
    frame_stem,
    ids_to_png,
    object_id_to_color,
    pose_to_mvpd,
    write_json,
)
from pipeline.io.segments import DenseLabels, frame_segments, unique_with_inverse
from pipeline.io.mvpd.panoptic_json import PanopticJsonSpool
from pipeline.io.mvpd.split_files import empty_videos_file, split_rows_of, zero_shot_file
from pipeline.io.reader import video_locations
from pipeline.io.zarr_video import Video, open_video
from pipeline.store.names import atomic_write_text, replaced
from pipeline.store.run_folder import RunFolder
from pipeline.split.selection import has_split, split_rows

log = logging.getLogger(__name__)
TRAIN_SPLIT = "train"
READ_BLOCK = 16  # frames read from Zarr at once: one shard of the default layout
# A worker process costs ~2.5 CPU seconds to start (its imports): give each at least ~25 s of frames to encode.
FRAMES_PER_WORKER = 1000


class MvpdExportError(ValueError):
    """A run that cannot be exported as asked; the message names what is missing and what to do."""


@dataclass
class VideoExport:
    """What one exported video adds to the split's JSON files."""

    name: str
    images: list[dict[str, Any]]
    annotations: list[dict[str, str]]
    instance_id_map: dict[Any, dict[str, Any]]  # segment id -> entry (str keys once finished)
    empty: bool
    instances: dict[int, dict[str, Any]] = field(default_factory=dict)  # segment id -> release `instance` entry


@dataclass
class ExportedVideo:
    """What the export keeps of a video once its entries are spooled to the split's JSON."""

    name: str
    frames: int
    empty: bool


@dataclass
class ExportSummary:
    """What an export wrote (returned to the CLI for its one-line summary)."""

    split_folder: Path
    videos: int = 0
    frames: int = 0
    rejected: list[str] = field(default_factory=list)
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)


def export_release(run: RunFolder, out_root: Path, split: str = "test", embodiment: str | None = None,
                   overwrite: bool = False, on_video: Callable[[str], None] | None = None,
                   on_start: Callable[[int], None] | None = None) -> ExportSummary:
    """Write every rendered video of one embodiment of a run as `<out_root>/<split>` in MVPd's layout.

    Args:
        run: the run folder.
        out_root: the MVPd root; the split folder is created inside it.
        split: split name; every video goes into it until a split stage exists.
        embodiment: which embodiment to export; may be omitted when the run has only one (MVPd's video
            names carry no embodiment, so two embodiments cannot share a split).
        overwrite: replace an existing `<out_root>/<split>`.
        on_start, on_video: progress callbacks (number of videos; each finished video's name).
    """
    started = time.monotonic()
    chosen = _choose_embodiment(run, embodiment)
    paths = SplitPaths(Path(out_root).expanduser().resolve(), split)
    if paths.folder.exists() and not overwrite:
        raise MvpdExportError(f"{paths.folder}: already exists; delete it or pass --overwrite")
    videos = _videos_of(run, chosen)
    split_rows = split_rows_of(run, split) if has_split(run) else None
    if split_rows is not None:  # the split stage decides which videos are in the split and their flags
        videos = {name: video for name, video in videos.items() if name in split_rows}
        if not videos:
            raise MvpdExportError(f"{run.location}/splits: no video of embodiment {chosen!r} in split {split!r}")
    objects = _release_objects(run)
    lit = _lit_companions(run, chosen)
    warnings = _camera_warnings(run, chosen)
    if on_start is not None:
        on_start(len(videos))
    staging = paths.root / f".{split}.partial-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        tasks = _video_tasks(run, videos, chosen, lit, objects, staging)
        exported = _spool_videos(tasks, staging / f"panoptic_{split}.json", on_video)
        _write_filter_files(staging, split, exported)
        if split_rows is not None:
            rows = [split_rows[v.name] for v in exported]
            write_json(staging / EMPTY_VIDEOS, empty_videos_file(rows))
            write_json(staging / ZERO_SHOT, zero_shot_file(run, split, rows))
            atomic_write_text(paths.root / f"{split}.txt", "".join(f"{s}\n" for s in sorted({r["scene_id"] for r in rows})))
        swap_into_place(staging, paths.folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    rejected = ([v.name for v in exported if v.empty] if split_rows is None
                else [v.name for v in exported if not split_rows[v.name]["accepted"]])
    return ExportSummary(paths.folder, len(exported), sum(v.frames for v in exported), rejected,
                         time.monotonic() - started, warnings)


def export_release_splits(run: RunFolder, out_root: Path, embodiment: str | None = None, overwrite: bool = False,
                          on_video: Callable[[str], None] | None = None,
                          on_start: Callable[[int], None] | None = None) -> list[ExportSummary]:
    """Every split of a run with a split stage (train, val, test), each as `export_release` writes one."""
    from pipeline.config import SPLIT_NAMES

    names = sorted({r["split"] for r in split_rows(run)}, key=SPLIT_NAMES.index)
    if not names:
        raise MvpdExportError(f"{run.location}: the run has no split stage output; give --split NAME to export every "
                              "video as one split")
    return [export_release(run, out_root, name, embodiment, overwrite, on_video, on_start) for name in names]


def _choose_embodiment(run: RunFolder, requested: str | None) -> str:
    """The embodiment whose masks, depth and colour images are exported (`imagesRGB`).

    Without `requested`: the job's only embodiment, or its only ambient one when every other differs from
    it only by a spot light (those become `imagesRGB.<watts>` folders, as in the release).
    """
    embodiments = run.job().embodiments
    names = [e.name for e in embodiments]
    if requested is not None:
        if requested not in names:
            raise MvpdExportError(f"{run.root}: no embodiment {requested!r} in the job; "
                                  f"choose one of {', '.join(names)}")
        return requested
    ambient = [e for e in embodiments if e.illumination.kind == "ambient"]
    if len(names) > 1 and not (len(ambient) == 1 and len(_lit_companions(run, ambient[0].name)) == len(names) - 1):
        raise MvpdExportError(f"{run.root}: the job has embodiments {', '.join(names)}, which are not one ambient camera "
                              "and its spot-lit copies; choose one with --embodiment")
    return ambient[0].name if len(names) > 1 else names[0]


def _lit_companions(run: RunFolder, chosen: str) -> dict[str, str]:
    """`imagesRGB.<watts:010d>` folder -> embodiment, for the spot-lit embodiments that are `chosen` in all but light."""
    job = run.job()
    base = job.embodiment(chosen)
    if base.illumination.kind != "ambient":
        return {}
    same = lambda e: e.model_dump(exclude={"name", "illumination"}) == base.model_dump(exclude={"name", "illumination"})  # noqa: E731
    return {f"{IMAGES_RGB}.{round(e.illumination.power):010d}": e.name for e in job.embodiments
            if e.name != chosen and e.illumination.kind == "spot" and same(e)}


def _camera_warnings(run: RunFolder, chosen: str) -> list[str]:
    """One line when the camera is not the release's 640x480 / 69 degrees (the authors' loader hard-codes it)."""
    sensor = run.job().embodiment(chosen).sensor
    fx, _, cx, cy = sensor.intrinsics()
    if (sensor.width, sensor.height) == (640, 480) and abs(fx - MVPD_FX) < 1e-3 and (cx, cy) == (320.0, 240.0):
        return []
    return [f"embodiment {chosen}: camera {sensor.width}x{sensor.height}, fx {fx:.4g}, is not MVPd's 640x480 / 69 degrees "
            f"(fx {MVPD_FX}); the authors' loader hard-codes those intrinsics, read ours from the run"]


def _videos_of(run: RunFolder, embodiment: str) -> dict[str, dict[str, Any]]:
    """Committed videos of the embodiment, by name in sorted order -> their `videos` row (scene_id, frames);
    the `videos` table lists committed ones only."""
    rows = [row for row in run.read("videos").select(["video_name", "embodiment", "scene_id", "frames"]).to_pylist()
            if row["embodiment"] == embodiment]
    if not rows:
        raise MvpdExportError(f"{run.root / 'videos'}: no videos of embodiment {embodiment!r}; "
                              "run the render stage first")
    return {row["video_name"]: row for row in sorted(rows, key=lambda row: row["video_name"])}


@dataclass(frozen=True)
class VideoTask:
    """What exporting one video needs, small enough to send to a worker process: store locations, not stores,
    and only its own scene's objects."""

    store: str
    extra_rgb: dict[str, str]
    objects: dict[tuple[str, int], tuple[int, str]]
    split_folder: Path
    first_image_id: int
    frames: int


def _video_tasks(run: RunFolder, videos: dict[str, dict[str, Any]], chosen: str, lit: dict[str, str],
                 objects: dict[tuple[str, int], tuple[int, str]], staging: Path) -> list[VideoTask]:
    """One task per video in order; image ids run on over the split's videos, from the frame counts."""
    stores = video_locations(run)  # local paths, or URLs on the run's object store
    by_scene: dict[str, dict[tuple[str, int], tuple[int, str]]] = {}
    for key, value in objects.items():
        by_scene.setdefault(key[0], {})[key] = value
    tasks, first_image_id = [], 0
    for name, video in videos.items():
        tasks.append(VideoTask(stores[(chosen, name)], {folder: stores[(other, name)] for folder, other in lit.items()},
                               by_scene.get(video["scene_id"], {}), staging, first_image_id, int(video["frames"])))
        first_image_id += int(video["frames"])
    return tasks


def _export_video(task: VideoTask) -> VideoExport:
    """Write one video's files (in this process or a worker) and return its entries."""
    extra_rgb = {folder: open_video(store) for folder, store in task.extra_rgb.items()}
    return VideoExporter(open_video(task.store), task.objects, task.split_folder, extra_rgb, task.first_image_id).run()


def _spool_videos(tasks: list[VideoTask], panoptic_json: Path, on_video: Callable[[str], None] | None
                  ) -> list[ExportedVideo]:
    """Export every video, appending its entries to `panoptic_json` as it finishes (see panoptic_json.py)."""
    spool, exported = PanopticJsonSpool(panoptic_json.parent, panoptic_json.name), []
    try:
        for export in _export_videos(tasks):
            spool.add(export.name, export.images, export.annotations, export.instance_id_map,
                      [export.instances[k] for k in sorted(export.instances)])
            exported.append(ExportedVideo(export.name, len(export.images), export.empty))
            if on_video is not None:
                on_video(export.name)
        spool.finish()
    finally:
        spool.close()
    return exported


def _export_videos(tasks: list[VideoTask]) -> Iterator[VideoExport]:
    """Each video's entries in task order, on one process per available core when there are several videos.

    Videos are independent and encoding a frame's JPEG and PNG files is the cost: in one process MVPd's 6 M
    frames would take days of wall time (benchmarks/results/full_job_1pct.json). An export under
    2 x FRAMES_PER_WORKER frames stays in this process. Workers are spawned, not forked (the caller may hold
    threads), and results come back in order, so the split's JSON files are the same whatever the workers.
    """
    frames = sum(task.frames for task in tasks)
    workers = min(len(tasks), len(os.sched_getaffinity(0)), max(1, frames // FRAMES_PER_WORKER))
    if workers <= 1:
        yield from map(_export_video, tasks)
        return
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        try:
            yield from pool.map(_export_video, tasks)
        finally:
            pool.shutdown(cancel_futures=True)


def _release_objects(run: RunFolder) -> dict[tuple[str, int], tuple[int, str]]:
    """(scene id, object id) -> (mpcat40 category, raw name), from the run's `objects` table."""
    table = run.read("objects")
    columns = (table[c].to_pylist() for c in ("scene_id", "object_id", "mpcat40_index", "raw_name"))
    return {(scene, int(obj)): (int(category), str(name)) for scene, obj, category, name in zip(*columns)}


# ------------------------------------------------------------------------------------------ videos


class VideoExporter:
    """Writes the frame files of one video into the split folder and collects its JSON entries.

    Args:
        video: the video's Zarr store (masks, depth and the `imagesRGB` colour images).
        objects: (scene, object id) -> (mpcat40 category, raw name) of the run.
        split_folder: where `panomasksRGB/`, `imagesRGB/`, `imagesDEPTH/` go.
        extra_rgb: `imagesRGB.<watts>` folder -> the same video rendered with that spot light.
        first_image_id: image id of the video's first frame (ids run on over the split's videos).
    """

    def __init__(self, video: Video, objects: dict[tuple[str, int], tuple[int, str]], split_folder: Path,
                 extra_rgb: dict[str, Video] | None = None, first_image_id: int = 0):
        attrs = video.attrs
        self.video = video
        self.objects = objects
        self.name, self.scene = str(attrs["video_name"]), str(attrs["scene_id"])
        absent = set(attrs.get("absent_arrays", []))
        # An imported MVPd video remembers its original PNG segment ids, so re-exporting reproduces them.
        self.segment_ids = {int(k): int(v) for k, v in attrs.get("mvpd_segment_ids", {}).items()}
        # Arrays an import found absent hold zeros: they are not written as if they were data.
        wanted = {PANOMASKS: True, IMAGES_RGB: "rgb" not in absent, IMAGES_DEPTH: "depth" not in absent}
        self.extra_rgb = dict(extra_rgb or {})
        wanted.update({folder: True for folder in self.extra_rgb})
        self.folders = {kind: split_folder / kind / self.name for kind, keep in wanted.items() if keep}
        self.first_image_id = first_image_id
        self.export = VideoExport(self.name, [], [], {}, False)

    def run(self) -> VideoExport:
        """Write every frame's files (PNG mask; JPEG colour and PNG depth unless absent); return the entries."""
        for folder in self.folders.values():
            folder.mkdir(parents=True)
        poses = self.video.poses()
        for start in range(0, self.video.frames, READ_BLOCK):
            stop = min(start + READ_BLOCK, self.video.frames)
            panoptic = np.asarray(self.video.panoptic[start:stop])
            rgb = np.asarray(self.video.rgb[start:stop]) if IMAGES_RGB in self.folders else None
            depth = np.asarray(self.video.depth[start:stop]) if IMAGES_DEPTH in self.folders else None
            for folder, lit in self.extra_rgb.items():
                self._write_jpegs(folder, start, np.asarray(lit.rgb[start:stop]))
            for offset in range(stop - start):
                self._write_frame(start + offset, panoptic[offset], None if rgb is None else rgb[offset],
                                  None if depth is None else depth[offset], poses[start + offset])
        self._add_unseen_instances()
        instances = self.export.instance_id_map
        self.export.instance_id_map = {str(k): instances[k] for k in sorted(instances)}
        return self.export

    def _write_jpegs(self, folder: str, start: int, rgb: np.ndarray) -> None:
        for offset, image in enumerate(rgb):
            _write_jpeg(self.folders[folder] / f"{frame_stem(start + offset)}.jpg", image)

    def _write_frame(self, frame: int, panoptic: np.ndarray, rgb: np.ndarray | None, depth: np.ndarray | None,
                     pose: np.ndarray) -> None:
        png_ids, present = _to_mvpd_ids(panoptic, self.scene, self.name, self.objects, self.segment_ids)
        self.export.empty |= float(np.mean(png_ids == 0)) > EMPTY_VOID_FRACTION
        self.export.instance_id_map.update({k: v["map"] for k, v in present.items()})
        for segment, entry in present.items():
            self.export.instances.setdefault(segment, entry["instance"])
        stem = frame_stem(frame)
        with replaced(self.folders[PANOMASKS] / f"{stem}.png") as temporary:  # a new file each (see `replaced`)
            Image.fromarray(ids_to_png(png_ids)).save(temporary, format="PNG")
        if rgb is not None:
            _write_jpeg(self.folders[IMAGES_RGB] / f"{stem}.jpg", rgb)
        if depth is not None:
            _write_depth_png(self.folders[IMAGES_DEPTH] / f"{stem}.png", depth)
        position, rotation = pose_to_mvpd(pose)
        image_id = self.first_image_id + frame
        height, width = panoptic.shape
        self.export.images.append({"id": image_id, "width": int(width), "height": int(height),
                                   "file_name": f"{stem}.jpg", "depth_file_name": f"{stem}.png", "scene_id": self.scene,
                                   "camera_position": position, "camera_rotation": rotation})
        self.export.annotations.append({"image_id": image_id, "file_name": f"{stem}.png",
                                        "segments_info": _segments_info(png_ids, present)})

    def _add_unseen_instances(self) -> None:
        """An imported video also lists instances its masks never show (MVPd's maps may): keep them listed."""
        for object_id, segment in self.segment_ids.items():
            category, _ = self.objects.get((self.scene, object_id), (0, ""))
            if segment not in self.export.instance_id_map and category > 0:
                self.export.instance_id_map[segment] = {"category_id": category, "scene_name": self.scene,
                                                        "color": object_id_to_color(object_id)}


def _write_jpeg(path: Path, rgb: np.ndarray) -> None:
    with replaced(path) as temporary:
        Image.fromarray(rgb).save(temporary, format="JPEG", quality=JPEG_QUALITY, subsampling=0)


def _segments_info(png_ids: np.ndarray, present: dict[int, dict[str, Any]]) -> list[dict[str, Any]]:
    """COCO panoptic `segments_info` of one frame: id, category, area, bbox [x, y, w, h], iscrowd, instance id."""
    if not present:
        return []
    labels = DenseLabels.from_categories({segment: entry["map"]["category_id"] for segment, entry in present.items()})
    found = frame_segments(png_ids, labels)
    info = []
    for k, segment in enumerate(int(v) for v in found.object_ids):
        x0, y0, x1, y1 = (int(v) for v in found.boxes[k])
        info.append({"id": segment, "category_id": int(found.categories[k]), "area": int(found.areas[k]),
                     "bbox": [x0, y0, x1 - x0, y1 - y0], "iscrowd": 0, "instance_id": present[segment]["object_id"]})
    return info


def _to_mvpd_ids(panoptic: np.ndarray, scene: str, video: str, objects: dict[tuple[str, int], tuple[int, str]],
                 segment_ids: dict[int, int]) -> tuple[np.ndarray, dict[int, dict[str, Any]]]:
    """One frame of object ids -> MVPd segment ids, and per segment present its `instance_id_map` entry
    (`map`), its release `instance` entry and its object id.

    Objects without an mpcat40 category become void, as in MVPd (its formatter skips category 0).
    """
    unique, inverse = unique_with_inverse(panoptic)
    mapped = np.zeros(len(unique), dtype=np.uint32)
    present: dict[int, dict[str, Any]] = {}
    for index, object_id in enumerate(int(v) for v in unique):
        if object_id == 0:
            continue
        found = objects.get((scene, object_id))
        if found is None:
            raise MvpdExportError(
                f"video {video}: object {object_id} of scene {scene} is not in the objects table; run the shard stage"
            )
        category, raw_name = found
        if category == 0:
            continue
        segment = segment_ids.get(object_id, object_id)
        if segment > MAX_MVPD_ID or object_id > MAX_MVPD_ID:
            raise MvpdExportError(f"video {video}: object id {object_id} does not fit MVPd's 24-bit RGB ids")
        mapped[index] = segment
        color = object_id_to_color(object_id)
        present[segment] = {
            "object_id": object_id,
            "map": {"category_id": category, "scene_name": scene, "color": color},
            "instance": {"id": segment, "category_id": category, "raw_category": raw_name, "color": color,
                         "scene_id": scene, "scene_name": scene, "video_name": video},
        }
    return mapped[inverse.reshape(panoptic.shape)], present


def _write_depth_png(path: Path, depth: np.ndarray) -> None:
    """uint16 millimetres as a 16-bit greyscale PNG (what MVPd's loader reads with cv2)."""
    with replaced(path) as temporary:
        if not cv2.imwrite(str(temporary), np.ascontiguousarray(depth, dtype=np.uint16)):
            raise OSError(f"{path}: could not write the depth PNG; check free space and permissions")


# ------------------------------------------------------------------------------------- split files


def _write_filter_files(folder: Path, split: str, exported: list[ExportedVideo]) -> None:
    """empty_videos.json and zero_shot.json of a split exported without a split stage, into `folder`."""
    write_json(folder / EMPTY_VIDEOS, {"accepted": [v.name for v in exported if not v.empty],
                                    "rejected": [v.name for v in exported if v.empty]})
    # Until a split stage exists no object is zero-shot, so no training video is removed for one.
    zero_shot: dict[str, Any] = (
        {"accepted": [v.name for v in exported], "rejected": []} if split == TRAIN_SPLIT else {"zero-shot": []}
    )
    write_json(folder / ZERO_SHOT, zero_shot)


def swap_into_place(staging: Path, target: Path) -> None:
    """Rename the finished split into place; an older export is moved aside first, then deleted."""
    if not target.exists():
        os.replace(staging, target)
        return
    aside = target.with_name(f".{target.name}.old-{os.getpid()}")
    shutil.rmtree(aside, ignore_errors=True)
    os.replace(target, aside)
    os.replace(staging, target)
    shutil.rmtree(aside, ignore_errors=True)
