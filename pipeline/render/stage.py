"""The `render` stage: one unit per video of one embodiment -> a Zarr store + `videos`, `frame_stats`, `segments` rows.

Unit id `<embodiment>.<video_name>`. Inputs: the plan's `trajectories` row and `frames` rows (poses) of the
video, and its scene (`scenes` row -> `load_scene_row`). Outputs (staged, committed by the runtime):
`videos/<embodiment>/<video_name>.zarr` (schemas/zarr_video.md) and one part file per dataset.
Zarr arrays and attributes hold no timings, so two runs of one job give bit-identical stores.
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np
import pyarrow as pa

from pipeline.config import Embodiment, Job
from pipeline.io.tables import dataset_parts, spec, to_table
from pipeline.io.zarr_video import VideoWriter
from pipeline.plan.poses import pose_matrices
from pipeline.render.lighting import SurfaceColors, job_exposure
from pipeline.render.raycaster import SceneRaycaster
from pipeline.render.renderer import RenderedFrame, SceneLabels, VideoRenderer, limit_worker_threads
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.scenes.scene import Scene

if TYPE_CHECKING:
    from pathlib import Path

    from pipeline.store.run_folder import RunFolder

# Bump when the rendered pixels change for the same inputs (part of every unit's config hash).
# 2: rays and spot scale computed in another float32 order (a few pixels per frame differ by 1-2 levels).
# 3: Embree 4 packets instead of open3d's single rays (a few pixels per frame hit the other triangle of a shared edge).
# 4: camera hits from the clustered z-buffer (raster.py): again a few pixels per frame on shared edges, and
#    depth / barycentrics within float32 rounding of the ray cast's.
# 5: spot light: blocks of a surface no nearby gather point lies on gather their indirect light themselves.
RENDER_ALGORITHM_VERSION = 5
# zstd level of the Zarr arrays. Measured on the detail-1.0 house at 640x480, zstd alone per frame
# (rgb + depth + panoptic; spot / ambient light): level 1: 154 / 79 kB, 2.5 / 1.4 ms (over the 150 kB
# budget); 3: 146 / 75 kB, 3.1 / 1.7 ms; 5: 128 / 67 kB, 7.4 / 5.6 ms. Zarr's own work added ~2-3 ms, which
# VideoWriter now skips for whole shards (it writes Zarr's bytes itself). Blosc loses on 32 ambient bench frames
# (issue 31): zstd 3 82.6 kB; Blosc zstd 3 + byte shuffle 86.7 kB at 1.8x its CPU; zstd 1 + shuffle 121 kB;
# lz4 + shuffle 169 kB; zstd 1 + bit shuffle 186 kB (Blosc's blocks and shuffled bytes suit images less).
# Spot light with indirect bounces (render version 5, 16 bench poses, level 3): 179 kB (rgb 165) / 103 kB,
# over the budget; level 5 brings its rgb to 150 kB at ~2.4x the encode time (left at 3: the frame's CPU).
# Swept again per array (issue 31; 32 bench poses, zstd alone, kB / ms per frame, ambient): rgb at levels -5, 1, 2,
# 3, 4, 5: 103 / 1.03, 77.9 / 1.15, 76.9 / 1.20, 72.5 / 1.25, 72.5 / 1.32, 64.1 / 3.12; depth 10.4 / 0.17, 6.88 /
# 0.19, 6.87 / 0.20, 6.83 / 0.21; panoptic 4.85 / 0.31, 3.14 / 0.29, 3.13 / 0.30, 3.12 / 0.30. Filters lose: rgb as
# planes 97 kB / 2.1 ms; a pixel delta 67.6 kB / 2.3 ms (69.5 / 1.9 at level 1); depth delta or byte split 7.3 kB /
# 0.4-0.5 ms. Every cheaper level stores more bytes and level 3 is where the curve bends: it stays for every array.
ZSTD_LEVEL = 3


class RenderInputError(ValueError):
    """The plan's outputs for a video are missing or inconsistent; the message names the table and the fix."""


