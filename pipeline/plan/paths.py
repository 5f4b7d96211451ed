"""Floor paths on a navigable area: random start/goal pairs, shortest paths, string pulling, checks.

A floor path is drawn as MVPd does: start and goal at random on one island (never the same pair twice),
the shortest path between them, straightened by line of sight on the navigable grid, interpolated
into frames, and kept only when it has `min_frames`..`max_frames` frames and every pose keeps the
body's radius from every triangle of the mesh (checked on the mesh itself, not on the grid).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from pipeline.config import Body, PlanConfig
from pipeline.plan.interpolation import FloorTrajectory, bound_steps_in_3d, frame_count, interpolate
from pipeline.plan.navigable import MeshQuery, NavigableArea, drawable_islands, restrict_to_islands
from pipeline.plan.search import PathSearch

# Line-of-sight samples per cell: fine enough that consecutive samples are in neighbouring cells.
SAMPLES_PER_CELL = 4
# Grid paths are at most ~8 % longer than straight ones (octile moves); search a bit beyond.
GRID_DETOUR = 1.1
# First search radius: 1.5 x the straight distance + 1 m covers most detours through doorways; only
# pairs not joined within it are searched again up to the longest allowed path.
FIRST_SEARCH_FACTOR = 1.5
FIRST_SEARCH_MARGIN = 1.0
# The clearance check splits the body's axis until the uncertainty is below this, metres.
CLEARANCE_TOLERANCE = 0.005


@dataclass(frozen=True)
class FloorPath:
    """An accepted floor path: its frames and the floor height under each frame.

    Attributes:
        trajectory: frames on the floor plane (positions, headings, waypoints, length).
        floor_heights: (T,) world y of the floor under each frame, metres.
        start_node, goal_node: node ids (in `NavigableArea.node_cells()` order) of the draw.
    """

    trajectory: FloorTrajectory
    floor_heights: np.ndarray
    start_node: int
    goal_node: int


@dataclass
class DrawReport:
    """What happened to the draws of one scene (goes into the unit's marker and log)."""

    attempts: int = 0
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)

    def reject(self, reason: str) -> None:
        """Count one rejected draw under `reason` (too_short, too_long, too_close, repeated_pair, ...)."""
        self.rejected[reason] += 1

    def as_dict(self) -> dict:
        """JSON-able counts, reasons sorted (for markers and logs)."""
        return {"attempts": self.attempts, "accepted": self.accepted, "rejected": dict(sorted(self.rejected.items()))}


