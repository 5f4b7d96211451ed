"""Export a run as a Hugging Face dataset folder (`mvpd export RUN --hf DIR`).

`datasets.load_dataset(DIR)` (and `streaming=True`) loads it with no code of ours: one row per frame,
Parquet shards per split under `data/`, the feature types and split sizes in the card's front matter
(and the shards' `huggingface` schema metadata), the run's job file beside the card.

Videos are written one at a time, a block of frames at a time, into size-bounded shards (shards.py), so
memory stays flat however many videos the run holds. The whole folder is built in a hidden staging folder
beside DIR and renamed into place at the end: DIR is absent, the previous export, or the complete new one.
Same run, same code -> the same bytes (no time or host in any file; fixed row groups).
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


from pipeline.io.huggingface.card import (DATA, JOB_COPY, LICENCE_FILE, CardFacts, SplitFacts, card_text,
                                          licence_notice)
from pipeline.io.huggingface.features import VideoFacts, dataset_features, frame_block, parquet_schema, png_bytes
from pipeline.io.huggingface.shards import ROWS_PER_GROUP, SHARD_BYTES, ShardWriter
from pipeline.io.mvpd.export import READ_BLOCK, swap_into_place
from pipeline.io.reader import LoadedVideo, load_video
from pipeline.store.run_folder import RunFolder

log = logging.getLogger(__name__)

CARD = "README.md"
# What an --hf export writes into DIR (and the CLI's `.mvpd-out` tag): --overwrite replaces only such a folder.
EXPORT_ENTRIES = {CARD, LICENCE_FILE, JOB_COPY, DATA}
# The one split of a run without a split stage: `datasets`' usual name for a lone split (`all`, the training
# exports' name, is `datasets`' keyword for the union of the splits and cannot name one).
UNSPLIT = "train"


class HfExportError(ValueError):
    """An --hf export that cannot run as asked; the message names the input and the fix."""


@dataclass(frozen=True)
class ExportedVideo:
    """One video to export and the split stage's flags for it (None without a split stage)."""

    embodiment: str
    video_name: str
    empty: bool | None = None
    zero_shot_rejected: bool | None = None
    accepted: bool | None = None


@dataclass
class HfExportSummary:
    """What an export wrote, for the CLI's summary line."""

    out: Path
    frames: dict[str, int] = field(default_factory=dict)  # split -> rows
    videos: int = 0
    shards: int = 0
    has_split: bool = True
    seconds: float = 0.0


