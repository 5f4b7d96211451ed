"""Plan a box scene directly (no run folder): navigable area and floor paths, for the plan tests."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from pipeline.config import Body, PlanConfig
from pipeline.plan.navigable import MeshQuery, NavigableArea, compute_navigable_area
from pipeline.plan.paths import DrawReport, FloorPath, FloorPathSampler, body_axis
from pipeline.scenes.scene import Scene

BODY = Body(radius=0.1, height=1.5, max_step=0.2, max_slope=20.0)
# Short paths allowed, so that a small room still gives many of them.
SHORT_PATHS = PlanConfig(trajectories_per_scene=12, min_frames=20, max_frames=600, max_attempts=400)


def plan_scene(scene: Scene, body: Body = BODY, plan: PlanConfig = SHORT_PATHS,
               seed: int = 0) -> tuple[NavigableArea, list[FloorPath], DrawReport]:
    """The navigable area and up to `plan.trajectories_per_scene` floor paths of a scene."""
    mesh = MeshQuery(scene.vertices, scene.faces)
    area = compute_navigable_area(mesh, body, plan.grid_resolution)
    paths, report = FloorPathSampler(area, mesh, body, plan).draw(np.random.default_rng(seed),
                                                                   plan.trajectories_per_scene)
    return area, paths, report


def closest_approach(scene: Scene, paths: list[FloorPath], body: Body, heights: int = 45) -> float:
    """Smallest distance from any pose's body axis to any triangle, measured on the mesh itself.

    Each pose's floor point is lifted to `heights` levels spread over the body's axis (from max_step
    + radius to height - radius above the floor) and its distance to the mesh is computed exactly.
    """
    scene_query = o3d.t.geometry.RaycastingScene()
    scene_query.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                              o3d.core.Tensor(scene.faces.astype(np.uint32)))
    low, high = body_axis(body)
    closest = np.inf
    for path in paths:
        floor = np.column_stack([path.trajectory.positions[:, 0], path.floor_heights, path.trajectory.positions[:, 1]])
        points = np.repeat(floor, heights, axis=0)
        points[:, 1] += np.tile(np.linspace(low, high, heights), len(floor))
        distance = scene_query.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()
        closest = min(closest, float(distance.min()))
    return closest
