"""Reading a run's videos for training and analysis: lazy arrays, metadata, frame and clip iterators.

    from pipeline import load_video
    video = load_video("runs/demo", "proc-000000.0000000003.0000001000")
    rgb = video.rgb[10]                       # (H, W, 3) uint8, read on demand (one Zarr chunk)
    for item in iter_clips("runs/demo", clip_len=8, stride=4): ...

No torch dependency: iterators yield dicts of numpy arrays. `TorchVideoDataset` exists only when torch is
importable (it wraps the same clip index).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from pipeline.io.zarr_video import open_video
from pipeline.lazy_import import lazy_module
from pipeline.store.markers import Marker
from pipeline.store.names import is_plain_name
from pipeline.store.run_folder import RunFolder, as_run

zarr = lazy_module("zarr")  # loaded on first use (see pipeline.io.zarr_video)

PIXEL_ARRAYS = ("rgb", "depth", "panoptic")


class VideoNotFoundError(LookupError):
    """A video name (or embodiment) that the run does not hold; the message lists what it does hold."""


class VideoDamagedError(VideoNotFoundError):
    """A stored video whose files are not as its unit's marker says; `mvpd rerun` repairs it."""


def _split_videos(run: RunFolder, split: str | None) -> set[tuple[str, str]] | None:
    """Accepted videos of `split` (None when no split is asked); raises when the run has no split output."""
    if split is None:
        return None
    from pipeline.split.selection import accepted_videos

    accepted = accepted_videos(run, split)
    if accepted is None:
        raise VideoNotFoundError(f"{run.location}: the run has no split (no `splits` table); add a `split:` section "
                                 "to the job and run `mvpd submit` again, or omit split=")
    return set(accepted)


@dataclass
class LoadedVideo:
    """One stored video: lazy Zarr arrays (index them to read) and its metadata.

    Attributes:
        embodiment, name: the video's key in the run.
        rgb, depth, panoptic: (T, H, W, 3) uint8, (T, H, W) uint16 mm, (T, H, W) uint32 ids; lazy.
        depth_clean: the ideal depth when the sensor model made `depth` noisy, else None.
        poses: (T, 4, 4) float64 camera-to-world (OpenCV camera axes).
        intrinsics: fx, fy, cx, cy, width, height (pixel centres at u + 0.5).
        categories: object id -> mpcat40 index of the objects seen in the video.
        raw_names: object id -> raw name (from the run's `objects` table; empty without it).
        attributes: every Zarr attribute of the store.
    """

    embodiment: str
    name: str
    path: Path
    rgb: zarr.Array
    depth: zarr.Array
    panoptic: zarr.Array
    depth_clean: zarr.Array | None
    poses: np.ndarray
    intrinsics: dict[str, float]
    categories: dict[int, int]
    raw_names: dict[int, str] = field(default_factory=dict)
    attributes: dict[str, Any] = field(default_factory=dict)

    @property
    def frames(self) -> int:
        """Number of frames T."""
        return int(self.panoptic.shape[0])

    def clip(self, start: int, length: int, arrays: Sequence[str] = PIXEL_ARRAYS) -> dict[str, Any]:
        """Frames [start, start + length) as numpy arrays, with their poses and the video's key."""
        if start < 0 or length < 1 or start + length > self.frames:
            raise IndexError(f"{self.name}: clip [{start}, {start + length}) outside 0..{self.frames}")
        item: dict[str, Any] = {name: np.asarray(getattr(self, name)[start:start + length]) for name in arrays}
        item.update(embodiment=self.embodiment, video_name=self.name, start=start,
                    frame=np.arange(start, start + length), poses=self.poses[start:start + length],
                    intrinsics=self.intrinsics)
        return item

    def frame(self, index: int, arrays: Sequence[str] = PIXEL_ARRAYS) -> dict[str, Any]:
        """One frame as numpy arrays (no leading time axis), with its pose."""
        item = self.clip(index, 1, arrays)
        for name in (*arrays, "poses"):
            item[name] = item[name][0]
        item["frame"] = index
        return item