class RgbdRenderer(Stage):
    """Ray casts every planned video: RGB, planar depth (mm) and panoptic ids, stored as Zarr, indexed in Parquet."""

    name = "render"
    after = ("plan",)
    datasets = ("videos", "frame_stats", "segments")
    when_empty = "no trajectory was planned; `mvpd plan report RUN` says why for each scene"

    def __init__(self, job: Job):
        super().__init__(job)
        self.exposure = job_exposure(job)

    # ------------------------------------------------------------------------------- units
    def units(self, run: "RunFolder") -> list[Unit]:
        """One unit per row of the plan's `trajectories` table (one video of one embodiment)."""
        rows = run.read("trajectories").to_pylist()
        known = {body.name for body in self.job.embodiments}
        units = []
        for row in rows:
            if row["embodiment"] not in known:
                raise RenderInputError(f"{run.root}/trajectories: rows of embodiment {row['embodiment']!r}, which the "
                                       "job no longer has; run `mvpd rerun RUN --stage plan` first")
            embodiment = self.job.embodiment(row["embodiment"])
            units.append(Unit(f"{row['embodiment']}.{row['video_name']}", {
                "trajectory": _plain(row),
                # Only what changes pixels: a new light or sensor reruns that embodiment's videos only.
                "sensor": embodiment.sensor.model_dump(mode="json"),
                "illumination": embodiment.illumination.hashed(),
            }))
        return sorted(units, key=lambda unit: unit.id)

    def settings(self) -> dict[str, Any]:
        """Seed, storage settings, the job's exposure and the algorithm version."""
        return {"seed": self.job.seed, "render": self.job.render.model_dump(mode="json"),
                "exposure": self.exposure, "algorithm": RENDER_ALGORITHM_VERSION}

    # -------------------------------------------------------------------------------- work
    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        """Render one video, write its store and its table rows."""
        started = time.perf_counter()
        trajectory = unit.params["trajectory"]
        embodiment = self.job.embodiment(trajectory["embodiment"])
        poses = read_poses(context.run, trajectory)
        scene = self.load_scene(context.run, trajectory["scene_id"])
        renderer = _WORKER_CACHE.renderer(scene, embodiment, self.exposure, self.job.seed)
        relative = f"videos/{embodiment.name}/{trajectory['video_name']}.zarr"
        store = context.staged_path(relative)
        video = render_video(renderer, poses, store, trajectory, self.job.render.frames_per_shard, context)
        seconds = time.perf_counter() - started
        stored_bytes = directory_bytes(store)
        context.write_table("videos", to_table("videos", [_video_row(trajectory, embodiment, renderer, self.exposure,
                                                                     relative, stored_bytes, seconds)]))
        context.write_table("frame_stats", to_table("frame_stats", video["frame_stats"]))
        context.write_table("segments", to_table("segments", video["segments"]))
        context.log.info("rendered %s frames in %.2f s (%.1f fps), %.1f kB/frame", len(poses), seconds,
                         len(poses) / seconds, stored_bytes / 1000 / max(len(poses), 1))
        return UnitResult(info={"frames": len(poses), "bytes": stored_bytes})

    def load_scene(self, run: "RunFolder", scene_id: str) -> Scene:
        """The scene of a video, from the `scenes` table (cached per worker process: videos of one scene share it)."""
        key = (str(run.root), scene_id)
        if _WORKER_CACHE.key == key and _WORKER_CACHE.scene is not None:
            return _WORKER_CACHE.scene
        from pipeline.scenes.sources import load_scene_row

        rows = [r for r in run.read("scenes").to_pylist() if r["scene_id"] == scene_id]
        if not rows:
            raise RenderInputError(f"{run.root}/scenes: no row for scene {scene_id!r}; run `mvpd rerun RUN --stage shard`")
        _WORKER_CACHE.clear()  # free the previous scene and its BVH before loading the next (worker memory bound)
        _WORKER_CACHE.key, _WORKER_CACHE.scene = key, load_scene_row(rows[0])
        return _WORKER_CACHE.scene


