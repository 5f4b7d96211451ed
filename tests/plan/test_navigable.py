"""The navigable area on box scenes whose answer is known: walls, doorways, disconnected rooms, no floor."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.config import Body
from pipeline.plan.navigable import MeshQuery, NavigableArea, NavigableAreaError, compute_navigable_area
from pipeline.plan.synthetic import Box, FLOOR, room_shell, scene_from_boxes, two_rooms
from tests.plan.planning import BODY, closest_approach, plan_scene


def sides(points_x: np.ndarray) -> set[int]:
    """Which sides of the dividing wall at x = 0 a path visits (-1 left, +1 right)."""
    return set(np.sign(points_x[np.abs(points_x) > 1e-9]).astype(int).tolist())


def test_a_thin_wall_between_the_grid_rays_is_never_crossed():
    # 5 mm thick, centred at x = 0: the vertical rays at cell centres x = -0.025 and +0.025 both miss it.
    area, paths, _ = plan_scene(two_rooms(door_width=None, wall_thickness=0.005))
    assert area.island_count == 2
    assert len(paths) == 12
    for path in paths:
        assert len(sides(path.trajectory.positions[:, 0])) == 1


def test_a_doorway_narrower_than_the_body_is_impassable_and_a_wide_one_is_used():
    narrow, _, _ = plan_scene(two_rooms(door_width=0.18), plan=_no_paths())  # 0.18 m < 2 x 0.1 m
    assert narrow.island_count == 2
    wide, paths, _ = plan_scene(two_rooms(door_width=0.9))
    assert wide.island_count == 1
    assert any(len(sides(p.trajectory.positions[:, 0])) == 2 for p in paths)  # some path goes through the door


def test_rooms_with_no_connection_give_no_path_between_them():
    area, paths, _ = plan_scene(two_rooms(door_width=None))
    assert area.island_count == 2
    assert paths and all(len(sides(p.trajectory.positions[:, 0])) == 1 for p in paths)


def test_no_pose_comes_closer_than_the_body_radius_to_any_triangle():
    from pipeline.plan.synthetic import furnished_room

    scene = furnished_room()  # table, pillar, a 0.4 m box and a 5 mm wall stub
    _, paths, _ = plan_scene(scene)
    assert len(paths) == 12
    assert closest_approach(scene, paths, BODY) >= BODY.radius


def test_a_scene_without_walkable_floor_has_no_navigable_area():
    steep = [b for b in room_shell(0.0, 4.0, 0.0, 4.0) if b.category != FLOOR]  # walls and ceiling, no floor
    area, paths, report = plan_scene(scene_from_boxes("no-floor", steep))
    assert area.stats["floor_nodes"] == 0 and area.island_count == 0
    assert paths == [] and report.attempts == 0


def test_floor_without_anything_above_is_not_navigable():
    # An open platform: no ceiling over it (roofs and the open sky are not navigable).
    platform = scene_from_boxes("platform", [Box((0, -0.1, 0), (4, 0, 4), FLOOR)])
    area, _, _ = plan_scene(platform)
    assert area.stats["floor_nodes"] == 0
    open_sky = compute_navigable_area(MeshQuery(platform.vertices, platform.faces), BODY, 0.05, require_ceiling=False)
    assert open_sky.stats["floor_nodes"] == 80 * 80  # every cell of the 4 x 4 m top, when no ceiling is required


def test_a_low_ceiling_leaves_no_floor_for_a_tall_body():
    scene = two_rooms(door_width=0.9, ceiling=1.2)
    area = compute_navigable_area(MeshQuery(scene.vertices, scene.faces), BODY, 0.05)  # body needs 1.5 m
    assert area.stats["floor_nodes"] == 0
    assert area.stats["ceiling_clearance_max_m"] == pytest.approx(1.2, abs=1e-3)


def test_cache_round_trip_is_byte_identical(tmp_path):
    scene = two_rooms(door_width=0.9)
    area = compute_navigable_area(MeshQuery(scene.vertices, scene.faces), Body(), 0.1)
    area.save(tmp_path / "a.npz")
    again = NavigableArea.load(tmp_path / "a.npz")
    again.save(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    assert np.array_equal(again.islands, area.islands) and again.stats == area.stats


def test_damaged_cache_names_the_file(tmp_path):
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"not a zip")
    with pytest.raises(NavigableAreaError, match="broken.npz"):
        NavigableArea.load(broken)


def _no_paths():
    from tests.plan.planning import SHORT_PATHS

    return SHORT_PATHS.model_copy(update={"trajectories_per_scene": 1, "max_attempts": 1})


def test_two_storeys_joined_by_stairs_are_one_island_and_paths_climb_step_by_step():
    from pipeline.plan.synthetic import two_storey

    scene = two_storey()  # 16 steps of 0.175 m (max_step 0.2) up to an upper floor at 2.8 m
    plan = _no_paths().model_copy(update={"trajectories_per_scene": 12, "max_attempts": 100, "max_frames": 900})
    area, paths, _ = plan_scene(scene, plan=plan)
    assert area.island_count == 1 and area.heights.shape[0] == 2  # two layers: ground and upper floor
    climbing = [p for p in paths if np.ptp(p.floor_heights) > 2.7]
    assert climbing, "some path should go from one storey to the other"
    for path in climbing:
        assert np.abs(np.diff(path.floor_heights)).max() <= BODY.max_step
    assert closest_approach(scene, paths, BODY) >= BODY.radius