def list_videos(run: Any) -> list[tuple[str, str]]:
    """(embodiment, video_name) of every rendered video of a run, sorted (from its `videos` table)."""
    table = as_run(run).read("videos")
    return sorted(zip(table.column("embodiment").to_pylist(), table.column("video_name").to_pylist()))


# The committing unit's (stage, marker) of one video by embodiment, as looked up once per `load_video`
# (resolving the embodiment and opening the store ask the same; on a store each ask is a listing and GETs).
_Found = dict[str, "tuple[str, Marker] | None"]


def _resolve_embodiment(run: RunFolder, name: str, embodiment: str | None, found_markers: _Found) -> str:
    """The embodiment of the stored video `name`. Only a plain name (letters, digits, `_`, `-`, inner dots)
    is looked up, so `../x`, `e/v` or an absolute name finds nothing and nothing outside the run is touched."""
    root = run.location
    hint = f"`mvpd query {root} \"select embodiment, video_name from videos\"` lists them"
    found = _video_embodiments(run, name, embodiment, found_markers)
    if embodiment is not None:
        if embodiment not in found:
            raise VideoNotFoundError(f"{root}: no video {name!r} of embodiment {embodiment!r}; {hint}")
        return embodiment
    if not found:
        raise VideoNotFoundError(f"{root}: no rendered video named {name!r}; {hint}")
    if len(found) > 1:
        raise VideoNotFoundError(f"{root}: video {name!r} exists for embodiments {', '.join(found)}; pass embodiment= (CLI: --embodiment)")
    return found[0]


def _video_embodiments(run: RunFolder, name: str, embodiment: str | None, found_markers: _Found) -> list[str]:
    """Embodiments (all, or just `embodiment`) holding a store for video `name`, without listing the videos
    (a run holds 18,000): on local disk one stat per embodiment; on object storage the committing unit's
    marker (a GET each) of the job's embodiments. Names that are not plain never reach a file system."""
    if not (is_plain_name(name) and (embodiment is None or is_plain_name(embodiment))):
        return []
    if run.store is not None:
        candidates = [embodiment] if embodiment is not None else [e.name for e in run.job().embodiments]
        return [e for e in candidates if _video_marker(run, e, name, found_markers) is not None]
    videos = run.root / "videos"
    if not videos.is_dir():
        return []
    candidates = [embodiment] if embodiment is not None else sorted(f.name for f in videos.iterdir() if f.is_dir())
    return [e for e in candidates if (videos / e / f"{name}.zarr").is_dir()]


def _video_marker(run: RunFolder, embodiment: str, name: str, found_markers: _Found) -> tuple[str, Marker] | None:
    """The stage and marker of the unit that committed video `embodiment/name` (render's unit ids, import's)."""
    if embodiment in found_markers:
        return found_markers[embodiment]
    store = f"videos/{embodiment}/{name}.zarr"
    found_markers[embodiment] = None
    for stage in run.stages_writing("videos"):
        for unit in (f"{embodiment}.{name}", name):
            marker = run.marker(stage, unit)
            if marker is not None and store in marker.outputs:
                found_markers[embodiment] = stage, marker
                return found_markers[embodiment]
    return None


def video_locations(run: Any) -> dict[tuple[str, str], str]:
    """(embodiment, video_name) -> where each video's Zarr store is read: on local disk its `store_path`
    in the run; on object storage its URL, from the markers of the stages that wrote videos (the `keys`
    of its files; no listing of the bucket)."""
    run = as_run(run)
    if run.store is None:
        table = run.read("videos", warn=False).select(["embodiment", "video_name", "store_path"]).to_pylist()
        return {(r["embodiment"], r["video_name"]): str(run.root / r["store_path"]) for r in table}
    found = {}
    for stage in run.stages_writing("videos"):
        for marker in run.markers(stage).values():
            for output in marker.outputs:
                parts = output.split("/")
                if len(parts) == 3 and parts[0] == "videos" and parts[2].endswith(".zarr"):
                    found[(parts[1], parts[2][: -len(".zarr")])] = run.committed_location(marker, output)
    return found


