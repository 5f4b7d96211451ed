"""Look at a plan: the navigable area (one colour per island) and the floor paths over the scene's
top-down picture (`pipeline.scenes.preview.top_down_image`), written as a PNG.

Paths are drawn as polylines from their start (green dot) to their goal (red dot); islands that paths
may use are tinted one distinct colour each, islands left out (not reachable from the entrance level, or
smaller than `plan.min_island_area`) grey, so walls and furniture stay visible around them. A legend
in the top-left corner names the colours.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline.config import Body, PlanConfig
from pipeline.io.tables import spec
from pipeline.plan.navigable import (MeshQuery, NavigableArea, NavigableAreaError, compute_navigable_area, drawable_islands,
                                      island_summary)
from pipeline.plan.stage import navmesh_path
from pipeline.store.names import replaced
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.preview import top_down_image
from pipeline.scenes.scene import Scene

LOG = logging.getLogger(__name__)
# top_down_image maps world (x, z) to pixels as (p - low) * scale + MARGIN with scale = (size - 2 MARGIN) / extent.
MARGIN = 10
ISLAND_ALPHA = 0.45
PATH_COLOR = (20, 90, 230)
START_COLOR = (20, 170, 40)
GOAL_COLOR = (220, 30, 30)
DROPPED_COLOR = (150, 150, 150)
LEGEND_ISLANDS = 6  # islands listed by name in the legend; more are summed up in one line


class PlanPreviewError(ValueError):
    """A preview that cannot be drawn; the message names the run, scene or file and the fix."""


@dataclass(frozen=True)
class PlanPreview:
    """What a written preview shows."""

    path: Path
    embodiment: str
    paths: int
    islands: int
    area_m2: float


def island_colors(count: int) -> np.ndarray:
    """(count, 3) uint8 distinct, deterministic colours (golden-ratio hues)."""
    hues = (np.arange(count) * 0.618033988749895) % 1.0
    hsv = np.stack([hues * 179, np.full(count, 200), np.full(count, 230)], axis=1).astype(np.uint8)
    return cv2.cvtColor(hsv[None], cv2.COLOR_HSV2RGB)[0] if count else np.zeros((0, 3), np.uint8)


def preview_image(scene: Scene, area: NavigableArea, floor_paths: list[np.ndarray], size: int = 1024,
                  drawable: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the scene from above, islands tinted, paths ((T, 2) x, z) drawn, a legend.

    `drawable` ((islands,) bool) marks the islands paths may use; the others are grey. Default: all.
    """
    drawable = np.ones(area.island_count, bool) if drawable is None else drawable
    image = top_down_image(scene, size)
    low, high = scene.bounds()
    scale = (size - 2 * MARGIN) / max(high[0] - low[0], high[2] - low[2], 1e-6)

    def to_pixels(xz: np.ndarray) -> np.ndarray:
        """World (x, z) -> pixel (column, row) of the top-down picture."""
        return np.round((xz - low[[0, 2]]) * scale + MARGIN).astype(np.int32)

    colors = _island_palette(drawable)
    _tint_islands(image, area, to_pixels, colors)
    for points in floor_paths:
        pixels = to_pixels(points)
        cv2.polylines(image, [pixels.reshape(-1, 1, 2)], False, PATH_COLOR, 2, cv2.LINE_AA)
        cv2.circle(image, tuple(int(v) for v in pixels[0]), 5, START_COLOR, -1, cv2.LINE_AA)
        cv2.circle(image, tuple(int(v) for v in pixels[-1]), 5, GOAL_COLOR, -1, cv2.LINE_AA)
    return _draw_legend(image, area, drawable, colors, size)


def _island_palette(drawable: np.ndarray) -> np.ndarray:
    """(islands, 3) colours: distinct hues for drawable islands (in order), grey for the others."""
    colors = np.tile(np.array(DROPPED_COLOR, np.uint8), (len(drawable), 1))
    colors[drawable] = island_colors(int(drawable.sum()))
    return colors