class FloorPathSampler:
    """Draws floor paths on one navigable area; `draw(rng, count)` is deterministic for a given rng."""

    def __init__(self, area: NavigableArea, mesh: MeshQuery, body: Body, plan: PlanConfig) -> None:
        # Paths start and end only on the islands a robot could reach (plan.reachable_only, min_island_area).
        area = restrict_to_islands(area, drawable_islands(area, body.max_step, plan.min_island_area, plan.reachable_only))
        self.area, self.mesh, self.body, self.plan = area, mesh, body, plan
        self.layers, self.rows, self.cols = area.node_cells()
        self.x, self.z = area.cell_centres(self.rows, self.cols)
        self.y = area.heights[self.layers, self.rows, self.cols].astype(np.float64)
        self.island = area.islands[self.layers, self.rows, self.cols]
        self.members = [np.flatnonzero(self.island == i) for i in range(area.island_count)]
        self.search = PathSearch(area) if len(self.layers) else None
        self.max_turn = math.radians(plan.max_turn)
        self.max_length = plan.max_frames * plan.max_step
        # Grids for line-of-sight tests, converted once (they are read thousands of times per scene).
        self.floor_grid = area.heights.astype(np.float64)
        self.island_grid = area.islands
        self.single_layer = area.heights.shape[0] == 1
        self.cells_per_metre = 1.0 / area.resolution
        self.samples_per_metre = SAMPLES_PER_CELL / area.resolution

    def draw(self, rng: np.random.Generator, count: int) -> tuple[list[FloorPath], DrawReport]:
        """Up to `count` floor paths from at most `plan.max_attempts` start/goal draws."""
        report, paths, seen = DrawReport(), [], set()
        if len(self.layers) == 0:
            return paths, report
        while len(paths) < count and report.attempts < self.plan.max_attempts:
            report.attempts += 1
            start = int(rng.integers(len(self.layers)))
            island = self.members[self.island[start]]
            goal = int(island[rng.integers(len(island))])
            if start == goal or (start, goal) in seen:
                report.reject("repeated_pair" if start != goal else "start_is_goal")
                continue
            seen.update({(start, goal), (goal, start)})
            path, reason = self._plan(start, goal)
            if path is None:
                report.reject(reason)
                continue
            paths.append(path)
        report.accepted = len(paths)
        return paths, report

    def _plan(self, start: int, goal: int) -> tuple[FloorPath | None, str]:
        """The floor path from node `start` to node `goal`, or None and why it was rejected."""
        straight = math.hypot(self.x[goal] - self.x[start], self.z[goal] - self.z[start])
        if straight > self.max_length:
            return None, "too_long"
        widest = self.max_length * GRID_DETOUR
        first = min(widest, FIRST_SEARCH_FACTOR * straight + FIRST_SEARCH_MARGIN)
        nodes = self.search.shortest_path(start, goal, (first, widest) if first < widest else (widest,))
        if nodes is None:
            return None, "too_long"
        corners = self.string_pull(nodes)
        waypoints = np.stack([self.x[corners], self.z[corners]], axis=1)
        frames = frame_count(waypoints, self.plan.max_step, self.max_turn)
        if frames < self.plan.min_frames:
            return None, "too_short"
        if frames > self.plan.max_frames:
            return None, "too_long"
        trajectory = interpolate(waypoints, self.plan.max_step, self.max_turn)
        floor = self.floor_heights(trajectory, corners)
        # The camera rides at floor + placement: the per-frame bound must hold in 3D, not only on the plan.
        trajectory, floor = bound_steps_in_3d(trajectory, floor, self.plan.max_step)
        if trajectory.frame_count > self.plan.max_frames:
            return None, "too_long"
        if not poses_clear(self.mesh, trajectory.positions, floor, self.body):
            return None, "too_close"
        return FloorPath(trajectory, floor, start, goal), ""

    def string_pull(self, nodes: np.ndarray) -> np.ndarray:
        """Corner nodes of a grid path: from each corner, the farthest path node in line of sight.

        The farthest visible node is found by doubling then bisecting, so a path of n nodes costs
        O(corners * log n) line-of-sight tests instead of O(n).
        """
        corners, i, last = [int(nodes[0])], 0, len(nodes) - 1
        while i < last:
            good, bad, step = i + 1, last + 1, 2
            while good < last:
                probe = min(i + step, last)
                if self.line_of_sight(nodes[i], nodes[probe]):
                    good, step = probe, step * 2
                else:
                    bad = probe
                    break
            while bad - good > 1:
                middle = (good + bad) // 2
                if self.line_of_sight(nodes[i], nodes[middle]):
                    good = middle
                else:
                    bad = middle
            corners.append(int(nodes[good]))
            i = good
        return np.array(corners, dtype=np.int64)

    def line_of_sight(self, a: int, b: int) -> bool:
        """True when the straight floor line from node a to node b stays on navigable cells of a's island.

        The line is sampled SAMPLES_PER_CELL times per cell; at each sample the floor layer closest to
        the height interpolated between a and b must be within `max_step` of it, and the floor may rise
        or fall by at most `max_step` between neighbouring samples (stairs are fine, a ledge is not).
        Both ends are cell centres inside the grid, so every sample is too.
        """
        area, step = self.area, self.area.max_step
        length = math.hypot(self.x[b] - self.x[a], self.z[b] - self.z[a])
        count = max(2, math.ceil(length * self.samples_per_metre) + 1)
        t = np.arange(count) * (1.0 / (count - 1))
        cols = ((self.x[a] + t * (self.x[b] - self.x[a]) - area.origin[0]) * self.cells_per_metre).astype(np.intp)
        rows = ((self.z[a] + t * (self.z[b] - self.z[a]) - area.origin[1]) * self.cells_per_metre).astype(np.intp)
        expected = self.y[a] + t * (self.y[b] - self.y[a])
        if self.single_layer:  # the common case, without the per-layer choice
            floors = self.floor_grid[0, rows, cols]
            if not np.all(self.island_grid[0, rows, cols] == self.island[a]):
                return False
            if not np.all(np.abs(floors - expected) <= step):
                return False
        else:
            layered = self.floor_grid[:, rows, cols]
            offset = np.where(self.island_grid[:, rows, cols] == self.island[a], np.abs(layered - expected), np.inf)
            best = np.argmin(offset, axis=0)
            columns = np.arange(count)
            if not np.all(offset[best, columns] <= step):
                return False
            floors = layered[best, columns]
        return bool(np.all(np.abs(np.diff(floors)) <= step))

    def floor_heights(self, trajectory: FloorTrajectory, corners: np.ndarray) -> np.ndarray:
        """World y of the floor under every frame, from a short downward ray at each frame position.

        The ray starts `max_step` above the height interpolated between the corners' floors, where the
        clearance checks guarantee free space, and falls back to that height if it hits nothing.
        """
        corner_xz = np.stack([self.x[corners], self.z[corners]], axis=1)
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(corner_xz, axis=0), axis=1))])
        positions = trajectory.positions
        travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
        expected = np.interp(travelled, along, self.y[corners])
        lift = self.body.max_step + 0.01
        origins = np.stack([positions[:, 0], expected + lift, positions[:, 1]], axis=1)
        hits = self.mesh.cast(origins, np.tile([0.0, -1.0, 0.0], (len(origins), 1)))
        reach = 2.0 * lift
        return np.where(hits <= reach, expected + lift - hits, expected)


