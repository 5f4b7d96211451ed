"""The split, as two stages after `render`: `screen` then `split`. Reads Parquet only, never pixels.

Our executor runs a stage's units in parallel with no order between them, so no unit reads another
unit of its own stage:

- `screen` (`VideoScreener`) has independent units: `empty.<embodiment>` (the empty-video filter:
  per video the void pixels of its worst frame, from render's `frame_stats.void_fraction`, which is
  the panoptic-0 pixel count over the frame size) and `zero-shot` (cluster names, rank clusters,
  list the unseen instances and the videos showing them). Each unit's config hash holds only what it
  depends on (`unit_hash`): changing the encoder reruns `zero-shot`, not the empty filter.
- `split` (`SplitAssigner`) has one unit per split name. Each recomputes the scene split (a cheap
  deterministic function, `scenes.py`) and joins `screen`'s tables into `splits` rows. Its units'
  params carry the config hashes of `screen`'s markers, so any change upstream reruns these joins.

Validation that needs the run (scene counts, lists naming unknown scenes, too few names for the
clusters) happens in `units()`, in the driver, before any unit of either stage runs: the error is one
line naming the field, and no split is written.
"""

from __future__ import annotations

from collections import defaultdict
from typing import TYPE_CHECKING, Any

import pyarrow as pa
import pyarrow.compute as pc

from pipeline.config import SPLIT_NAMES, ConfigError, Job, SplitConfig, config_hash
from pipeline.io.tables import dataset_parts, to_table
from pipeline.runtime.executor import StageOrderError
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.split.scenes import assign_scenes, train_and_pool
from pipeline.split.zero_shot import Instance, Video, ZeroShotError, ZeroShotSplitter

if TYPE_CHECKING:
    import duckdb

    from pipeline.store.markers import Marker
    from pipeline.store.run_folder import RunFolder

ZERO_SHOT_UNIT = "zero-shot"
EMPTY_PREFIX = "empty."


class SplitInputError(ConfigError):
    """The run lacks what the split reads; the message names the table and the command that makes it."""


class ScreenNotDoneError(StageOrderError):
    """`split` was asked to run before `screen` finished (its failures, if any, are the news)."""


def _split_config(job: Job) -> SplitConfig:
    assert job.split is not None
    return job.split


def _fingerprint(markers: dict[str, "Marker"], prefix: str = "") -> str:
    """Hash of the config hashes of an upstream stage's committed units (whose ids start with `prefix`)."""
    return config_hash(sorted((unit, m.config_hash, m.code_version) for unit, m in markers.items() if unit.startswith(prefix)))


def _connect(run: "RunFolder", *datasets: str) -> "duckdb.DuckDBPyConnection":
    """DuckDB over the marker-trusted parts of `datasets` (the same confined connection as `mvpd query`)."""
    from pipeline.io.query import connect

    for dataset in datasets:
        if not dataset_parts(run, dataset):
            raise SplitInputError(f"{run.location}/{dataset}: no rows; run the stage that writes {dataset} first (mvpd status RUN)")
    return connect(run, only=datasets)