def export_hf_dataset(run: RunFolder, out: Path, split: str | None = None, embodiment: str | None = None,
                      overwrite: bool = False, on_start: Callable[[int], None] | None = None,
                      on_video: Callable[[str], None] | None = None, rows_per_group: int = ROWS_PER_GROUP,
                      shard_bytes: int = SHARD_BYTES) -> HfExportSummary:
    """Write the run's videos as a Hugging Face dataset folder `out`.

    Args:
        run: the run folder.
        out: the dataset folder (absent, empty, or an earlier --hf export with `overwrite`).
        split: only this split of the run's split stage; without a split stage, the name of the one split
            holding every video (default `train`).
        embodiment: only this embodiment's videos (default: all; they must share one image size).
        overwrite: replace an earlier --hf export in `out`.
        on_start, on_video: progress callbacks (number of videos; each finished video's name).
        rows_per_group, shard_bytes: Parquet row group size (frames) and shard size bound (bytes).
    """
    started = time.monotonic()
    _require_datasets()
    from pipeline.split.selection import has_split

    splits = planned_splits(run, split, embodiment)
    videos_table = _videos_table(run)
    height, width = _frame_size(run, splits, videos_table)
    out = checked_target(Path(out), overwrite)
    features = dataset_features(height, width)
    schema = parquet_schema(features)
    unseen = _unseen_objects(run)
    if on_start is not None:
        on_start(sum(len(videos) for videos in splits.values()))
    staging = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    (staging / DATA).mkdir(parents=True)
    try:
        written = {}
        for name, videos in splits.items():
            written[name] = _write_split(run, staging / DATA, name, videos, videos_table, unseen, schema,
                                         rows_per_group, shard_bytes, on_video)
        facts = CardFacts(run.job(), run.job_hash(), _code_versions(run), _exporter_version(), features, written,
                          has_split(run), height, width, _scene_sources(run))
        (staging / JOB_COPY).write_text(run.job_text(), encoding="utf-8")
        (staging / CARD).write_text(card_text(facts), encoding="utf-8")
        (staging / LICENCE_FILE).write_text(licence_notice(facts), encoding="utf-8")
        swap_into_place(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    summary = HfExportSummary(out, {name: s.frames for name, s in written.items()},
                              sum(s.videos for s in written.values()),
                              sum(len(s.shards.files) for s in written.values()), facts.has_split_stage,
                              time.monotonic() - started)
    log.info("exported %s frames of %s videos to %s", sum(summary.frames.values()), summary.videos, out)
    return summary


def _require_datasets() -> None:
    try:
        import datasets  # noqa: F401
    except ImportError:
        raise HfExportError("export --hf needs the `datasets` package: pip install 'mvpd-pipeline[hf]'") from None


# ------------------------------------------------------------------------------------ what to export


def planned_splits(run: RunFolder, split: str | None, embodiment: str | None) -> dict[str, list[ExportedVideo]]:
    """split -> its videos in export order (embodiment, then name), every video of the split with its flags."""
    from pipeline.config import SPLIT_NAMES
    from pipeline.io.reader import list_videos
    from pipeline.split.selection import has_split, split_rows

    stored = list_videos(run)
    known = sorted({e for e, _ in stored})
    if embodiment is not None and embodiment not in known:
        raise HfExportError(f"{run.location}: no videos of embodiment {embodiment!r}; "
                            f"choose one of {', '.join(known) or '(none rendered)'}")
    keep = lambda key: embodiment in (None, key[0])  # noqa: E731
    if split == "all":
        raise HfExportError("--split all: `datasets` reads `all` as the union of every split; choose another name")
    if not has_split(run):
        videos = [ExportedVideo(e, n) for e, n in stored if keep((e, n))]
        planned = {split or UNSPLIT: videos}
    else:
        rows = split_rows(run)
        names = sorted({r["split"] for r in rows}, key=SPLIT_NAMES.index)
        if split is not None and split not in names:
            raise HfExportError(f"--split {split}: the run's split stage made {', '.join(names)}; choose one of them")
        stored_set = set(stored)
        planned = {}
        for name in [split] if split is not None else names:
            chosen = sorted((r for r in rows if r["split"] == name and keep((r["embodiment"], r["video_name"]))),
                            key=lambda r: (r["embodiment"], r["video_name"]))
            for row in chosen:
                if (row["embodiment"], row["video_name"]) not in stored_set:
                    raise HfExportError(f"{run.location}/splits: split {name!r} lists video {row['video_name']!r} of "
                                        f"embodiment {row['embodiment']!r}, which the run's videos table does not "
                                        "hold; rerun the split stage")
            planned[name] = [ExportedVideo(r["embodiment"], r["video_name"], bool(r["empty"]),
                                           bool(r["zero_shot_rejected"]), bool(r["accepted"])) for r in chosen]
    planned = {name: videos for name, videos in planned.items() if videos}
    if not planned:
        raise HfExportError(f"{run.location}: no videos to export; run the render stage first")
    return planned


def _videos_table(run: RunFolder) -> dict[tuple[str, str], dict[str, Any]]:
    """(embodiment, video_name) -> its `videos` row."""
    return {(r["embodiment"], r["video_name"]): r for r in run.read("videos").to_pylist()}


def _frame_size(run: RunFolder, splits: dict[str, list[ExportedVideo]],
                videos: dict[tuple[str, str], dict[str, Any]]) -> tuple[int, int]:
    """The one (height, width) of every exported video (`Array2D` has one shape per column)."""
    sizes: dict[tuple[int, int], str] = {}
    for video in (v for listed in splits.values() for v in listed):
        row = videos[(video.embodiment, video.video_name)]
        sizes.setdefault((int(row["height"]), int(row["width"])), video.embodiment)
    if len(sizes) > 1:
        seen = ", ".join(f"{e} {w}x{h}" for (h, w), e in sizes.items())
        raise HfExportError(f"{run.location}: the videos have several image sizes ({seen}); one dataset holds one "
                            "size: export one embodiment at a time with --embodiment")
    return next(iter(sizes))


def checked_target(out: Path, overwrite: bool) -> Path:
    """`out` resolved: absent, empty, or (with `overwrite`) a folder holding only what an --hf export writes."""
    out = out.expanduser().resolve()
    if out.exists() and not out.is_dir():
        raise HfExportError(f"{out}: is a file; give a folder for the dataset")
    entries = {p.name for p in out.iterdir()} if out.is_dir() else set()
    entries = {name for name in entries if not name.startswith(".mvpd")}  # the CLI's tag of its own folders
    if entries and not overwrite:
        raise HfExportError(f"{out}: exists and is not empty; choose a new folder or pass --overwrite")
    foreign = sorted(entries - EXPORT_ENTRIES)
    if foreign:
        raise HfExportError(f"{out}: holds {foreign[0]!r}, which an --hf export does not write; --overwrite replaces "
                            "only an earlier --hf export: choose a new folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    return out


def _unseen_objects(run: RunFolder) -> set[tuple[str, int]]:
    from pipeline.split.selection import has_split, zero_shot_objects

    return zero_shot_objects(run) if has_split(run) else set()


# ------------------------------------------------------------------------------------------ writing


def _write_split(run: RunFolder, folder: Path, split: str, videos: list[ExportedVideo],
                 table: dict[tuple[str, str], dict[str, Any]], unseen: set[tuple[str, int]], schema: Any,
                 rows_per_group: int, shard_bytes: int, on_video: Callable[[str], None] | None) -> SplitFacts:
    """Every frame of the split's videos, one video and one block of frames at a time, into its shards."""
    writer = ShardWriter(folder, split, schema, rows_per_group, shard_bytes)
    # PNG encoding is the export's main cost and Pillow releases the GIL while it compresses: one thread per
    # core encodes a block's images (in order, so the bytes do not depend on the threads).
    pool = ThreadPoolExecutor(len(os.sched_getaffinity(0)))
    encode = lambda images: list(pool.map(png_bytes, images))  # noqa: E731
    try:
        for entry in videos:
            video = load_video(run, entry.video_name, entry.embodiment)
            facts = _video_facts(entry, video, table[(entry.embodiment, entry.video_name)], unseen)
            poses = video.poses
            for start in range(0, video.frames, READ_BLOCK):
                stop = min(start + READ_BLOCK, video.frames)
                writer.add(frame_block(schema, facts, start, video.rgb[start:stop], video.depth[start:stop],
                                       video.panoptic[start:stop], poses[start:stop], encode))
            if on_video is not None:
                on_video(entry.video_name)
        shards = writer.finish()
    finally:
        writer.close()
        pool.shutdown(cancel_futures=True)
    accepted = None if videos[0].accepted is None else sum(bool(v.accepted) for v in videos)
    return SplitFacts(len(videos), accepted, shards.rows, shards)


def _video_facts(entry: ExportedVideo, video: LoadedVideo, row: dict[str, Any],
                 unseen: set[tuple[str, int]]) -> VideoFacts:
    ids = sorted(video.categories)
    return VideoFacts(
        video_name=entry.video_name, embodiment=entry.embodiment, scene_id=str(row["scene_id"]),
        camera_height_m=float(row["height_m"]), illumination=str(row["illumination"]),
        intrinsics={k: float(video.intrinsics[k]) for k in ("fx", "fy", "cx", "cy", "width", "height")},
        object_ids=ids, object_categories=[video.categories[i] for i in ids],
        zero_shot_object_ids=[i for i in ids if (str(row["scene_id"]), i) in unseen],
        empty=entry.empty, zero_shot_rejected=entry.zero_shot_rejected, accepted=entry.accepted)


# ---------------------------------------------------------------------------------- provenance


def _code_versions(run: RunFolder) -> list[str]:
    """The code versions (package version + source hash) in the markers of the stages that wrote the videos
    and the split: normally one; several when stages ran with different code."""
    stages = dict.fromkeys([*run.stages_writing("videos"), *run.stages_writing("splits")])
    return sorted({marker.code_version for stage in stages for marker in run.markers(stage).values()})


def _exporter_version() -> str:
    from pipeline.store.markers import code_version

    return code_version()


def _scene_sources(run: RunFolder) -> list[str]:
    """The job's scene sources by name (procedural, hm3dsem, ...), in the job's order."""
    sources = run.job().scenes
    return [name for name in type(sources).model_fields if getattr(sources, name) is not None]