class _WorkerCache:
    """The last scene a worker process loaded and its per-scene render tables (BVH, colours, labels).

    A Ray worker renders many videos; consecutive videos of one scene (units are sorted by scene) then
    skip the load and the BVH build (~1-2 s per 1 M triangles). One scene at a time bounds memory.
    """

    def __init__(self) -> None:
        self.key: tuple[str, str] | None = None
        self.scene: Scene | None = None
        self.parts: tuple[Scene, SceneRaycaster, SurfaceColors, SceneLabels] | None = None

    def clear(self) -> None:
        self.key = self.scene = self.parts = None

    def renderer(self, scene: Scene, embodiment: Embodiment, exposure: float, seed: int = 0) -> VideoRenderer:
        """A renderer for `scene`, reusing its BVH and lookup tables when the scene is the cached one."""
        if self.parts is None or self.parts[0] is not scene:
            self.parts = None
            self.parts = (scene, SceneRaycaster(scene), SurfaceColors(scene), SceneLabels(scene))
            limit_worker_threads(self.parts[1].threads)
        _, raycaster, colors, labels = self.parts
        return VideoRenderer(scene, embodiment, exposure, raycaster=raycaster, colors=colors, labels=labels, seed=seed)


_WORKER_CACHE = _WorkerCache()


def render_video(renderer: VideoRenderer, poses: np.ndarray, store: "Path", trajectory: Mapping[str, Any],
                 frames_per_shard: int, context: UnitContext | None = None,
                 rng_of_frame: Callable[[int], np.random.Generator] | None = None) -> dict[str, list[dict]]:
    """Render every pose into a Zarr store; returns the `frame_stats` and `segments` rows.

    Sensor noise of frame t is drawn from `context.rng("sensor", t)` (or `rng_of_frame(t)` without a context).
    """
    embodiment = renderer.embodiment
    noisy = embodiment.sensor.model != "ideal"
    arrays = ("rgb", "depth", "depth_clean", "panoptic") if noisy else ("rgb", "depth", "panoptic")
    with VideoWriter(store, len(poses), renderer.camera.width, renderer.camera.height,
                     video_attributes(renderer, poses, trajectory), arrays=arrays, frames_per_shard=frames_per_shard,
                     level=ZSTD_LEVEL, background=renderer.raycaster.threads > 1) as writer:
        key = {"embodiment": embodiment.name, "video_name": trajectory["video_name"]}
        frame_stats, segments, visible_categories = [], [], {}
        for t, pose in enumerate(poses):
            started = time.perf_counter()
            rng = None
            if noisy:
                if context is None and rng_of_frame is None:
                    raise ValueError("a noisy sensor model needs `context` or `rng_of_frame` to seed its noise")
                rng = context.rng("sensor", t) if context is not None else rng_of_frame(t)  # type: ignore[misc]
            frame = renderer.render(pose, rng)
            found = frame.segment_statistics(renderer.labels)
            writer.append(**_buffers(frame, noisy))
            frame_stats.append({**key, "frame": t, "render_seconds": time.perf_counter() - started,
                                "void_fraction": found.void_pixels / frame.panoptic.size,
                                "visible_objects": len(found.object_ids),
                                "valid_depth_fraction": float(np.count_nonzero(frame.depth)) / frame.depth.size})
            for k, object_id in enumerate(found.object_ids):
                x0, y0, x1, y1 = (int(v) for v in found.boxes[k])
                segments.append({**key, "frame": t, "object_id": int(object_id), "category": int(found.categories[k]),
                                 "area": int(found.areas[k]), "x0": x0, "y0": y0, "x1": x1, "y1": y1})
                visible_categories[int(object_id)] = int(found.categories[k])
        writer.close()
    writer.group.attrs["object_categories"] = {str(k): v for k, v in sorted(visible_categories.items())}
    return {"frame_stats": frame_stats, "segments": segments}


def _buffers(frame: RenderedFrame, noisy: bool) -> dict[str, np.ndarray]:
    buffers = {"rgb": frame.rgb, "depth": frame.depth, "panoptic": frame.panoptic}
    if noisy:
        buffers["depth_clean"] = frame.depth_clean  # type: ignore[assignment]
    return buffers


