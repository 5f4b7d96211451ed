"""Walks where a robot would walk (not on roofs or furniture), and the per-frame step bound in 3D."""

from __future__ import annotations

import numpy as np

from pipeline.plan.interpolation import bound_steps_in_3d, interpolate
from pipeline.plan.synthetic import CEILING, FLOOR, FURNITURE, Box, room_shell, scene_from_boxes, two_storey
from tests.plan.planning import SHORT_PATHS, plan_scene


def _storeys_with_a_flat_roof_under_a_canopy():
    """`two_storey` (ground 0 m, upper 2.8 m, roof top 5.4 m) plus a canopy 2.2 m over half the roof.

    The canopy makes the roof a floor with a ceiling, so `require_ceiling` alone keeps it navigable.
    """
    scene = two_storey()
    roof_top = float(scene.vertices[:, 1].max())
    canopy = Box((4.0, roof_top + 2.2, -0.1), (8.1, roof_top + 2.3, 4.1), CEILING)
    boxes = [Box(tuple(scene.vertices[scene.faces[scene.face_object_ids == i]].reshape(-1, 3).min(0)),
                 tuple(scene.vertices[scene.faces[scene.face_object_ids == i]].reshape(-1, 3).max(0)), o.category)
             for i, o in sorted(scene.objects.items())]
    return scene_from_boxes("roofed", boxes + [canopy]), roof_top


def test_a_flat_roof_gets_no_path_unless_every_island_is_asked_for() -> None:
    scene, roof_top = _storeys_with_a_flat_roof_under_a_canopy()
    plan = SHORT_PATHS.model_copy(update={"trajectories_per_scene": 30, "max_attempts": 300, "max_frames": 900})
    _, everywhere, _ = plan_scene(scene, plan=plan.model_copy(update={"reachable_only": False}))
    assert any(p.floor_heights.min() > roof_top - 0.01 for p in everywhere), "the roof is walkable under the canopy"
    area, paths, _ = plan_scene(scene, plan=plan)
    assert paths
    assert all(p.floor_heights.max() < roof_top - 1.0 for p in paths)  # ground floor and upper storey only
    assert any(np.ptp(p.floor_heights) > 2.7 for p in paths)  # the stairs still lead upstairs


def test_furniture_tops_and_tiny_islands_get_no_path() -> None:
    boxes = room_shell(0.0, 5.0, 0.0, 5.0, ceiling=2.6) + [
        Box((1.0, 0.0, 1.0), (3.0, 0.5, 2.6), FURNITURE),  # a bed: 2 x 1.6 m top, 2.1 m under the ceiling
    ]
    plan = SHORT_PATHS.model_copy(update={"min_frames": 4, "trajectories_per_scene": 40, "max_attempts": 400})
    _, everywhere, _ = plan_scene(scene_from_boxes("bed", boxes), plan=plan.model_copy(update={"reachable_only": False}))
    assert any(p.floor_heights.min() > 0.4 for p in everywhere)
    _, paths, _ = plan_scene(scene_from_boxes("bed", boxes), plan=plan)
    assert paths and all(p.floor_heights.max() < 0.01 for p in paths)


def test_a_rug_edge_does_not_make_the_camera_step_more_than_max_step_in_3d() -> None:
    step = SHORT_PATHS.max_step
    trajectory = interpolate(np.array([[0.0, 0.0], [2.0, 0.0]]), step, np.radians(0.5))
    floor = np.where(trajectory.positions[:, 0] > 1.0, 0.01, 0.0)  # a 1 cm rug from x = 1 m on
    moves = np.sqrt(np.sum(np.diff(trajectory.positions, axis=0) ** 2, axis=1) + np.diff(floor) ** 2)
    assert moves.max() > step  # what the camera did before: a 5.1 cm step onto the rug
    bounded, heights = bound_steps_in_3d(trajectory, floor, step)
    moves = np.sqrt(np.sum(np.diff(bounded.positions, axis=0) ** 2, axis=1) + np.diff(heights) ** 2)
    assert moves.max() <= step + 1e-12
    assert bounded.frame_count == trajectory.frame_count + 1  # one extra frame ramps over the edge
    assert np.array_equal(bounded.positions[[0, -1]], trajectory.positions[[0, -1]])


def test_planned_paths_over_a_rug_keep_the_3d_bound() -> None:
    boxes = room_shell(0.0, 5.0, 0.0, 5.0) + [Box((1.0, 0.0, 0.5), (4.0, 0.01, 4.5), FLOOR)]  # a 1 cm rug
    _, paths, _ = plan_scene(scene_from_boxes("rug", boxes))
    crossing = [p for p in paths if np.ptp(p.floor_heights) > 0.005]
    assert crossing, "some path should cross the rug edge"
    for path in paths:
        moves = np.sqrt(np.sum(np.diff(path.trajectory.positions, axis=0) ** 2, axis=1) + np.diff(path.floor_heights) ** 2)
        assert moves.max() <= SHORT_PATHS.max_step + 1e-9
