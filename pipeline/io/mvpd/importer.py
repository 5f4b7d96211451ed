"""Import one split of an MVPd release into a run folder (`mvpd import-mvpd ROOT --split test RUN`).

Each video is one unit of the `import` stage: its Zarr store and its table parts are written into a
staging folder and committed whole by the run folder, then its marker is written. A re-import skips
videos whose marker matches (same annotation entries, same arrays present) and replaces the others,
so rows are never duplicated. Objects are one unit per scene (they are shared by the scene's videos).
The mapping between the two layouts is documented in schemas/mvpd.md.
"""

from __future__ import annotations

import logging
import shutil
import socket
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
from PIL import Image
from pydantic import ValidationError
from scipy import ndimage

from pipeline.config import (
    ConfigError,
    Embodiment,
    Job,
    MvpdReleaseSource,
    SceneSources,
    Sensor,
    config_hash,
)
from pipeline.io.mvpd.layout import (
    MVPD_HFOV_DEGREES,
    MvpdFormatError,
    SplitPaths,
    VideoName,
    color_to_object_id,
    matrix_to_quaternion,
    parse_video_name,
    png_to_ids,
    pose_from_mvpd,
    read_json,
    require,
)
from pipeline.io.tables import spec, to_table, write_part
from pipeline.io.zarr_video import VideoWriter
from pipeline.runtime.lock import RunLock
from pipeline.runtime.run_folder import Marker, RunFolder, RunFolderError
from pipeline.runtime.status import UnitOutcome, read_status, write_status
from pipeline.scenes.categories import STUFF_CATEGORIES, categories

log = logging.getLogger(__name__)
STAGE = "import"
DEFAULT_EMBODIMENT = "mvpd"


class MvpdImportError(ValueError):
    """A release that cannot go into the given run folder; the message names the folder and the fix."""


@dataclass(frozen=True)
class ReleaseVideo:
    """One video of the split as its panoptic JSON describes it (matched by name, not by list position)."""

    name: VideoName
    video_name: str
    images: list[dict[str, Any]]
    masks: list[str]
    segments: dict[int, tuple[int, int]]  # PNG segment id -> (our object id, category)
    entry_hash: str


@dataclass
class ImportSummary:
    """What an import did (returned to the CLI for its one-line summary)."""

    run_root: Path
    imported: list[str] = field(default_factory=list)
    up_to_date: list[str] = field(default_factory=list)
    frames: int = 0
    absent_arrays: set[str] = field(default_factory=set)
    seconds: float = 0.0


def import_release(root: Path, split: str, run_root: Path, embodiment: str = DEFAULT_EMBODIMENT, force: bool = False,
                   on_start: Callable[[int], None] | None = None,
                   on_video: Callable[[str], None] | None = None) -> ImportSummary:
    """Read `<root>/<split>` of an MVPd release into the run folder `run_root` (created when new).

    Args:
        root: the MVPd root (holds `<split>/panoptic_<split>.json`).
        split: the split folder to read; every video of the run belongs to it.
        run_root: the run folder to create or update.
        embodiment: embodiment name the videos are stored under (`videos/<embodiment>/...`).
        force: re-import videos whose marker says they are up to date.
        on_start, on_video: progress callbacks (number of videos; each handled video's name).
    """
    started = time.monotonic()
    paths = SplitPaths(Path(root).expanduser().resolve(), split)
    data = read_json(paths.annotations, f"{split}/panoptic_{split}.json")
    videos = read_release_videos(data, paths.annotations)
    width, height = _frame_size(paths, videos[0])
    job = release_job(paths, embodiment, videos, width, height)
    run = _open_run(Path(run_root), job)
    summary = ImportSummary(run.root)
    if on_start is not None:
        on_start(len(videos))
    with RunLock(run.root):
        outcomes: dict[str, UnitOutcome] = {}
        try:
            for video in videos:
                _import_unit(run, job, paths, video, (width, height), force, summary, outcomes)
                if on_video is not None:
                    on_video(video.video_name)
            _import_objects(run, videos, force)
        finally:
            # Written even when a video fails, so the run's status names it and what went wrong.
            previous = {unit: outcome for (_, unit), outcome in read_status(run.root, STAGE).items()}
            write_status(run.root, STAGE, {**previous, **outcomes})
    summary.seconds = time.monotonic() - started
    return summary


# ------------------------------------------------------------------------------------ the JSON


