"""Statistics of the dataset a run holds: the numbers the MVPd paper reports (scenes, videos, frames,
masks, object instances), per embodiment and per category, and a picture of their distributions.

Every number is one DuckDB aggregate over the run's Parquet datasets (the `segments` table has one row
per mask: 162 M rows at MVPd scale), so nothing is loaded into Python row by row.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.io.query import connect
from pipeline.lazy_import import lazy_module
from pipeline.store.names import replaced
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.categories import categories

duckdb = lazy_module("duckdb")  # loaded on first use (see pipeline.io.query)

REQUIRED = ("videos", "frame_stats", "segments")

PER_EMBODIMENT = """
with per_video as (
    select embodiment, video_name, count(*) as masks, count(distinct object_id) as objects
    from segments group by all
), per_frame as (
    select embodiment, avg(visible_objects) as objects_per_frame, avg(void_fraction) as void_fraction
    from frame_stats group by all
)
select v.embodiment, count(distinct v.scene_id) as scenes, count(*) as videos, sum(v.frames) as frames,
       avg(v.frames) as frames_per_video, coalesce(sum(p.masks), 0) as masks,
       avg(p.objects) as objects_per_video, any_value(f.objects_per_frame) as objects_per_frame,
       any_value(f.void_fraction) as void_fraction, sum(v.bytes) / 1e9 as gigabytes
from videos v
left join per_video p using (embodiment, video_name)
left join per_frame f using (embodiment)
group by v.embodiment order by v.embodiment
"""

# Object instances are (scene, object id) pairs: the same id in two scenes is two objects.
INSTANCES = """
select count(distinct (v.scene_id, s.object_id)) from segments s join videos v using (embodiment, video_name)
"""

PER_CATEGORY = """
select s.category, count(*) as masks, count(distinct (v.scene_id, s.object_id)) as instances
from segments s join videos v using (embodiment, video_name)
group by 1 order by masks desc, s.category
"""


# Per split (all embodiments): what the split stage kept and why it rejected the rest.
PER_SPLIT = """
with per_video as (select embodiment, video_name, count(*) as masks from segments group by all)
select s.split, count(*) as videos, sum(v.frames) as frames, coalesce(sum(p.masks), 0) as masks,
       count(*) filter (where s.empty) as rejected_empty,
       count(*) filter (where s.zero_shot_rejected) as rejected_zero_shot,
       count(*) filter (where s.accepted) as accepted