def _draw_legend(image: np.ndarray, area: NavigableArea, drawable: np.ndarray, colors: np.ndarray,
                 left: int) -> np.ndarray:
    """The plan's key under the category legend on the right: islands (area), left-out islands, path, start, end.

    Returns the picture, taller when the key needs more rows than it has.
    """
    sizes, _ = island_summary(area)
    entries: list[tuple[tuple[int, int, int], str, str]] = []
    for shown, island in enumerate(np.flatnonzero(drawable)):
        if shown == LEGEND_ISLANDS:
            rest = np.flatnonzero(drawable)[LEGEND_ISLANDS:]
            entries.append(((255, 255, 255), "box", f"+{len(rest)} islands, {sizes[rest].sum():.1f} m2"))
            break
        entries.append((tuple(int(v) for v in colors[island]), "box", f"island {shown + 1}: {sizes[island]:.1f} m2"))
    if (~drawable).any():
        entries.append((DROPPED_COLOR, "box", f"{int((~drawable).sum())} islands left out"))
    entries += [(PATH_COLOR, "line", "path"), (START_COLOR, "dot", "start"), (GOAL_COLOR, "dot", "end")]
    background = image[-1, -1].copy()
    used = np.flatnonzero(np.any(image[:, left:] != background, axis=(1, 2)))
    top = (int(used.max()) if len(used) else 0) + 30
    needed = top + 22 * len(entries)
    if needed > image.shape[0]:
        image = np.concatenate([image, np.tile(background, (needed - image.shape[0], image.shape[1], 1))])
    for row, (color, mark, text) in enumerate(entries):
        y = top + row * 22
        if mark == "box":
            cv2.rectangle(image, (left + 10, y - 12), (left + 28, y + 4), color, -1)
        elif mark == "line":
            cv2.line(image, (left + 10, y - 4), (left + 28, y - 4), color, 2, cv2.LINE_AA)
        else:
            cv2.circle(image, (left + 19, y - 4), 5, color, -1, cv2.LINE_AA)
        cv2.putText(image, text, (left + 36, y + 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return image


def _tint_islands(image: np.ndarray, area: NavigableArea, to_pixels: Callable[[np.ndarray], np.ndarray],
                  colors: np.ndarray) -> None:
    """Blend each navigable cell's island colour into the picture (the top-most layer of each column)."""
    layers, rows, cols = area.node_cells()
    corners = to_pixels(np.stack(area.cell_centres(rows, cols), axis=1) - area.resolution / 2.0)
    far = to_pixels(np.stack(area.cell_centres(rows, cols), axis=1) + area.resolution / 2.0)
    overlay = image.copy()
    covered = np.zeros(image.shape[:2], dtype=np.uint8)
    labels = area.islands[layers, rows, cols]
    for (x0, y0), (x1, y1), label in zip(corners, far, labels):
        corner, opposite = (int(x0), int(y0)), (int(max(x0, x1 - 1)), int(max(y0, y1 - 1)))
        cv2.rectangle(overlay, corner, opposite, tuple(int(v) for v in colors[label]), -1)
        cv2.rectangle(covered, corner, opposite, 1, -1)
    mask = covered.astype(bool)
    image[mask] = (ISLAND_ALPHA * overlay[mask] + (1 - ISLAND_ALPHA) * image[mask]).astype(np.uint8)


def write_plan_preview(run: RunFolder, scene_id: str, out: Path, embodiment: str | None = None,
                       size: int = 1024) -> PlanPreview:
    """Draw the navigable area and the run's paths of one scene (one embodiment) into a PNG."""
    from pipeline.scenes.sources import load_scene_row

    job = run.job()
    name = embodiment or job.embodiments[0].name
    if name not in {e.name for e in job.embodiments}:
        raise PlanPreviewError(f"{run.root}: the job has no embodiment {name!r}; "
                               f"use one of {', '.join(e.name for e in job.embodiments)}")
    body = job.embodiment(name).body
    scenes = run.read("scenes").to_pylist()
    rows = [row for row in scenes if row["scene_id"] == scene_id]
    if not rows:
        known = ", ".join(sorted(row["scene_id"] for row in scenes)[:5]) or "none: run the shard stage first"
        raise PlanPreviewError(f"{run.root}: no scene {scene_id!r} in the scenes table (known: {known})")
    scene = load_scene_row(rows[0])
    area = _area(run, rows[0], scene, body, job.plan)
    floor_paths = run_floor_paths(run, scene_id, name)
    drawable = drawable_islands(area, body.max_step, job.plan.min_island_area, job.plan.reachable_only)
    image = preview_image(scene, area, floor_paths, size, drawable)
    out.parent.mkdir(parents=True, exist_ok=True)
    with replaced(out) as temporary:  # a new file (see `replaced`): never one shared by a hard link
        if not cv2.imwrite(str(temporary), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise PlanPreviewError(f"{out}: could not write the PNG; check the folder is writable "
                                   "and the name ends in .png")
    return PlanPreview(out, name, len(floor_paths), int(drawable.sum()), area.area_m2)


def _area(run: RunFolder, row: dict, scene: Scene, body: Body, plan: PlanConfig) -> NavigableArea:
    """The run's cached navigable area of the scene, or a fresh one when the plan stage has not run."""
    cached = run.root / navmesh_path(row, body, plan)
    if cached.is_file():
        try:
            return NavigableArea.load(cached)
        except NavigableAreaError as error:
            LOG.warning("%s; recomputing it for the preview", error)
    return compute_navigable_area(MeshQuery(scene.vertices, scene.faces), body, plan.grid_resolution,
                                  plan.require_ceiling)


def run_floor_paths(run: RunFolder, scene_id: str, embodiment: str) -> list[np.ndarray]:
    """(T, 2) floor-plane positions (x, z) of each floor path of a scene in the run, by trajectory index.

    Reads only the plan unit's own part files (`<dataset>/part-<scene_id>.<embodiment>.parquet`), not
    the whole run's frames.
    """
    unit = f"{scene_id}.{embodiment}"
    trajectories, frames = (_unit_part(run, dataset, unit) for dataset in ("trajectories", "frames"))
    first_video: dict[int, str] = {}
    for row in trajectories.select(["trajectory", "video_name"]).to_pylist():
        first_video.setdefault(row["trajectory"], row["video_name"])  # one placement per floor path is enough
    paths = []
    for _, video in sorted(first_video.items()):
        rows = frames.filter(pc.equal(frames["video_name"], video)).sort_by("frame")
        paths.append(np.stack([rows["px"].to_numpy(), rows["pz"].to_numpy()], axis=1))
    return paths


def _unit_part(run: RunFolder, dataset: str, unit: str) -> pa.Table:
    """One plan unit's committed part of a dataset, with the registered schema (empty when it wrote none);
    on object storage read in place at the key its marker names."""
    part = run.committed_part("plan", unit, dataset)
    schema = spec(dataset).schema
    return run.read_part(part, schema) if part is not None else schema.empty_table()