def read_release_videos(data: Any, source: Path) -> list[ReleaseVideo]:
    """Pair `videos` and `annotations` entries by video name and check what the import needs."""
    video_entries = require(data, "videos", list, source, "(top level)")
    annotation_entries = require(data, "annotations", list, source, "(top level)")
    annotations = {require(a, "video_name", str, source, "annotations[]"): a for a in annotation_entries}
    videos = []
    for index, entry in enumerate(video_entries):
        where = f"videos[{index}]"
        name = require(entry, "video_name", str, source, where)
        if name not in annotations:
            raise MvpdFormatError(f"{source}: {where}: video {name} has no entry in annotations; "
                                  "the file is incomplete")
        videos.append(_release_video(name, entry, annotations[name], source, where))
    if not videos:
        raise MvpdFormatError(f"{source}: videos: the split lists no videos; give a non-empty split")
    names = [v.video_name for v in videos]
    if len(set(names)) != len(names):
        raise MvpdFormatError(f"{source}: videos: a video name occurs twice; the file is corrupt")
    return sorted(videos, key=lambda v: v.video_name)


def _release_video(name: str, entry: dict, annotation: dict, source: Path, where: str) -> ReleaseVideo:
    images = require(entry, "images", list, source, where)
    masks = [require(a, "file_name", str, source, f"{where}.annotations[]")
             for a in require(annotation, "annotations", list, source, f"annotations[{name}]")]
    if len(masks) != len(images) or not images:
        raise MvpdFormatError(f"{source}: {name}: {len(images)} images but {len(masks)} masks; "
                              "the file is inconsistent")
    for i, image in enumerate(images):
        require(image, "camera_position", list, source, f"{where}.images[{i}]")
        require(image, "camera_rotation", list, source, f"{where}.images[{i}]")
    instance_map = require(annotation, "instance_id_map", dict, source, f"annotations[{name}]")
    segments = _segment_ids(name, instance_map, source)
    entry_hash = config_hash({"images": images, "annotations": masks, "instance_id_map": instance_map})
    return ReleaseVideo(parse_video_name(name, source), name, images, masks, segments, entry_hash)


def _segment_ids(video: str, instance_map: dict, source: Path) -> dict[int, tuple[int, int]]:
    """PNG segment id -> (object id = the HM3DSem colour 0xRRGGBB, mpcat40 category)."""
    segments: dict[int, tuple[int, int]] = {}
    for key, info in instance_map.items():
        where = f"annotations[{video}].instance_id_map.{key}"
        color = require(info, "color", list, source, where)
        object_id = color_to_object_id(color)
        if not key.isdigit() or int(key) == 0 or object_id == 0:
            raise MvpdFormatError(f"{source}: {where}: segment ids and colours must be non-zero; the file is corrupt")
        segments[int(key)] = (object_id, int(require(info, "category_id", int, source, where)))
    colours = Counter(object_id for object_id, _ in segments.values())
    repeated = [f"{object_id:06x}" for object_id, count in colours.items() if count > 1]
    if repeated:
        raise MvpdFormatError(f"{source}: annotations[{video}]: colour {repeated[0]} names two segments; "
                              "the file is corrupt")
    return segments


def _frame_size(paths: SplitPaths, video: ReleaseVideo) -> tuple[int, int]:
    """(width, height) of the split's frames, from the first mask (MVPd has one camera for all videos)."""
    first = paths.panomask(video.video_name, video.masks[0])
    if not first.is_file():
        raise MvpdFormatError(f"{first}: no such mask; the {paths.split} split is incomplete")
    with Image.open(first) as image:
        return image.size


def release_job(paths: SplitPaths, embodiment: str, videos: list[ReleaseVideo], width: int, height: int) -> Job:
    """The job an imported run records: the release as its scene source, MVPd's camera at the heights found."""
    heights = sorted({v.name.height_m for v in videos}, reverse=True)
    try:
        return Job(
            name=f"mvpd-{paths.split}",
            scenes=SceneSources(mvpd=MvpdReleaseSource(root=paths.root, split=paths.split)),
            embodiments=[Embodiment(name=embodiment, sensor=Sensor(width=width, height=height, hfov=MVPD_HFOV_DEGREES),
                                    placements=heights)],
        )
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"{paths.annotations}: the imported job is invalid ({where}: {first['msg']}); "
                          "check --embodiment") from None


def _open_run(run_root: Path, job: Job) -> RunFolder:
    """Create the run, or reopen one that holds the same import (anything else is refused)."""
    run = RunFolder(run_root)
    if (run.root / "job.yaml").is_file():
        existing = RunFolder.open(run.root).job()
        if existing.hash() != job.hash():
            raise MvpdImportError(
                f"{run.root}: holds another job ({existing.name}, hash {existing.hash()}); import into a new folder"
            )
        return run
    try:
        return RunFolder.create(run.root, job)
    except RunFolderError as error:
        raise MvpdImportError(str(error)) from None