def _committed_store(run: RunFolder, embodiment: str, name: str, found_markers: _Found) -> str:
    """Where video `embodiment/name` is read (its local path or its URL on the store); refuses a video
    whose committing unit's files are damaged (a lost shard would read as zeros)."""
    relative = f"videos/{embodiment}/{name}.zarr"
    found = _video_marker(run, embodiment, name, found_markers)
    if found is None:
        return str(run.root / relative)  # a store written outside the commit protocol (an old run): as it is
    stage, marker = found
    damage = run.check_files(marker)
    if damage:
        where = run.location
        raise VideoDamagedError(f"{where}: video {embodiment}/{name} is damaged ({damage[0].line()}); "
                                f"`mvpd status {where}` lists damage, `mvpd rerun {where} --stage {stage}` repairs it")
    return run.committed_location(marker, relative)


def _object_names(run: RunFolder, scene_id: str) -> tuple[dict[int, int], dict[int, str]]:
    """Categories and raw names of a scene's objects from the run's `objects` table ({} without it)."""
    import pyarrow as pa

    from pipeline.store.datasets import dataset_parts
    from pipeline.store.tables import spec

    schema = spec("objects").schema
    tables = [run.read_part(part, schema, filters=[("scene_id", "=", scene_id)],
                            columns=["object_id", "mpcat40_index", "raw_name"]) for part in dataset_parts(run, "objects")]
    if not tables:
        return {}, {}
    table = pa.concat_tables(tables)
    ids = table.column("object_id").to_pylist()
    return (dict(zip(ids, table.column("mpcat40_index").to_pylist())),
            dict(zip(ids, table.column("raw_name").to_pylist())))


def load_video(run: Any, name: str, embodiment: str | None = None, split: str | None = None) -> LoadedVideo:
    """Open one video of a run lazily. `run` is a RunFolder or a path; `embodiment` is needed only when
    several embodiments rendered a video of that name; with `split`, a video the split rejected (empty,
    or zero-shot in train) or that is in another split is not found."""
    run = as_run(run)
    root = run.location
    found_markers: _Found = {}
    embodiment = _resolve_embodiment(run, name, embodiment, found_markers)
    accepted = _split_videos(run, split)
    if accepted is not None and (embodiment, name) not in accepted:
        raise VideoNotFoundError(f"{root}: video {embodiment}/{name} is not an accepted video of split {split!r} "
                                 f"(`mvpd query {root} \"select * from splits where video_name = '{name}'\"` says why)")
    video = open_video(_committed_store(run, embodiment, name, found_markers))
    attributes = video.attrs
    categories = {int(k): int(v) for k, v in attributes.get("object_categories", {}).items()}
    table_categories, raw_names = _object_names(run, str(attributes.get("scene_id", "")))
    for object_id in categories:  # the run's objects table is the reference when present
        categories[object_id] = int(table_categories.get(object_id, categories[object_id]))
    return LoadedVideo(
        embodiment=embodiment, name=name, path=video.path, rgb=video.rgb, depth=video.depth, panoptic=video.panoptic,
        depth_clean=video.group["depth_clean"] if "depth_clean" in video.group else None,  # type: ignore[arg-type]
        poses=video.poses(), intrinsics=video.intrinsics(), categories=categories,
        raw_names={k: raw_names[k] for k in categories if k in raw_names}, attributes=attributes,
    )