def video_attributes(renderer: VideoRenderer, poses: np.ndarray, trajectory: Mapping[str, Any]) -> dict[str, Any]:
    """Zarr attributes of a video (schemas/zarr_video.md): everything needed to use it without the run."""
    embodiment = renderer.embodiment
    attributes = {
        "video_name": trajectory["video_name"],
        "scene_id": trajectory["scene_id"],
        "trajectory": int(trajectory["trajectory"]),
        "height_m": float(trajectory["height_m"]),
        "embodiment": embodiment.model_dump(mode="json"),
        "intrinsics": renderer.camera.as_dict(),
        "illumination": illumination_label(embodiment),
        "exposure": renderer.shader.exposure if embodiment.illumination.kind == "spot" else None,
        "depth": {"unit": "mm", "near_m": embodiment.sensor.near, "far_m": embodiment.sensor.far,
                  "model": embodiment.sensor.model},
        "poses": np.asarray(poses, np.float64).tolist(),
    }
    if renderer.sensor is not None:
        attributes["depth"]["parameters"] = renderer.sensor.as_dict()
    return attributes


def illumination_label(embodiment: Embodiment) -> str:
    """'ambient' or 'spot-<watts>W' (e.g. 'spot-20W', 'spot-2.5W')."""
    light = embodiment.illumination
    if light.kind == "ambient":
        return "ambient"
    return f"spot-{light.power:g}W"


def read_poses(run: "RunFolder", trajectory: Mapping[str, Any]) -> np.ndarray:
    """(T, 4, 4) camera-to-world poses of a video (a `trajectories` row) in frame order, from the one
    `frames` part of the plan unit that wrote it (read in place on object storage)."""
    embodiment, video_name, frames = trajectory["embodiment"], trajectory["video_name"], int(trajectory["frames"])
    part = run.committed_part("plan", f"{trajectory['scene_id']}.{embodiment}", "frames")
    # Frames committed otherwise (a fixture, a tool): every trusted part, filtered.
    parts = [part] if part is not None else dataset_parts(run, "frames")
    if not parts:
        raise RenderInputError(f"{run.location}/frames: missing; run `mvpd rerun RUN --stage plan`")
    schema = spec("frames").schema
    table = pa.concat_tables([run.read_part(part, schema, filters=[("embodiment", "=", embodiment),
                                                                          ("video_name", "=", video_name)])
                              for part in parts]).sort_by("frame")
    order = table.column("frame").to_numpy()
    if len(order) != frames or not np.array_equal(order, np.arange(frames)):
        raise RenderInputError(f"{run.location}/frames: {embodiment}/{video_name} has {len(order)} frame rows, the "
                               f"trajectory says {frames} (indices must be 0..{frames - 1}); run `mvpd rerun RUN --stage plan --all`")
    return pose_matrices(table)


def directory_bytes(path: "Path | str") -> int:
    """Total size in bytes of the files under `path`."""
    return sum(os.path.getsize(os.path.join(folder, name)) for folder, _, names in os.walk(path) for name in names)


def _video_row(trajectory: Mapping[str, Any], embodiment: Embodiment, renderer: VideoRenderer, exposure: float,
               store_path: str, stored_bytes: int, seconds: float) -> dict[str, Any]:
    camera = renderer.camera
    return {
        "embodiment": embodiment.name, "video_name": trajectory["video_name"], "scene_id": trajectory["scene_id"],
        "trajectory": int(trajectory["trajectory"]), "height_m": float(trajectory["height_m"]),
        "illumination": illumination_label(embodiment), "sensor_model": embodiment.sensor.model,
        "frames": int(trajectory["frames"]), "width": camera.width, "height": camera.height,
        "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
        "exposure": exposure if embodiment.illumination.kind == "spot" else None,
        "store_path": store_path, "bytes": stored_bytes, "render_seconds": seconds,
    }


def _plain(row: Mapping[str, Any]) -> dict[str, Any]:
    """A table row as JSON-able Python values (numpy / Arrow scalars converted)."""
    return {key: (value.item() if isinstance(value, np.generic) else value) for key, value in row.items()}