# ----------------------------------------------------------------------------------- one video


def _import_unit(run: RunFolder, job: Job, paths: SplitPaths, video: ReleaseVideo, size: tuple[int, int],
                 force: bool, summary: ImportSummary, outcomes: dict[str, UnitOutcome]) -> None:
    """Import one video unless its marker says it is up to date; commit, then write its marker."""
    embodiment = job.embodiments[0]
    arrays = _present_arrays(paths, video.video_name)
    unit_hash = config_hash({"entry": video.entry_hash, "arrays": arrays,
                             "embodiment": embodiment.model_dump(mode="json")})
    marker = run.marker(STAGE, video.video_name)
    if not force and marker is not None and marker.config_hash == unit_hash \
            and all((run.root / p).exists() for p in marker.outputs):
        summary.up_to_date.append(video.video_name)
        outcomes[video.video_name] = UnitOutcome(STAGE, video.video_name, "done", marker.attempt,
                                                 seconds=marker.seconds)
        return
    started = time.monotonic()
    staging = run.staging(STAGE, video.video_name)
    attempt = (marker.attempt + 1) if marker is not None else 1
    try:
        rows = VideoImporter(paths, video, embodiment, job.render.frames_per_shard, size, arrays).write(staging)
    except BaseException as error:
        shutil.rmtree(staging, ignore_errors=True)  # nothing of a failed video reaches the run
        outcomes[video.video_name] = UnitOutcome(STAGE, video.video_name, "failed", attempt, type(error).__name__,
                                                 str(error), seconds=time.monotonic() - started)
        raise
    outputs = run.commit(staging, marker.outputs if marker is not None else [])
    seconds = time.monotonic() - started
    run.write_marker(Marker(STAGE, video.video_name, unit_hash, _code_version(), outputs, rows, round(seconds, 3),
                            attempt, socket.gethostname(), time.time(),
                            {"absent_arrays": [a for a in ("rgb", "depth") if a not in arrays]}))
    outcomes[video.video_name] = UnitOutcome(STAGE, video.video_name, "done", attempt, seconds=seconds)
    summary.imported.append(video.video_name)
    summary.frames += len(video.images)
    summary.absent_arrays.update(a for a in ("rgb", "depth") if a not in arrays)


def _present_arrays(paths: SplitPaths, video: str) -> list[str]:
    """Which arrays the release has for this video: the mask always, colour and depth when their folders exist."""
    arrays = ["panoptic"]
    if paths.rgb_folder(video).is_dir():
        arrays.append("rgb")
    if paths.depth_folder(video).is_dir():
        arrays.append("depth")
    return arrays


