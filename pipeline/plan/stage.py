"""`PathPlanner`: the plan stage. One unit per (scene, embodiment) turns the scene into camera trajectories.

A unit computes (or reads from the run's cache) the scene's navigable area for the embodiment's body,
draws floor paths with a generator seeded by (job seed, scene, body) only, so that every embodiment
with the same body gets the same floor paths, and writes one video per (floor path, placement):
`trajectories` (one row per video, with the intrinsics) and `frames` (one pose per frame).
A scene where no path can be found is reported (status, reason and draw counts in the unit's marker
and log) and writes no rows; it never fails the unit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from pipeline.config import Body, Embodiment, PlanConfig, config_hash
from pipeline.io.tables import to_table
from pipeline.plan.navigable import FORMAT_VERSION, MeshQuery, NavigableArea, NavigableAreaError, compute_navigable_area
from pipeline.plan.paths import DrawReport, FloorPath, FloorPathSampler
from pipeline.plan.poses import level_camera_rotations, matrix_to_quaternion
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.stage import Stage, Unit, UnitContext, UnitResult
from pipeline.scenes.scene import Scene

NAVMESH_FOLDER = "navmesh"


class PathPlanner(Stage):
    """Plan stage: navigable area, floor paths and camera poses per (scene, embodiment)."""

    name = "plan"
    after = ("shard",)
    datasets = ("trajectories", "frames")

    def units(self, run: RunFolder) -> list[Unit]:
        """One unit `<scene_id>.<embodiment>` per committed scene row and embodiment of the job."""
        units = []
        for row in run.read("scenes").to_pylist():
            for embodiment in self.job.embodiments:
                units.append(Unit(id=f"{row['scene_id']}.{embodiment.name}",
                                  params={"scene": row, "embodiment": embodiment.name}))
        return sorted(units, key=lambda unit: unit.id)

    def settings(self) -> dict[str, Any]:
        """Seed, plan config and what of each embodiment shapes a trajectory (not its light)."""
        return {"seed": self.job.seed, "plan": self.job.plan.model_dump(mode="json"),
                "embodiments": {e.name: _trajectory_settings(e) for e in self.job.embodiments}}

    def load_scene(self, row: dict[str, Any]) -> Scene:
        """The scene of a `scenes` row (the shard stage's table)."""
        from pipeline.scenes.sources import load_scene_row

        return load_scene_row(row)

    def run_unit(self, unit: Unit, context: UnitContext) -> UnitResult:
        """Plan one scene for one embodiment and stage its `trajectories` and `frames` rows."""
        embodiment = self.job.embodiment(unit.params["embodiment"])
        row = unit.params["scene"]
        scene_id = str(row["scene_id"])
        scene = self.load_scene(row)
        mesh = MeshQuery(scene.vertices, scene.faces)
        area = self._navigable_area(row, mesh, embodiment.body, context)
        seed = floor_path_seed(self.job.seed, scene_id, embodiment.body)
        sampler = FloorPathSampler(area, mesh, embodiment.body, self.job.plan)
        paths, report = sampler.draw(np.random.default_rng(seed), self.job.plan.trajectories_per_scene)
        trajectories, frames = video_tables(scene_id, embodiment, paths, seed)
        context.write_table("trajectories", trajectories)
        context.write_table("frames", frames)
        status, reason = plan_status(area, report, embodiment, self.job.plan, sampler.area.island_count)
        log = context.log.warning if status != "planned" else context.log.info
        log("%s %s: %s %d of %d paths (%s)%s", scene_id, embodiment.name, status, report.accepted,
            self.job.plan.trajectories_per_scene, report.as_dict(), f": {reason}" if reason else "")
        return UnitResult(rows=context.rows_written,
                          info={"status": status, "reason": reason, "seed": seed, "draws": report.as_dict(),
                                "navigable": sampler.area.stats})

    def _navigable_area(self, row: dict[str, Any], mesh: MeshQuery, body: Body, context: UnitContext) -> NavigableArea:
        """The scene's navigable area for `body`: read from the run's cache or computed, and (re)staged.

        Staging it every time keeps it among this unit's outputs, so a rerun never deletes a cache
        file that a finished unit committed.
        """
        relative = navmesh_path(row, body, self.job.plan)
        cached = context.run.root / relative
        area = None
        if cached.is_file():
            try:
                area = NavigableArea.load(cached)
            except NavigableAreaError as error:
                context.log.warning("%s; recomputing", error)
        if area is None:
            plan = self.job.plan
            area = compute_navigable_area(mesh, body, plan.grid_resolution, plan.require_ceiling)
        area.save(context.staged_path(relative))
        return area


def _trajectory_settings(embodiment: Embodiment) -> dict[str, Any]:
    return {"body": embodiment.body.model_dump(mode="json"), "sensor": embodiment.sensor.model_dump(mode="json"),
            "placements": list(embodiment.placements)}


def navmesh_path(row: dict[str, Any], body: Body, plan: PlanConfig) -> str:
    """Run-relative cache path of a scene's navigable area: keyed by the scene row, body and grid."""
    key = config_hash({"scene": row, "body": body.model_dump(mode="json"), "resolution": plan.grid_resolution,
                       "require_ceiling": plan.require_ceiling, "format": FORMAT_VERSION})
    return f"{NAVMESH_FOLDER}/{row['scene_id']}.{key}.npz"


def floor_path_seed(job_seed: int, scene_id: str, body: Body) -> int:
    """Seed (int64) of a scene's start/goal draws: from the job seed, the scene and the body only."""
    digest = config_hash(["plan", job_seed, scene_id, body.model_dump(mode="json")])
    return int(digest, 16) & (2**63 - 1)


def video_name(scene_id: str, trajectory: int, height_m: float) -> str:
    """`<scene_id>.<trajectory:010d>.<height_mm:010d>` (DESIGN.md)."""
    return f"{scene_id}.{trajectory:010d}.{round(height_m * 1000):010d}"


def video_tables(scene_id: str, embodiment: Embodiment, paths: list[FloorPath], seed: int) -> tuple[pa.Table, pa.Table]:
    """`trajectories` and `frames` tables: one video per (floor path, placement), paths in draw order."""
    fx, fy, cx, cy = embodiment.sensor.intrinsics()
    videos: list[dict[str, Any]] = []
    columns: dict[str, list[np.ndarray]] = {k: [] for k in ("frame", "px", "py", "pz", "qw", "qx", "qy", "qz")}
    names: list[np.ndarray] = []
    for index, path in enumerate(paths):
        trajectory = path.trajectory
        quaternions = matrix_to_quaternion(level_camera_rotations(trajectory.headings))
        for height in embodiment.placements:
            name = video_name(scene_id, index, height)
            count = trajectory.frame_count
            videos.append({
                "embodiment": embodiment.name, "video_name": name, "scene_id": scene_id, "trajectory": index,
                "height_m": float(height), "frames": count, "path_length_m": trajectory.length, "seed": seed,
                "width": embodiment.sensor.width, "height": embodiment.sensor.height,
                "fx": fx, "fy": fy, "cx": cx, "cy": cy, "near": embodiment.sensor.near, "far": embodiment.sensor.far,
                "waypoints": len(trajectory.waypoints),
                "start_x": float(trajectory.waypoints[0, 0]), "start_z": float(trajectory.waypoints[0, 1]),
                "goal_x": float(trajectory.waypoints[-1, 0]), "goal_z": float(trajectory.waypoints[-1, 1]),
            })
            names.append(np.full(count, name, dtype=object))
            columns["frame"].append(np.arange(count, dtype=np.int32))
            columns["px"].append(trajectory.positions[:, 0])
            columns["py"].append(path.floor_heights + height)
            columns["pz"].append(trajectory.positions[:, 1])
            for k, key in enumerate(("qw", "qx", "qy", "qz")):
                columns[key].append(quaternions[:, k])
    frame_columns: dict[str, Any] = {"embodiment": [embodiment.name] * sum(len(n) for n in names),
                                     "video_name": np.concatenate(names).tolist() if names else []}
    for key, parts in columns.items():
        frame_columns[key] = np.concatenate(parts) if parts else np.zeros(0)
    return to_table("trajectories", videos), to_table("frames", frame_columns)


def plan_status(area: NavigableArea, report: DrawReport, embodiment: Embodiment, plan: PlanConfig,
                drawable_islands: int | None = None) -> tuple[str, str]:
    """("planned" | "partial" | "unplannable", reason): why a scene gave fewer paths than asked.

    `drawable_islands` is how many islands paths may use (after plan.reachable_only / min_island_area).
    """
    body = embodiment.body
    if area.stats.get("floor_nodes", 0) == 0:
        highest = area.stats.get("ceiling_clearance_max_m", 0.0)
        reason = (f"no walkable floor with {body.height} m clearance (body.height) under a ceiling; "
                  f"the most clearance found is {highest} m")
        if highest > 0 and max(embodiment.placements) >= highest:
            reason += f"; the camera at {max(embodiment.placements)} m would be above the ceiling"
        return "unplannable", reason
    if area.stats.get("navigable_nodes", 0) == 0:
        return "unplannable", f"the floor has no place {body.radius} m (body.radius) away from walls and ledges"
    if drawable_islands == 0:
        return "unplannable", (f"no island of at least {plan.min_island_area} m2 (plan.min_island_area) at the "
                               "entrance level; plan.reachable_only: false takes every island")
    if report.accepted == 0:
        return "unplannable", (f"no start/goal pair gave a {plan.min_frames}..{plan.max_frames}-frame "
                               f"collision-free path in {report.attempts} draws")
    if report.accepted < plan.trajectories_per_scene:
        return "partial", f"plan.max_attempts ({plan.max_attempts}) draws gave {report.accepted} paths"
    return "planned", ""