class VideoScreener(Stage):
    """Screens videos and names: the empty-video filter per embodiment and the zero-shot clustering."""

    name = "screen"
    after = ("render",)
    datasets = ("video_void", "zero_shot_clusters", "zero_shot_instances", "zero_shot_videos")

    def units(self, run: "RunFolder") -> list[Unit]:
        """`zero-shot` and one `empty.<embodiment>` per rendered embodiment (none when the job has no split)."""
        if self.job.split is None:
            return []
        scenes = run.read("scenes").column("scene_id").to_pylist()
        train, pool = train_and_pool(scenes, self.job.split.scenes, self.job.seed)  # raises on a bad scene split
        self._check_names(run, set(train) | set(pool))
        embodiments = sorted(set(run.read("videos").column("embodiment").to_pylist()))
        rendered = run.markers("render")  # read once: 18,000 files at MVPd scale
        units = [Unit(f"{EMPTY_PREFIX}{e}", {"embodiment": e, "render": _fingerprint(rendered, f"{e}.")})
                 for e in embodiments]
        units.append(Unit(ZERO_SHOT_UNIT, {"shard": _fingerprint(run.markers("shard")), "render": _fingerprint(rendered)}))
        return sorted(units, key=lambda u: u.id)

    def _check_names(self, run: "RunFolder", scenes: set[str]) -> None:
        config = _split_config(self.job).zero_shot
        names = {row["raw_name"] for row in _clustered_objects(run, config.categories) if row["scene_id"] in scenes}
        if len(names) < config.clusters:
            raise ZeroShotError(f"split.zero_shot.clusters: {config.clusters} clusters but the run's scenes hold only "
                                f"{len(names)} unique names in categories {config.categories}; lower clusters")

    def unit_hash(self, unit: Unit) -> str:
        """Only what the unit depends on: the threshold for the empty filter; scenes and zero-shot settings for zero-shot."""
        split = _split_config(self.job)
        if unit.id == ZERO_SHOT_UNIT:
            settings: dict[str, Any] = {"seed": self.job.seed, "scenes": split.scenes.model_dump(mode="json"),
                                        "zero_shot": split.zero_shot.model_dump(mode="json")}
        else:
            settings = {"empty_threshold": split.empty_threshold}
        return config_hash({"stage": self.name, "settings": settings, "params": unit.params})

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        if unit.id == ZERO_SHOT_UNIT:
            return self._zero_shot(context)
        return self._empty(unit.params["embodiment"], context)

    # ------------------------------------------------------------------------- empty filter
    def _empty(self, embodiment: str, context: UnitContext) -> UnitResult:
        """Per video, the worst frame's void pixels; empty when above the threshold (the authors' `>`)."""
        run = context.run
        threshold = _split_config(self.job).empty_threshold
        query = """
            select v.embodiment, v.video_name, v.scene_id, count(f.frame)::int as frames,
                   round(max(f.void_fraction) * v.width * v.height)::bigint as max_void_pixels,
                   (v.width * v.height)::bigint as pixels
            from videos v join frame_stats f using (embodiment, video_name)
            where v.embodiment = $embodiment
            group by v.embodiment, v.video_name, v.scene_id, v.width, v.height order by v.video_name"""
        table = _connect(run, "videos", "frame_stats").sql(query, params={"embodiment": embodiment}).to_arrow_table()
        empty = [void > threshold * pixels for void, pixels in
                 zip(table.column("max_void_pixels").to_pylist(), table.column("pixels").to_pylist())]
        table = table.append_column("empty", pa.array(empty, pa.bool_()))
        context.write_table("video_void", to_table("video_void", table.to_pydict()))
        context.log.info("%s: %d of %d videos empty (threshold %s)", embodiment, sum(empty), len(empty), threshold)
        return UnitResult(info={"videos": len(empty), "empty": sum(empty)})

    # ---------------------------------------------------------------------------- zero-shot
    def _zero_shot(self, context: UnitContext) -> UnitResult:
        run = context.run
        split = _split_config(self.job)
        scenes = run.read("scenes").column("scene_id").to_pylist()
        train, pool = train_and_pool(scenes, split.scenes, self.job.seed)
        clustered = set(train) | set(pool)
        instances = [Instance(r["scene_id"], int(r["object_id"]), r["raw_name"])
                     for r in _clustered_objects(run, split.zero_shot.categories) if r["scene_id"] in clustered]
        videos_of = _videos_of_instances(run, split.zero_shot.categories)
        outcome = ZeroShotSplitter(split.zero_shot).split(instances, videos_of, set(train))
        context.write_table("zero_shot_clusters", to_table("zero_shot_clusters", outcome.clusters))
        rows = [{"scene_id": i.scene_id, "object_id": i.object_id, "color": _color(i.object_id), "raw_name": i.raw_name,
                 "cluster": outcome.cluster_of_name[i.raw_name], "unseen": outcome.is_unseen(i.raw_name)}
                for i in sorted(instances, key=lambda i: (i.scene_id, i.object_id))]
        context.write_table("zero_shot_instances", to_table("zero_shot_instances", rows))
        unseen_per_video: dict[tuple[Video, str], int] = defaultdict(int)
        for row in rows:
            if row["unseen"]:
                for video in videos_of.get((row["scene_id"], row["object_id"]), ()):
                    unseen_per_video[(video, row["scene_id"])] += 1
        video_rows = [{"embodiment": e, "video_name": v, "scene_id": s, "unseen_instances": n}
                      for ((e, v), s), n in sorted(unseen_per_video.items())]
        context.write_table("zero_shot_videos", to_table("zero_shot_videos", video_rows))
        context.log.info("%d names in %d clusters (%s); unseen clusters %s; %d videos show unseen instances",
                         len(outcome.cluster_of_name), split.zero_shot.clusters, outcome.encoder,
                         sorted(outcome.unseen_clusters), len(video_rows))
        return UnitResult(info={"names": len(outcome.cluster_of_name), "unseen_clusters": sorted(outcome.unseen_clusters)})


