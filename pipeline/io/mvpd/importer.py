"""Import one split of an MVPd release into a run folder (`mvpd import-mvpd ROOT --split test RUN`).

`MvpdImporter` is the `import` stage, run by the shared executor like every other stage: one Ray task
per video (unit id = video name: its Zarr store and its `videos`, `frames`, `frame_stats`, `segments`
parts) and one per scene (unit id = scene id: its `objects` part, shared by the scene's videos). The
panoptic JSON is read once, in the driver; each unit's params carry its own entry, so its config hash
changes exactly when that entry (or the arrays present) changes, and a re-import runs only those units.
Staging, commit, markers, status rows, per-unit logs and retries of dead workers are the executor's.
The mapping between the two layouts is documented in schemas/mvpd.md.
"""

from __future__ import annotations

import logging
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

from pipeline.config import ConfigError, Embodiment, Job, MvpdReleaseSource, SceneSources, Sensor
from pipeline.io.mvpd.layout import (
    EMPTY_VIDEOS,
    ZERO_SHOT,
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
from pipeline.io.mvpd.split_files import read_split_flags
from pipeline.io.segments import DenseLabels, FrameSegments, frame_segments, unique_with_inverse
from pipeline.io.tables import spec, to_table
from pipeline.io.zarr_video import VideoWriter
from pipeline.runtime.executor import ProgressCallback, StagePlan, StageReport, run_stage
from pipeline.runtime.executors import ExecutorName
from pipeline.store.names import JOB_FILE
from pipeline.store.run_folder import RunFolder, RunFolderError
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.runtime.status import UnitOutcome
from pipeline.scenes.categories import STUFF_CATEGORIES, categories

log = logging.getLogger(__name__)
STAGE = "import"
DEFAULT_EMBODIMENT = "mvpd"
SPLIT_FLAGS_UNIT = "split-flags"  # the unit turning empty_videos.json / zero_shot.json into `splits` rows
OPTIONAL_ARRAYS = ("rgb", "depth")


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

    def params(self, arrays: list[str]) -> dict[str, Any]:
        """JSON-able unit params: everything a worker needs to import the video without the split's JSON."""
        return {"kind": "video", "video_name": self.video_name, "images": self.images, "masks": self.masks,
                "segments": [[segment, obj, category] for segment, (obj, category) in sorted(self.segments.items())],
                "arrays": arrays}

    @classmethod
    def from_params(cls, params: dict[str, Any], source: Path) -> "ReleaseVideo":
        """The video back from `params` (inside the worker)."""
        return cls(parse_video_name(params["video_name"], source), params["video_name"], params["images"],
                   params["masks"], {int(s): (int(o), int(c)) for s, o, c in params["segments"]})


@dataclass
class ImportSummary:
    """What an import did (returned to the CLI for its summary); unit lists name videos only."""

    run_root: Path
    report: StageReport
    imported: list[str] = field(default_factory=list)
    up_to_date: list[str] = field(default_factory=list)
    failed: list[UnitOutcome] = field(default_factory=list)  # every failed unit (videos and scenes)
    frames: int = 0
    absent_arrays: set[str] = field(default_factory=set)
    seconds: float = 0.0


def import_release(root: Path, split: str, run: RunFolder, embodiment: str = DEFAULT_EMBODIMENT, force: bool = False,
                   address: str | None = None, on_start: Callable[[StagePlan], None] | None = None,
                   on_unit: ProgressCallback | None = None, executor: ExecutorName = "auto") -> ImportSummary:
    """Read `<root>/<split>` of an MVPd release into the run folder `run_root` (created when new).

    Videos are imported in parallel as Ray tasks; a video that fails is recorded in the run's status
    (with its one-line message) and leaves nothing behind, while the others are imported.

    Args:
        root: the MVPd root (holds `<split>/panoptic_<split>.json`).
        split: the split folder to read; every video of the run belongs to it.
        run_root: the run folder to create or update.
        embodiment: embodiment name the videos are stored under (`videos/<embodiment>/...`).
        force: re-import units whose marker says they are up to date.
        address: Ray cluster address (a local Ray when None).
        on_start, on_unit: progress callbacks of `run_stage` (the plan; each finished unit's outcome).
        executor: where units run ("auto": in-process while the split is small, else Ray; "local"; "ray").
    """
    started = time.monotonic()
    paths = SplitPaths(Path(root).expanduser().resolve(), split)
    data = read_json(paths.annotations, f"{split}/panoptic_{split}.json")
    videos = read_release_videos(data, paths.annotations)
    width, height = _frame_size(paths, videos[0])
    job = release_job(paths, embodiment, videos, width, height)
    _open_run(run, job)
    stage = MvpdImporter(job, videos)
    plans: list[StagePlan] = []

    def start(plan: StagePlan) -> None:
        plans.append(plan)
        if on_start is not None:
            on_start(plan)

    with run.locked():
        report = run_stage(stage, run, force=force, address=address, on_start=start, on_unit=on_unit, executor=executor)
    return _summary(run, {v.video_name for v in videos}, plans[0], report, time.monotonic() - started)


def _summary(run: RunFolder, video_names: set[str], plan: StagePlan, report: StageReport,
             seconds: float) -> ImportSummary:
    markers = run.markers(STAGE)
    imported = [o.unit for o in report.outcomes if not o.failed and o.unit in video_names]
    return ImportSummary(
        run.root, report, imported, [u for u in plan.up_to_date if u in video_names], report.failed,
        frames=sum(markers[u].rows.get("frames", 0) for u in imported if u in markers),
        absent_arrays={a for u in imported if u in markers for a in markers[u].info.get("absent_arrays", [])},
        seconds=seconds,
    )


# ------------------------------------------------------------------------------------ the stage


class MvpdImporter(Stage):
    """The `import` stage: one unit per video of the split (Zarr store + tables), one per scene (objects).

    The job is the imported run's (`release_job`): `scenes.mvpd` names the release root and split,
    its single embodiment the camera. Pass `videos` when the driver has already read the split's JSON.
    """

    name = STAGE
    datasets = ("videos", "frames", "frame_stats", "segments", "objects", "splits", "zero_shot_instances")

    def __init__(self, job: Job, videos: list[ReleaseVideo] | None = None):
        super().__init__(job)
        source = job.scenes.mvpd
        if source is None:
            raise MvpdImportError(f"job {job.name}: has no scenes.mvpd source; the import stage reads an MVPd "
                                  "release (mvpd import-mvpd ROOT --split S RUN)")
        self.paths = SplitPaths(Path(source.root), source.split)
        self._videos = videos

    def __getstate__(self) -> dict[str, Any]:
        # The stage is shipped to every worker: leave the (possibly large) parsed JSON in the driver.
        return {**self.__dict__, "_videos": None}

    @property
    def videos(self) -> list[ReleaseVideo]:
        """The split's videos, read from its panoptic JSON once per driver."""
        if self._videos is None:
            data = read_json(self.paths.annotations, f"{self.paths.split}/panoptic_{self.paths.split}.json")
            self._videos = read_release_videos(data, self.paths.annotations)
        return self._videos

    @property
    def embodiment(self) -> Embodiment:
        """The camera the videos are stored under (an imported job has exactly one)."""
        return self.job.embodiments[0]

    def units(self, run: RunFolder) -> list[Unit]:
        """One unit per video (id = video name), one per scene (id = scene id), sorted by id."""
        videos = [Unit(v.video_name, v.params(_present_arrays(self.paths, v.video_name))) for v in self.videos]
        scenes = [Unit(scene, {"kind": "objects", "scene_id": scene, "objects": objects})
                  for scene, objects in scene_objects(self.videos).items()]
        clash = sorted({u.id for u in videos} & {u.id for u in scenes})
        if clash:
            raise MvpdFormatError(f"{self.paths.annotations}: {clash[0]} is both a video name and a scene id; "
                                  "rename the scene")
        # The split files (empty_videos.json, zero_shot.json) -> the run's `splits` flags, one unit.
        files = [self.paths.folder / name for name in (EMPTY_VIDEOS, ZERO_SHOT)]
        flags = Unit(SPLIT_FLAGS_UNIT, {"kind": "split", "files": [f.read_text() if f.is_file() else "" for f in files],
                                        "videos": sorted(v.video_name for v in self.videos)})
        return sorted([*videos, *scenes, flags], key=lambda u: u.id)

    def settings(self) -> dict[str, Any]:
        """What every unit's output depends on besides its params: the camera, the shard size, the source."""
        assert self.job.scenes.mvpd is not None
        return {"embodiment": self.embodiment.model_dump(mode="json"),
                "frames_per_shard": self.job.render.frames_per_shard,
                "source": self.job.scenes.mvpd.model_dump(mode="json")}

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        """Stage one video's store and table parts, or one scene's objects part."""
        if unit.params["kind"] == "split":
            rows, instances = read_split_flags(self.paths.folder, self.paths.split, unit.params["videos"])
            context.write_table("splits", _table("splits", [{**r, "embodiment": self.embodiment.name} for r in rows]))
            context.write_table("zero_shot_instances", _table("zero_shot_instances", instances))
            return UnitResult(info={"rejected": sum(not r["accepted"] for r in rows)})
        if unit.params["kind"] == "objects":
            rows = [_object_row(unit.params["scene_id"], obj, category) for obj, category in unit.params["objects"]]
            context.write_table("objects", _table("objects", rows))
            context.log.info("scene %s: %s objects", unit.params["scene_id"], len(rows))
            return UnitResult()
        video = ReleaseVideo.from_params(unit.params, self.paths.annotations)
        arrays = list(unit.params["arrays"])
        absent = [a for a in OPTIONAL_ARRAYS if a not in arrays]
        context.log.info("video %s: %s frames from %s; absent arrays: %s", video.video_name, len(video.images),
                         self.paths.folder, absent or "none")
        sensor = self.embodiment.sensor
        VideoImporter(self.paths, video, self.embodiment, self.job.render.frames_per_shard,
                      (sensor.width, sensor.height), arrays).write(context)
        return UnitResult(info={"absent_arrays": absent})


def scene_objects(videos: list[ReleaseVideo]) -> dict[str, list[list[int]]]:
    """Scene id -> sorted [object id, category] of every (scene, colour) the split's videos show."""
    by_scene: dict[str, dict[int, Counter]] = defaultdict(lambda: defaultdict(Counter))
    for video in videos:
        for object_id, category in video.segments.values():
            by_scene[video.name.scene_id][object_id][category] += 1
    return {scene: [[object_id, _category(scene, object_id, counts)] for object_id, counts in sorted(objects.items())]
            for scene, objects in sorted(by_scene.items())}


def _category(scene: str, object_id: int, counts: Counter) -> int:
    # Videos of one scene should agree on an object's category; if not, the most frequent (then lowest) wins.
    category = min(counts, key=lambda c: (-counts[c], c))
    if len(counts) > 1:
        log.warning("scene %s object %06x has categories %s in different videos; using %s", scene, object_id,
                    dict(counts), category)
    return category


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
    return ReleaseVideo(parse_video_name(name, source), name, images, masks, segments)


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


def _open_run(run: RunFolder, job: Job) -> None:
    """Create the run, or reopen one that holds the same import (anything else is refused)."""
    try:
        run.prepared()
    except RunFolderError as error:
        raise MvpdImportError(str(error)) from None
    if (run.root / JOB_FILE).is_file():
        existing = run.job()
        if existing.hash() != job.hash():
            raise MvpdImportError(
                f"{run.location}: holds another job ({existing.name}, hash {existing.hash()}); import into a new folder"
            )
        return
    run.save_job(job)


# ----------------------------------------------------------------------------------- one video


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
        self.labels = DenseLabels.from_categories({obj: category for obj, category in video.segments.values()})
        fx, fy, cx, cy = embodiment.sensor.intrinsics()
        self.intrinsics = {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "width": self.width, "height": self.height}

    def write(self, context: UnitContext) -> None:
        """Stage `videos/<embodiment>/<name>.zarr` and the parts of videos, frames, frame_stats, segments."""
        poses = [pose_from_mvpd(i["camera_position"], i["camera_rotation"]) for i in self.video.images]
        relative = f"videos/{self.embodiment.name}/{self.video.video_name}.zarr"
        store = context.staged_path(relative)
        writer = VideoWriter(store, len(poses), self.width, self.height, self._attributes(poses),
                             frames_per_shard=self.frames_per_shard)
        segments, stats = [], []
        for frame in range(len(poses)):
            ids, rgb, depth = self._read_frame(frame)
            writer.append(rgb=rgb, depth=depth, panoptic=ids)
            found = frame_segments(ids, self.labels)
            segments.extend(self._segment_rows(frame, found))
            stats.append(self._stats_row(frame, found, depth))
        writer.close()
        tables = {
            "videos": [self._video_row(relative, _folder_bytes(store))],
            "frames": [self._frame_row(frame, pose) for frame, pose in enumerate(poses)],
            "frame_stats": stats,
            "segments": segments,
        }
        for dataset, rows in tables.items():
            context.write_table(dataset, _table(dataset, rows))

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
            "absent_arrays": [a for a in OPTIONAL_ARRAYS if a not in self.arrays],
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
        unique, inverse = unique_with_inverse(segment_ids)
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

    def _video_row(self, store: str, size: int) -> dict[str, Any]:
        name = self.video.name
        return {
            **self._key(), "scene_id": name.scene_id, "trajectory": name.trajectory, "height_m": name.height_m,
            "illumination": "ambient", "sensor_model": self.embodiment.sensor.model, "frames": len(self.video.images),
            "width": self.width, "height": self.height, **{k: self.intrinsics[k] for k in ("fx", "fy", "cx", "cy")},
            "exposure": float("nan"), "store_path": store, "bytes": size, "render_seconds": 0.0,
        }

    def _frame_row(self, frame: int, pose: np.ndarray) -> dict[str, Any]:
        qw, qx, qy, qz = matrix_to_quaternion(pose[:3, :3])
        px, py, pz = pose[:3, 3]
        return {**self._key(), "frame": frame, "px": px, "py": py, "pz": pz, "qw": qw, "qx": qx, "qy": qy, "qz": qz}

    def _segment_rows(self, frame: int, found: FrameSegments) -> list[dict[str, Any]]:
        rows = []
        for k, object_id in enumerate(found.object_ids):
            x0, y0, x1, y1 = (int(v) for v in found.boxes[k])
            rows.append({**self._key(), "frame": frame, "object_id": int(object_id),
                         "category": int(found.categories[k]), "area": int(found.areas[k]),
                         "x0": x0, "y0": y0, "x1": x1, "y1": y1})
        return rows

    def _stats_row(self, frame: int, found: FrameSegments, depth: np.ndarray) -> dict[str, Any]:
        return {**self._key(), "frame": frame, "render_seconds": 0.0, "void_fraction": found.void_pixels / depth.size,
                "visible_objects": len(found.object_ids), "valid_depth_fraction": float(np.mean(depth > 0))}


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



def _object_row(scene: str, object_id: int, category: int) -> dict[str, Any]:
    """An objects row from MVPd's instance entries: the split files carry no raw names or geometry."""
    nan = float("nan")
    return {
        "scene_id": scene, "object_id": object_id, "raw_name": "", "mpcat40_index": category,
        "mpcat40_name": categories()[category].name if category in categories() else "void",
        "is_stuff": category in STUFF_CATEGORIES, "region": -1, "triangles": 0,
        "min_x": nan, "min_y": nan, "min_z": nan, "max_x": nan, "max_y": nan, "max_z": nan, "surface_area": nan,
    }
