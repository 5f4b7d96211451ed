"""Floor path -> frames, as MVPd moves its camera (DESIGN.md): straight moves of at most `max_step`
metres per frame at a fixed heading, then, at each corner, an in-place turn of at most `max_turn`
radians per frame toward the next segment. The camera starts facing the first segment.

Everything here is on the floor plane (x, z); heights are added by the caller (floor + placement).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Guards ceil() against values like 2.0000000000000004 steps that are really 2.
CEIL_TOLERANCE = 1e-9


class InterpolationError(ValueError):
    """A floor path that cannot be turned into frames (fewer than two distinct points)."""


@dataclass(frozen=True)
class FloorTrajectory:
    """Frames of one floor path on the floor plane.

    Attributes:
        positions: (T, 2) float64 floor-plane position (x, z) of every frame, metres.
        headings: (T,) float64 viewing direction per frame, radians; forward = (cos h, 0, sin h).
        waypoints: (W, 2) corners of the path, start and goal included.
        length: path length on the floor plane, metres.
    """

    positions: np.ndarray
    headings: np.ndarray
    waypoints: np.ndarray
    length: float

    @property
    def frame_count(self) -> int:
        """Number of frames (T)."""
        return int(len(self.positions))


def clean_waypoints(waypoints: np.ndarray) -> np.ndarray:
    """Drop consecutive duplicate points (zero-length segments have no heading)."""
    points = np.asarray(waypoints, dtype=np.float64)
    if len(points) == 0:
        return points
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9
    return points[keep]


def _segments(waypoints: np.ndarray, max_step: float,
              max_turn: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per segment: length, heading, move frames; per corner: signed turn angle and turn frames."""
    delta = np.diff(waypoints, axis=0)
    lengths = np.hypot(delta[:, 0], delta[:, 1])
    headings = np.arctan2(delta[:, 1], delta[:, 0])
    moves = np.ceil(lengths / max_step - CEIL_TOLERANCE).astype(np.int64)
    turns = wrap_angle(np.diff(headings))
    turn_frames = np.ceil(np.abs(turns) / max_turn - CEIL_TOLERANCE).astype(np.int64)
    return lengths, headings, moves, np.stack([turns, turn_frames], axis=1) if len(turns) else np.zeros((0, 2))


def frame_count(waypoints: np.ndarray, max_step: float, max_turn: float) -> int:
    """Frames the path will have (1 + moves + turns), without building them."""
    points = clean_waypoints(waypoints)
    if len(points) < 2:
        return 1
    _, _, moves, corners = _segments(points, max_step, max_turn)
    return int(1 + moves.sum() + corners[:, 1].sum())


def interpolate(waypoints: np.ndarray, max_step: float, max_turn: float) -> FloorTrajectory:
    """Frames along `waypoints` ((W, 2) floor-plane points): moves <= max_step m, turns <= max_turn rad."""
    points = clean_waypoints(waypoints)
    if len(points) < 2:
        raise InterpolationError(f"a floor path needs two distinct points, got {len(points)}")
    lengths, headings, moves, corners = _segments(points, max_step, max_turn)
    positions, angles = [points[:1]], [headings[:1]]
    for k in range(len(lengths)):
        fractions = np.arange(1, moves[k] + 1) / moves[k]
        positions.append(points[k] + fractions[:, None] * (points[k + 1] - points[k]))
        angles.append(np.full(moves[k], headings[k]))
        if k < len(corners):
            turn, count = corners[k, 0], int(corners[k, 1])
            positions.append(np.repeat(points[k + 1 : k + 2], count, axis=0))
            angles.append(headings[k] + turn * np.arange(1, count + 1) / max(count, 1))
    return FloorTrajectory(positions=np.concatenate(positions), headings=wrap_angle(np.concatenate(angles)),
                           waypoints=points, length=float(lengths.sum()))


def wrap_angle(angles: np.ndarray) -> np.ndarray:
    """Angles wrapped into [-pi, pi)."""
    return (np.asarray(angles, dtype=np.float64) + math.pi) % (2.0 * math.pi) - math.pi


def bound_steps_in_3d(trajectory: FloorTrajectory, floor_heights: np.ndarray,
                      max_step: float) -> tuple[FloorTrajectory, np.ndarray]:
    """Split every move whose 3D length (floor-plane move and floor height change) exceeds `max_step`.

    The floor-plane moves are at most `max_step`, but the floor under them may rise or fall (a 1 cm
    rug edge under a 5 cm move is a 5.1 cm step of the camera). Such a move becomes ceil(3D length /
    max_step) equal sub-moves with the height interpolated linearly, so the camera ramps over the
    edge and no frame moves more than `max_step` in 3D. Turns in place keep their frames.

    Returns the new trajectory (same waypoints and floor-plane length) and the floor height per frame.
    """
    positions, heights = trajectory.positions, np.asarray(floor_heights, np.float64)
    steps = np.sqrt(np.sum(np.diff(positions, axis=0) ** 2, axis=1) + np.diff(heights) ** 2)
    pieces = np.maximum(np.ceil(steps / max_step - CEIL_TOLERANCE).astype(np.int64), 1)
    if np.all(pieces == 1):
        return trajectory, heights
    # Frame k + 1 is reached in pieces[k] sub-moves; sub-move j of pieces p sits at fraction j / p.
    starts = np.repeat(np.arange(len(pieces)), pieces)
    fractions = (np.arange(len(starts)) - np.repeat(np.cumsum(pieces) - pieces, pieces) + 1) / np.repeat(pieces, pieces)
    new_positions = positions[starts] + fractions[:, None] * (positions[starts + 1] - positions[starts])
    new_heights = heights[starts] + fractions * (heights[starts + 1] - heights[starts])
    new_headings = trajectory.headings[starts + 1]  # a move keeps the heading of the frame it reaches
    bounded = FloorTrajectory(positions=np.concatenate([positions[:1], new_positions]),
                              headings=np.concatenate([trajectory.headings[:1], new_headings]),
                              waypoints=trajectory.waypoints, length=trajectory.length)
    return bounded, np.concatenate([heights[:1], new_heights])