def _clustered_objects(run: "RunFolder", categories: list[int]) -> list[dict[str, Any]]:
    objects = run.read("objects").select(["scene_id", "object_id", "raw_name", "mpcat40_index"])
    keep = pc.is_in(objects.column("mpcat40_index"), pa.array(categories, pa.int16()))
    return objects.filter(keep).to_pylist()


def _videos_of_instances(run: "RunFolder", categories: list[int]) -> dict[tuple[str, int], set[Video]]:
    """(scene, object) -> the videos in which it covers a pixel of some frame (from `segments`)."""
    query = f"""
        select distinct v.scene_id, s.object_id, s.embodiment, s.video_name
        from segments s join videos v using (embodiment, video_name)
        where s.category in ({", ".join(str(int(c)) for c in categories)})"""
    table = _connect(run, "segments", "videos").sql(query).to_arrow_table()
    videos_of: dict[tuple[str, int], set[Video]] = defaultdict(set)
    columns = [table.column(c).to_pylist() for c in ("scene_id", "object_id", "embodiment", "video_name")]
    for scene, object_id, embodiment, video in zip(*columns):
        videos_of[(scene, int(object_id))].add((embodiment, video))
    return videos_of


def _color(object_id: int) -> list[int]:
    """The semantic colour of an object id 0xRRGGBB (HM3DSem's convention, what zero_shot.json names)."""
    return [(object_id >> 16) & 255, (object_id >> 8) & 255, object_id & 255]


class SplitAssigner(Stage):
    """Assigns every video to train / val / test by its scene and writes its flags (`splits`), one unit per split."""

    name = "split"
    # Reads `screen`'s tables; listed after `render` so a job without a `split:` section (no screen units) runs.
    after = ("render",)
    datasets = ("splits",)

    def units(self, run: "RunFolder") -> list[Unit]:
        """One unit per split name; params carry `screen`'s marker hashes (so upstream changes rerun the joins)."""
        if self.job.split is None:
            return []
        screened = run.markers("screen")
        if ZERO_SHOT_UNIT not in screened:
            raise ScreenNotDoneError(f"{run.location}: the screen stage's zero-shot unit has not finished; see `mvpd status` "
                                  "and run `mvpd rerun RUN --stage screen`")
        upstream = _fingerprint(screened)
        return [Unit(name, {"split": name, "screen": upstream}) for name in sorted(SPLIT_NAMES)]

    def settings(self) -> dict[str, Any]:
        return {"seed": self.job.seed, "scenes": _split_config(self.job).scenes.model_dump(mode="json")}

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        run = context.run
        name = unit.params["split"]
        assignment = scene_assignment(run, self.job)
        rejected_by_zero_shot = set()
        if name == "train":
            table = run.read("zero_shot_videos")
            rejected_by_zero_shot = set(zip(table.column("embodiment").to_pylist(), table.column("video_name").to_pylist()))
        rows = []
        for video in sorted(run.read("video_void").to_pylist(), key=lambda r: (r["embodiment"], r["video_name"])):
            if assignment.get(video["scene_id"]) != name:
                continue
            zero_shot = (video["embodiment"], video["video_name"]) in rejected_by_zero_shot
            rows.append({"embodiment": video["embodiment"], "video_name": video["video_name"],
                         "scene_id": video["scene_id"], "split": name, "empty": video["empty"],
                         "zero_shot_rejected": zero_shot, "accepted": not (video["empty"] or zero_shot)})
        context.write_table("splits", to_table("splits", rows))
        accepted = sum(r["accepted"] for r in rows)
        context.log.info("%s: %d scenes, %d videos, %d accepted", name,
                         sum(s == name for s in assignment.values()), len(rows), accepted)
        return UnitResult(info={"videos": len(rows), "accepted": accepted})


def scene_assignment(run: "RunFolder", job: Job) -> dict[str, str]:
    """Scene id -> split name for this run: the scene split recomputed from `scenes` and `zero_shot_instances`."""
    split = _split_config(job)
    instances = run.read("zero_shot_instances")
    unseen = pc.filter(instances.column("scene_id"), instances.column("unseen")).to_pylist()
    return assign_scenes(run.read("scenes").column("scene_id").to_pylist(), split.scenes, job.seed, set(unseen))
