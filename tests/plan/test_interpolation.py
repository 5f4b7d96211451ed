"""Floor path -> frames: at most 0.05 m or 0.5 degrees per frame, as MVPd moves its camera."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.plan.interpolation import InterpolationError, frame_count, interpolate, wrap_angle

STEP, TURN = 0.05, math.radians(0.5)


def test_l_shaped_path_has_hand_counted_frames():
    waypoints = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.5]])
    trajectory = interpolate(waypoints, STEP, TURN)
    # 1 start frame + 20 moves (1.0 / 0.05) + 180 turn frames (90 / 0.5) + 10 moves (0.5 / 0.05)
    assert trajectory.frame_count == 1 + 20 + 180 + 10 == frame_count(waypoints, STEP, TURN)
    assert trajectory.length == pytest.approx(1.5)
    assert np.allclose(trajectory.positions[0], [0, 0]) and np.allclose(trajectory.positions[-1], [1.0, 0.5])
    assert trajectory.headings[0] == pytest.approx(0.0)  # starts facing the first segment
    assert trajectory.headings[-1] == pytest.approx(math.pi / 2)


def test_every_frame_moves_at_most_5_cm_or_turns_at_most_half_a_degree_never_both():
    rng = np.random.default_rng(0)
    waypoints = np.cumsum(rng.uniform(-2, 2, size=(8, 2)), axis=0)
    trajectory = interpolate(waypoints, STEP, TURN)
    moves = np.linalg.norm(np.diff(trajectory.positions, axis=0), axis=1)
    turns = np.abs(wrap_angle(np.diff(trajectory.headings)))
    assert moves.max() <= STEP + 1e-12
    assert turns.max() <= TURN + 1e-12
    assert not np.any((moves > 1e-12) & (turns > 1e-12))  # straight moves at a fixed heading, turns in place


def test_turns_take_the_short_way_round():
    waypoints = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.01]])  # almost a U-turn to the left
    trajectory = interpolate(waypoints, STEP, TURN)
    turns = wrap_angle(np.diff(trajectory.headings))
    assert np.all(turns >= -1e-12)  # never turns right the long way


def test_a_path_needs_two_distinct_points():
    with pytest.raises(InterpolationError, match="two distinct points"):
        interpolate(np.array([[1.0, 1.0], [1.0, 1.0]]), STEP, TURN)
