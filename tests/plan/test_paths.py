"""Floor paths: deterministic for a seed, within the frame bounds, inside the rooms."""

from __future__ import annotations

import math

import numpy as np

from pipeline.plan.interpolation import wrap_angle
from pipeline.plan.synthetic import furnished_room, two_rooms
from tests.plan.planning import SHORT_PATHS, plan_scene


def test_the_same_seed_gives_identical_paths_and_another_seed_other_paths():
    scene = two_rooms(door_width=0.9)
    _, first, _ = plan_scene(scene, seed=7)
    _, again, _ = plan_scene(scene, seed=7)
    _, other, _ = plan_scene(scene, seed=8)
    assert len(first) == len(again) == 12
    for a, b in zip(first, again):
        assert np.array_equal(a.trajectory.positions, b.trajectory.positions)
        assert np.array_equal(a.trajectory.headings, b.trajectory.headings)
        assert np.array_equal(a.floor_heights, b.floor_heights)
    assert [p.start_node for p in first] != [p.start_node for p in other]


def test_every_frame_respects_the_step_and_turn_bounds_and_the_frame_range():
    _, paths, _ = plan_scene(furnished_room())
    assert paths
    for path in paths:
        trajectory = path.trajectory
        moves = np.linalg.norm(np.diff(trajectory.positions, axis=0), axis=1)
        turns = np.abs(wrap_angle(np.diff(trajectory.headings)))
        assert moves.max() <= SHORT_PATHS.max_step + 1e-9
        assert turns.max() <= math.radians(SHORT_PATHS.max_turn) + 1e-9
        assert SHORT_PATHS.min_frames <= trajectory.frame_count <= SHORT_PATHS.max_frames
        assert np.allclose(path.floor_heights, 0.0, atol=1e-4)  # the rooms' floor is at y = 0


def test_draws_never_reuse_a_start_goal_pair():
    _, paths, report = plan_scene(two_rooms(door_width=0.9))
    pairs = [(p.start_node, p.goal_node) for p in paths]
    assert len(set(pairs)) == len(pairs)
    assert report.attempts == report.accepted + sum(report.as_dict()["rejected"].values())


def test_a_room_too_small_for_the_frame_range_reports_its_rejections():
    tight = SHORT_PATHS.model_copy(update={"min_frames": 400, "max_frames": 420, "max_attempts": 30})
    _, paths, report = plan_scene(two_rooms(door_width=None, size=2.0), plan=tight)
    assert paths == [] and report.attempts == 30
    assert report.as_dict()["rejected"].get("too_short", 0) > 0