def body_axis(body: Body) -> tuple[float, float]:
    """Heights above the floor between which the body must keep `radius` from every triangle.

    The body is modelled as a capsule of `radius` around the vertical axis from `max_step + radius`
    to `height - radius` above the floor: what lies below is climbable, what lies above is checked
    by the ceiling clearance.
    """
    low = body.max_step + body.radius
    return low, max(low, body.height - body.radius)


def poses_clear(mesh: MeshQuery, positions: np.ndarray, floor_heights: np.ndarray, body: Body) -> bool:
    """True when every pose's body axis is at least `radius` from the mesh (exact distance queries).

    The distance to a mesh changes by at most the distance moved, so a point at distance d proves
    the whole axis piece of half-length h around it clear when d >= radius + h. Pieces that are
    neither proven clear nor found too close are halved until CLEARANCE_TOLERANCE.
    """
    points = np.unique(np.round(np.column_stack([positions[:, 0], floor_heights, positions[:, 1]]), 9), axis=0)
    low, high = body_axis(body)
    centres = points[:, 1] + (low + high) / 2.0
    base = points.copy()
    half = (high - low) / 2.0
    while len(base):
        query = base.copy()
        query[:, 1] = centres
        distance = mesh.distance(query)
        if np.any(distance < body.radius):
            return False
        open_piece = distance < body.radius + half
        if not open_piece.any():
            return True
        if half < CLEARANCE_TOLERANCE:
            return False
        half /= 2.0
        base = np.repeat(base[open_piece], 2, axis=0)
        centres = np.repeat(centres[open_piece], 2) + np.tile([-half, half], int(open_piece.sum()))
    return True