class VideoImporter:
    """Reads one video's frames from the release and stages its Zarr store and table parts."""

    def __init__(self, paths: SplitPaths, video: ReleaseVideo, embodiment: Embodiment, frames_per_shard: int,
                 size: tuple[int, int], arrays: list[str]):
        self.paths = paths
        self.video = video
        self.embodiment = embodiment
        self.frames_per_shard = frames_per_shard
        self.width, self.height = size
        self.arrays = arrays
        fx, fy, cx, cy = embodiment.sensor.intrinsics()
        self.intrinsics = {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "width": self.width, "height": self.height}

    def write(self, staging: Path) -> dict[str, int]:
        """Stage `videos/<embodiment>/<name>.zarr` and the parts of videos, frames, frame_stats, segments."""
        name = self.video.video_name
        poses = [pose_from_mvpd(i["camera_position"], i["camera_rotation"]) for i in self.video.images]
        relative = Path("videos") / self.embodiment.name / f"{name}.zarr"
        writer = VideoWriter(staging / relative, len(poses), self.width, self.height, self._attributes(poses),
                             frames_per_shard=self.frames_per_shard)
        segments, stats = [], []
        for frame in range(len(poses)):
            ids, rgb, depth = self._read_frame(frame)
            writer.append(rgb=rgb, depth=depth, panoptic=ids)
            segments.extend(self._segment_rows(frame, ids))
            stats.append(self._stats_row(frame, ids, depth))
        writer.close()
        tables = {
            "videos": [self._video_row(relative, _folder_bytes(staging / relative))],
            "frames": [self._frame_row(frame, pose) for frame, pose in enumerate(poses)],
            "frame_stats": stats,
            "segments": segments,
        }
        for dataset, rows in tables.items():
            write_part(staging, dataset, name, _table(dataset, rows))
        return {dataset: len(rows) for dataset, rows in tables.items()}

    def _attributes(self, poses: list[np.ndarray]) -> dict[str, Any]:
        video = self.video
        return {
            "video_name": video.video_name,
            "scene_id": video.name.scene_id,
            "embodiment": self.embodiment.model_dump(mode="json"),
            "height_m": video.name.height_m,
            "intrinsics": self.intrinsics,
            "poses": [pose.tolist() for pose in poses],
            "source": {"format": "mvpd", "root": str(self.paths.root), "split": self.paths.split},
            # Arrays the release lacks are stored as zeros; readers check this list before trusting them.
            "absent_arrays": [a for a in ("rgb", "depth") if a not in self.arrays],
            # Our id is the HM3DSem colour; the original PNG ids are kept so an export reproduces the files.
            "mvpd_segment_ids": {str(obj): seg for seg, (obj, _) in sorted(video.segments.items())},
        }

    def _read_frame(self, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(object ids uint32, rgb uint8, depth uint16) of one frame; absent arrays are zeros."""
        name = self.video.video_name
        mask_path = self.paths.panomask(name, self.video.masks[frame])
        ids = self._object_ids(png_to_ids(self._read_image(mask_path, "RGB")), mask_path)
        rgb = np.zeros((self.height, self.width, 3), np.uint8)
        if "rgb" in self.arrays:
            rgb = self._read_image(self.paths.rgb_folder(name) / self.video.images[frame]["file_name"], "RGB")
        depth = np.zeros((self.height, self.width), np.uint16)
        if "depth" in self.arrays:
            stem = Path(self.video.images[frame]["file_name"]).stem
            depth = self._read_depth(self.paths.depth_folder(name) / f"{stem}.png")
        return ids, rgb, depth

    def _read_image(self, path: Path, mode: str) -> np.ndarray:
        if not path.is_file():
            raise MvpdFormatError(f"{path}: no such file; the {self.paths.split} split is incomplete")
        with Image.open(path) as image:
            pixels = np.asarray(image.convert(mode))
        self._check_size(path, pixels)
        return pixels

    def _read_depth(self, path: Path) -> np.ndarray:
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
        if depth is None or depth.dtype != np.uint16 or depth.ndim != 2:
            raise MvpdFormatError(f"{path}: missing or not a 16-bit greyscale PNG; MVPd depth is uint16 millimetres")
        self._check_size(path, depth)
        return depth

    def _check_size(self, path: Path, pixels: np.ndarray) -> None:
        if pixels.shape[:2] != (self.height, self.width):
            raise MvpdFormatError(f"{path}: {pixels.shape[1]}x{pixels.shape[0]} pixels, the split's frames are "
                                  f"{self.width}x{self.height}; one import holds one camera")

    def _object_ids(self, segment_ids: np.ndarray, path: Path) -> np.ndarray:
        """PNG segment ids -> our object ids (the HM3DSem colour), through the video's instance_id_map."""
        unique, inverse = np.unique(segment_ids, return_inverse=True)
        mapped = np.zeros(len(unique), np.uint32)
        for index, segment in enumerate(int(s) for s in unique):
            if segment == 0:
                continue
            if segment not in self.video.segments:
                raise MvpdFormatError(f"{path}: segment id {segment} is not in the video's instance_id_map; "
                                      "the mask and panoptic JSON disagree")
            mapped[index] = self.video.segments[segment][0]
        return mapped[inverse.reshape(segment_ids.shape)]

    # ---------------------------------------------------------------------------------- rows
    def _key(self) -> dict[str, str]:
        return {"embodiment": self.embodiment.name, "video_name": self.video.video_name}

    def _video_row(self, store: Path, size: int) -> dict[str, Any]:
        name = self.video.name
        return {
            **self._key(), "scene_id": name.scene_id, "trajectory": name.trajectory, "height_m": name.height_m,
            "illumination": "ambient", "sensor_model": self.embodiment.sensor.model, "frames": len(self.video.images),
            "width": self.width, "height": self.height, **{k: self.intrinsics[k] for k in ("fx", "fy", "cx", "cy")},
            "exposure": float("nan"), "store_path": str(store), "bytes": size, "render_seconds": 0.0,
        }

    def _frame_row(self, frame: int, pose: np.ndarray) -> dict[str, Any]:
        qw, qx, qy, qz = matrix_to_quaternion(pose[:3, :3])
        px, py, pz = pose[:3, 3]
        return {**self._key(), "frame": frame, "px": px, "py": py, "pz": pz, "qw": qw, "qx": qx, "qy": qy, "qz": qz}

    def _segment_rows(self, frame: int, ids: np.ndarray) -> list[dict[str, Any]]:
        categories_by_object = {obj: category for obj, category in self.video.segments.values()}
        return [
            {**self._key(), "frame": frame, "object_id": obj, "category": categories_by_object[obj], "area": area,
             "x0": x0, "y0": y0, "x1": x1, "y1": y1}
            for obj, area, x0, y0, x1, y1 in frame_segments(ids)
        ]

    def _stats_row(self, frame: int, ids: np.ndarray, depth: np.ndarray) -> dict[str, Any]:
        return {**self._key(), "frame": frame, "render_seconds": 0.0, "void_fraction": float(np.mean(ids == 0)),
                "visible_objects": int(len(np.unique(ids[ids > 0]))),
                "valid_depth_fraction": float(np.mean(depth > 0))}


def frame_segments(ids: np.ndarray) -> list[tuple[int, int, int, int, int, int]]:
    """(object id, area, x0, y0, x1, y1) of every non-void id of a frame; x1, y1 exclusive; sorted by id."""
    unique, inverse = np.unique(ids, return_inverse=True)
    inverse = inverse.reshape(ids.shape)
    areas = np.bincount(inverse.ravel(), minlength=len(unique))
    boxes = ndimage.find_objects(inverse + 1)  # label i + 1 is unique[i]; one pass for every box
    rows = []
    for index, object_id in enumerate(int(v) for v in unique):
        if object_id == 0:
            continue
        rows_slice, cols_slice = boxes[index]
        rows.append((object_id, int(areas[index]), cols_slice.start, rows_slice.start,
                     cols_slice.stop, rows_slice.stop))
    return rows


def _folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def _table(dataset: str, rows: list[dict[str, Any]]) -> pa.Table:
    """Rows -> table of a registered dataset; a column the import does not fill is a bug, not a null."""
    expected = {f.name for f in spec(dataset).schema}
    for row in rows[:1]:
        missing = sorted(expected - set(row))
        if missing:
            raise KeyError(f"dataset {dataset}: the MVPd import does not fill {', '.join(missing)}; update importer.py")
    return to_table(dataset, rows)


def _code_version() -> str:
    from pipeline.runtime.executor import code_version  # imported late: the executor pulls in Ray

    return code_version()


# ------------------------------------------------------------------------------------- objects


def _import_objects(run: RunFolder, videos: list[ReleaseVideo], force: bool) -> None:
    """One `objects` part per scene: every (scene, colour) the split's videos show, with its category."""
    by_scene: dict[str, dict[int, Counter]] = defaultdict(lambda: defaultdict(Counter))
    for video in videos:
        for object_id, category in video.segments.values():
            by_scene[video.name.scene_id][object_id][category] += 1
    for scene, objects in sorted(by_scene.items()):
        rows = [_object_row(scene, object_id, counts) for object_id, counts in sorted(objects.items())]
        unit_hash = config_hash({"objects": [(r["object_id"], r["mpcat40_index"]) for r in rows]})
        marker = run.marker(STAGE, scene)
        if not force and marker is not None and marker.config_hash == unit_hash \
                and all((run.root / p).exists() for p in marker.outputs):
            continue
        staging = run.staging(STAGE, scene)
        write_part(staging, "objects", scene, _table("objects", rows))
        outputs = run.commit(staging, marker.outputs if marker is not None else [])
        run.write_marker(Marker(STAGE, scene, unit_hash, _code_version(), outputs, {"objects": len(rows)}, 0.0,
                                (marker.attempt + 1) if marker is not None else 1, socket.gethostname(), time.time()))


def _object_row(scene: str, object_id: int, counts: Counter) -> dict[str, Any]:
    """An objects row from MVPd's instance entries: the split files carry no raw names or geometry."""
    # Videos of one scene should agree on an object's category; if not, the most frequent (then lowest) wins.
    category = min(counts, key=lambda c: (-counts[c], c))
    if len(counts) > 1:
        log.warning("scene %s object %06x has categories %s in different videos; using %s", scene, object_id,
                    dict(counts), category)
    nan = float("nan")
    return {
        "scene_id": scene, "object_id": object_id, "raw_name": "", "mpcat40_index": category,
        "mpcat40_name": categories()[category].name if category in categories() else "void",
        "is_stuff": category in STUFF_CATEGORIES, "region": -1, "triangles": 0,
        "min_x": nan, "min_y": nan, "min_z": nan, "max_x": nan, "max_y": nan, "max_z": nan, "surface_area": nan,
    }