from splits s join videos v using (embodiment, video_name)
left join per_video p using (embodiment, video_name)
group by s.split order by case s.split when 'train' then 0 when 'val' then 1 when 'test' then 2 else 3 end, s.split
"""

CLUSTERS = "select cluster, size, training_videos, unseen, example_names from zero_shot_clusters order by rank"

SPLIT_ROWS = {  # per-split statistic -> label
    "videos": "videos", "frames": "frames", "masks": "masks", "rejected_empty": "rejected empty",
    "rejected_zero_shot": "rejected zero-shot", "accepted": "accepted",
}


class StatsError(ValueError):
    """The run has nothing to describe yet."""


@dataclass
class DatasetStats:
    """Per embodiment rows (column -> value), object instances over the run, per category rows."""

    per_embodiment: list[dict[str, object]]
    instances: int
    per_category: list[dict[str, object]]
    per_split: list[dict[str, object]] = field(default_factory=list)
    clusters: list[dict[str, object]] = field(default_factory=list)
    comparison: dict[str, object] = field(default_factory=dict)


def dataset_stats(run: RunFolder) -> DatasetStats:
    """The statistics of every rendered (or imported) video of `run`."""
    connection = _connection(run)
    category_names = {index: category.name for index, category in categories().items()}
    per_category = [{**row, "name": category_names.get(int(row["category"]), "?")}
                    for row in _rows(connection, PER_CATEGORY)]
    datasets = set(run.datasets())
    found = DatasetStats(_rows(connection, PER_EMBODIMENT), int(connection.sql(INSTANCES).fetchall()[0][0]), per_category,
                         _rows(connection, PER_SPLIT) if "splits" in datasets else [],
                         _rows(connection, CLUSTERS) if "zero_shot_clusters" in datasets else [])
    found.comparison = comparison_row(run, found)
    return found


def comparison_row(run: RunFolder, stats: DatasetStats) -> dict[str, object]:
    """The run as a row of the paper's dataset comparison table (MVPd's: indoor, RGB-D, yes, 18,000 videos,
    6.06 M images, objects per video, 40 classes, 3 stuff, yes, yes)."""
    job = run.job()
    stuff = {1, 2, 17}  # wall, floor, ceiling
    present = {int(row["category"]) for row in stats.per_category if int(row["category"]) > 0}
    videos = sum(int(r["videos"]) for r in stats.per_embodiment)
    objects = [float(r["objects_per_video"]) * int(r["videos"]) for r in stats.per_embodiment if r["objects_per_video"] is not None]
    return {
        "dataset": run.root.name, "setting": "indoor", "modality": "RGB-D", "camera_pose": "yes",
        "videos": videos, "images": sum(int(r["frames"]) for r in stats.per_embodiment),
        "objects_per_video": sum(objects) / videos if videos else 0.0,
        "classes": len(present - stuff), "stuff": len(present & stuff),
        "unseen_split": "yes" if any(c["unseen"] for c in stats.clusters) else "no",
        # The same floor path seen from several heights is the paper's sensor-placement control.
        "sensor_placement_control": "yes" if any(len(e.placements) > 1 for e in job.embodiments) else "no",
    }


COMPARISON_COLUMNS = {  # key -> header of the paper's comparison table
    "dataset": "dataset", "setting": "setting", "modality": "modality", "camera_pose": "camera pose",
    "videos": "videos", "images": "images", "objects_per_video": "objects / video", "classes": "classes",
    "stuff": "stuff", "unseen_split": "unseen split", "sensor_placement_control": "sensor placement control",
}


def write_stats_picture(run: RunFolder, stats: DatasetStats, out: Path, top: int = 30) -> Path:
    """A PNG of four panels: masks per category (the `top` most frequent), frames per video, visible
    objects per frame and void fraction per frame (one line per embodiment)."""
    import matplotlib

    matplotlib.use("Agg")  # files only, never a window
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    connection = _connection(run)
    rows = 3 if stats.clusters else 2
    figure = plt.figure(figsize=(14, 4.5 * rows), constrained_layout=True)
    grid = figure.add_gridspec(rows, 2)
    axes = np.array([[figure.add_subplot(grid[r, c]) for c in range(2)] for r in range(2)])
    if stats.clusters:
        draw_cluster_histogram(figure.add_subplot(grid[2, :]), stats.clusters)
    shown = stats.per_category[:top]
    colours = {index: tuple(c / 255 for c in category.rgb) for index, category in categories().items()}
    axes[0, 0].bar([row["name"] for row in shown], [row["masks"] for row in shown],
                   color=[colours.get(int(row["category"]), (0.5, 0.5, 0.5)) for row in shown], edgecolor="black")
    axes[0, 0].set_yscale("log")
    # Names slanted and anchored at their right end, so long category names never run into each other.
    plt.setp(axes[0, 0].get_xticklabels(), rotation=60, ha="right", rotation_mode="anchor", fontsize=8)
    axes[0, 0].set_xlabel("mpcat40 category")
    axes[0, 0].set_ylabel("masks (log scale)")
    axes[0, 0].set_title(f"masks per category (top {len(shown)} of {len(stats.per_category)})")
    histograms = [  # (axis, SQL, title, x label, y label, whole-number values)
        (axes[0, 1], "select embodiment, frames as value, count(*) from videos group by all", "frames per video",
         "frames in the video", "videos", True),
        (axes[1, 0], "select embodiment, visible_objects, count(*) from frame_stats group by all",
         "objects visible per frame", "objects visible in the frame", "frames", True),
        (axes[1, 1], "select embodiment, round(void_fraction, 2), count(*) from frame_stats group by all",
         "void fraction per frame", "fraction of the frame's pixels that are void", "frames", False),
    ]
    for axis, sql, title, x_label, y_label, whole in histograms:
        series = _series(connection, sql)
        low = min(min(values) for _, values, _ in series)
        high = max(max(values) for _, values, _ in series)
        bins = _bins(low, high, whole)
        for number, (embodiment, values, counts) in enumerate(series):
            # Histograms of (value, count) pairs DuckDB already counted; dashes keep identical ones visible.
            axis.hist(values, bins=bins, weights=counts, histtype="step", linewidth=2,
                      linestyle=("-", "--", ":", "-.")[number % 4], label=embodiment)
        axis.set_title(title)
        axis.set_xlabel(x_label)
        axis.set_ylabel(y_label)
        axis.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts are whole numbers
        if whole:
            axis.xaxis.set_major_locator(MaxNLocator(integer=True))
        axis.legend()
    figure.suptitle(f"{run.root.name}: {sum(r['videos'] for r in stats.per_embodiment)} videos, "
                    f"{sum(r['frames'] for r in stats.per_embodiment)} frames, "
                    f"{sum(r['masks'] for r in stats.per_embodiment)} masks, {stats.instances} object instances")
    out.parent.mkdir(parents=True, exist_ok=True)
    with replaced(out) as partial:  # never a half-written picture under the real name, never a shared file
        figure.savefig(partial, dpi=90, format="png")
    plt.close(figure)
    return out


def draw_cluster_histogram(axis: "object", clusters: list[dict[str, object]]) -> None:
    """Training videos per zero-shot cluster (least seen first), unseen clusters hatched red, labelled by examples."""
    labels = [", ".join(list(c["example_names"])[:2]) for c in clusters]  # type: ignore[call-overload]
    counts = [int(c["training_videos"]) for c in clusters]  # type: ignore[call-overload]
    colours = ["#d62728" if c["unseen"] else "#1f77b4" for c in clusters]
    # A bar of height 0 is invisible, hatching and all: a cluster no training video shows is drawn as a
    # dashed, unfilled stub of 4 % of the tallest bar, so it is seen; every bar says its count, so the stub
    # still reads as 0 beside a shorter bar of 1.
    stub = 0.04 * max(max(counts), 1)
    bars = axis.bar(range(len(clusters)), [count or stub for count in counts], color=colours, edgecolor="black")  # type: ignore[attr-defined]
    for bar, cluster, count, colour in zip(bars, clusters, counts, colours):
        if cluster["unseen"]:
            bar.set_hatch("//")
        if count == 0:
            bar.set(fill=False, edgecolor=colour, linestyle="--")
    axis.bar_label(bars, [str(count) for count in counts], fontsize=8)  # type: ignore[attr-defined]
    axis.set_xticks(range(len(clusters)), labels, rotation=35, ha="right", fontsize=8)  # type: ignore[attr-defined]
    axis.set_ylabel("training videos")  # type: ignore[attr-defined]
    axis.yaxis.get_major_locator().set_params(integer=True)  # type: ignore[attr-defined]
    unseen = sum(bool(c["unseen"]) for c in clusters)
    axis.set_title(f"zero-shot clusters: training videos showing any of their names ({unseen} unseen, hatched red)")  # type: ignore[attr-defined]


def _bins(low: float, high: float, whole: bool) -> np.ndarray:
    """20 equal bins over [low, high]; for whole numbers over a short range, one bin per value centred on it."""
    if whole and high - low <= 40:
        return np.arange(low, high + 2) - 0.5
    return np.linspace(low, high if high > low else low + 1, 21)


def _connection(run: RunFolder) -> duckdb.DuckDBPyConnection:
    missing = [name for name in REQUIRED if name not in run.datasets()]
    if missing:
        raise StatsError(f"{run.root}: no {', '.join(missing)} yet; render (mvpd rerun {run.root} --stage render) "
                         "or import (mvpd import-mvpd) videos first")
    return connect(run)


def _rows(connection: duckdb.DuckDBPyConnection, sql: str) -> list[dict[str, object]]:
    relation = connection.sql(sql)
    return [dict(zip(relation.columns, row)) for row in relation.fetchall()]


def _series(connection: duckdb.DuckDBPyConnection, sql: str) -> list[tuple[str, list, list]]:
    """(embodiment, sorted values, counts) of a `select embodiment, value, count` query."""
    points: dict[str, list[tuple]] = {}
    for embodiment, value, count in connection.sql(sql).fetchall():
        points.setdefault(embodiment, []).append((value, count))
    return [(name, *map(list, zip(*sorted(pairs)))) for name, pairs in sorted(points.items())]