def clip_index(run: Any, clip_len: int, stride: int | None = None,
               videos: Sequence[tuple[str, str]] | None = None, split: str | None = None) -> list[tuple[str, str, int]]:
    """(embodiment, video_name, start) of every clip of `clip_len` frames, starts every `stride` frames.

    Clips never cross videos; a video shorter than `clip_len` gives none. Deterministic order. With
    `split`, only the split's accepted videos (rejected ones are skipped, as the authors' loader does).
    """
    if clip_len < 1:
        raise ValueError(f"clip_len must be >= 1, got {clip_len}")
    stride = stride or clip_len
    run = as_run(run)
    table = run.read("videos")
    frames = {(e, n): f for e, n, f in zip(table.column("embodiment").to_pylist(),
                                             table.column("video_name").to_pylist(), table.column("frames").to_pylist())}
    keys = sorted(frames) if videos is None else list(videos)
    accepted = _split_videos(run, split)
    if accepted is not None:
        keys = [key for key in keys if key in accepted]
    return [(e, n, start) for e, n in keys for start in range(0, frames[(e, n)] - clip_len + 1, stride)]


def iter_clips(run: Any, clip_len: int, stride: int | None = None, videos: Sequence[tuple[str, str]] | None = None,
               arrays: Sequence[str] = PIXEL_ARRAYS, split: str | None = None) -> Iterator[dict[str, Any]]:
    """Yield clips (dicts of numpy arrays with a leading time axis, poses and keys) of a run's videos
    (with `split`: of that split's accepted videos only)."""
    run = as_run(run)  # resolved once, not once per video
    opened: dict[tuple[str, str], LoadedVideo] = {}
    for embodiment, name, start in clip_index(run, clip_len, stride, videos, split):
        if (embodiment, name) not in opened:
            opened.clear()  # one open video at a time: memory stays flat over a whole run
            opened[(embodiment, name)] = load_video(run, name, embodiment)
        yield opened[(embodiment, name)].clip(start, clip_len, arrays)


def iter_frames(run: Any, videos: Sequence[tuple[str, str]] | None = None,
                arrays: Sequence[str] = PIXEL_ARRAYS) -> Iterator[dict[str, Any]]:
    """Yield every frame of a run's videos (or of `videos`), one dict of numpy arrays per frame."""
    for clip in iter_clips(run, 1, 1, videos, arrays):
        for name in (*arrays, "poses"):
            clip[name] = clip[name][0]
        clip["frame"] = int(clip["start"])
        yield clip


def _torch_dataset_class() -> type:
    """Build `TorchVideoDataset` (a map-style Dataset over `clip_index`); raises ImportError without torch."""
    try:
        import torch
        from torch.utils.data import Dataset
    except ImportError as error:
        raise ImportError(f"TorchVideoDataset needs torch ({error}); install torch, or use iter_clips") from None

    class TorchVideoDataset(Dataset):  # type: ignore[misc, valid-type]
        """Clips of a run as torch tensors: rgb (T, 3, H, W) uint8, depth (T, H, W) int32 mm, panoptic (T, H, W) int64."""

        def __init__(self, run: Any, clip_len: int, stride: int | None = None,
                     videos: Sequence[tuple[str, str]] | None = None, split: str | None = None):
            self.run = as_run(run)
            self.index = clip_index(self.run, clip_len, stride, videos, split)
            self.clip_len = clip_len

        def __len__(self) -> int:
            return len(self.index)

        def __getitem__(self, item: int) -> dict[str, Any]:
            embodiment, name, start = self.index[item]
            clip = load_video(self.run, name, embodiment).clip(start, self.clip_len)
            return {"rgb": torch.from_numpy(clip["rgb"]).permute(0, 3, 1, 2),
                    # torch has no uint16 / uint32 arithmetic: widen to signed types that hold every value.
                    "depth": torch.from_numpy(clip["depth"].astype(np.int32)),
                    "panoptic": torch.from_numpy(clip["panoptic"].astype(np.int64)),
                    "poses": torch.from_numpy(clip["poses"]), "video_name": name, "embodiment": embodiment,
                    "start": start}

    return TorchVideoDataset


def __getattr__(name: str) -> Any:
    # `TorchVideoDataset` is built on first use, so importing this module never imports torch.
    if name == "TorchVideoDataset":
        cls = _torch_dataset_class()
        globals()[name] = cls
        return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
