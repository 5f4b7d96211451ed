"""The navigable area of a scene for a robot body: a layered (2.5D) floor grid built from ray casts.

How it is computed (numpy, scipy and open3d only; no navmesh library):
1. Floor candidates: one vertical ray per grid cell lists every surface in the column (by peeling:
   cast, step past the hit, cast again). A surface is a
   floor when it faces up within `max_slope`, has a surface above it (a ceiling: roofs and the open
   sky are not navigable) and at least `body.height` of clearance below that surface. A column may
   hold several floors (storeys, a table top): each is a node of layer 0, 1, ... counted bottom-up, so
   two-storey houses with stairs are handled.
2. Adjacency: a node links to the node of each of the 8 neighbouring columns whose floor is within
   `max_step` of its own. Horizontal rays between the two cell centres at several heights of the
   body's band (from `max_step` to `height` above the floor) catch walls thinner than a cell that the
   vertical rays fall beside.
3. Erosion: nodes missing a neighbour or with a blocked link are boundary nodes (walls, furniture,
   ledges, the grid edge); every node within ceil(radius / resolution) + 1 grid steps of a boundary
   node is removed, which keeps every point of a remaining cell at least `radius` from what the rays
   found. `paths.py` checks the final poses against the mesh itself.
4. Islands: connected components of the remaining nodes.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.config import Body
from pipeline.lazy_import import lazy_module

o3d = lazy_module("open3d")  # loaded when a MeshQuery is built, not when `mvpd status` lists plan units

FORMAT_VERSION = 1
MAX_GRID_CELLS = 40_000_000
# Hits closer than this along one ray are one surface (shared triangle edges are reported twice).
SAME_SURFACE_M = 1e-3
# The 8 neighbour directions (row, column); the first four are each link's canonical direction.
DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1), (0, -1), (-1, 0), (-1, -1), (-1, 1))
OPPOSITE = (4, 5, 6, 7, 0, 1, 2, 3)
RAY_BATCH = 1_000_000
# Surfaces listed per vertical ray at most (a multi-storey scan has a few dozen).
MAX_SURFACES_PER_RAY = 256


class NavigableAreaError(ValueError):
    """A navigable-area cache or request that cannot be used; the message names the file or field."""


class MeshQuery:
    """Ray casts and distance queries against one triangle mesh (open3d's Embree scene, built once)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        self.faces = np.ascontiguousarray(faces, dtype=np.uint32)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(self.vertices), o3d.core.Tensor(self.faces))
        a, b, c = (self.vertices[self.faces[:, i]].astype(np.float64) for i in range(3))
        normals = np.cross(b - a, c - a)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        self.face_normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Distance to the first hit along each ray (inf when none); directions must be unit length."""
        hits = np.empty(len(origins), dtype=np.float64)
        for start in range(0, len(origins), RAY_BATCH):
            stop = start + RAY_BATCH
            rays = np.concatenate([origins[start:stop], directions[start:stop]], axis=1).astype(np.float32)
            hits[start:stop] = self._scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        return hits

    def all_hits(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every surface along every ray: (ray index, distance, triangle index), sorted by ray then distance.

        Found by peeling: cast, step SAME_SURFACE_M past each hit, cast again (8-10x faster than
        open3d's list_intersections on million-triangle scenes). Surfaces closer together than that
        step count once; of coincident triangles (a doubly wound surface) the one Embree hits first
        is kept.
        """
        ray_ids, distances, triangles = [], [], []
        active = np.arange(len(origins))
        travelled = np.zeros(len(origins))
        for _ in range(MAX_SURFACES_PER_RAY):
            if len(active) == 0:
                break
            starts = origins[active] + travelled[active, None] * directions[active]
            rays = np.concatenate([starts, directions[active]], axis=1).astype(np.float32)
            found = self._scene.cast_rays(o3d.core.Tensor(rays))
            hit_distance = found["t_hit"].numpy().astype(np.float64)
            hit = np.isfinite(hit_distance)
            active, hit_distance = active[hit], hit_distance[hit]
            ray_ids.append(active)
            distances.append(travelled[active] + hit_distance)
            triangles.append(found["primitive_ids"].numpy()[hit].astype(np.int64))
            travelled[active] += hit_distance + SAME_SURFACE_M
        ray_id, distance, triangle = (np.concatenate(parts) if parts else np.zeros(0) for parts in
                                      (ray_ids, distances, triangles))
        order = np.lexsort((distance, ray_id))
        return ray_id[order].astype(np.int64), distance[order], triangle[order].astype(np.int64)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance from each point to the nearest triangle, metres."""
        if len(points) == 0:
            return np.zeros(0)
        tensor = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
        return self._scene.compute_distance(tensor).numpy().astype(np.float64)


@dataclass
class NavigableArea:
    """Navigable floor of one scene for one body, on a layered grid.

    Attributes:
        origin: (x, z) of the grid's corner; cell (row, col) spans x0 + col*res .. x0 + (col+1)*res
            and z0 + row*res .. z0 + (row+1)*res; its centre is where the vertical ray was cast.
        resolution: metres per cell.
        heights: (L, R, C) float32 floor height (world y) of each floor node, NaN where there is none.
        navigable: (L, R, C) bool, nodes that remain after erosion.
        islands: (L, R, C) int32 island of each navigable node, -1 elsewhere.
        max_step: metres the body climbs between neighbouring cells.
        stats: counts for reports (floor nodes, navigable nodes, highest ceiling clearance, ...).
    """

    origin: np.ndarray
    resolution: float
    heights: np.ndarray
    navigable: np.ndarray
    islands: np.ndarray
    max_step: float
    stats: dict = field(default_factory=dict)

    @property
    def island_count(self) -> int:
        """Number of islands (connected parts of the navigable area)."""
        return int(self.islands.max()) + 1 if self.islands.size else 0

    @property
    def area_m2(self) -> float:
        """Navigable area in square metres (cells times cell area)."""
        return float(self.navigable.sum()) * self.resolution**2

    def node_cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(layer, row, col) of every navigable node, in flat index order (the node ids of `graph`)."""
        return np.nonzero(self.navigable)

    def cell_centres(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (x, z) of cell centres."""
        return (self.origin[0] + (np.asarray(cols) + 0.5) * self.resolution,
                self.origin[1] + (np.asarray(rows) + 0.5) * self.resolution)

    def graph(self) -> csr_matrix:
        """Links between navigable nodes (both directions), weighted by their 3D length in metres."""
        layers, rows, cols = self.node_cells()
        ids = np.full(self.navigable.shape, -1, dtype=np.int64)
        ids[layers, rows, cols] = np.arange(len(layers))
        neighbours = _neighbour_nodes(np.where(self.navigable, self.heights, np.nan), self.max_step,
                                      layers, rows, cols, ids)
        source, direction = np.nonzero(neighbours >= 0)
        target = neighbours[source, direction]
        steps = np.array(DIRECTIONS, dtype=np.float64)[direction] * self.resolution
        floor = self.heights[layers, rows, cols].astype(np.float64)
        rise = floor[target] - floor[source]
        weights = np.sqrt(steps[:, 0] ** 2 + steps[:, 1] ** 2 + rise**2)
        return csr_matrix((weights, (source, target)), shape=(len(layers), len(layers)))

    def save(self, path: Path) -> None:
        """Write the area as an .npz with fixed zip timestamps, so equal areas give equal bytes."""
        arrays = {"origin": self.origin, "resolution": np.float64(self.resolution), "heights": self.heights,
                  "navigable": self.navigable, "islands": self.islands, "max_step": np.float64(self.max_step),
                  "format_version": np.int64(FORMAT_VERSION),
                  "stats": np.frombuffer(json.dumps(self.stats, sort_keys=True).encode(), dtype=np.uint8)}
        path.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
            for name, array in arrays.items():
                buffer = io.BytesIO()
                np.lib.format.write_array(buffer, np.asarray(array), allow_pickle=False)
                archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), buffer.getvalue(),
                                 compress_type=zipfile.ZIP_DEFLATED)

    @classmethod
    def load(cls, path: Path) -> "NavigableArea":
        """Read an area written by `save`; raises NavigableAreaError naming the file when unusable."""
        try:
            with np.load(path, allow_pickle=False) as data:
                if int(data["format_version"]) != FORMAT_VERSION:
                    raise NavigableAreaError(f"{path}: cache format {int(data['format_version'])}, expected "
                                             f"{FORMAT_VERSION}; delete the file to recompute it")
                return cls(origin=data["origin"], resolution=float(data["resolution"]), heights=data["heights"],
                           navigable=data["navigable"], islands=data["islands"], max_step=float(data["max_step"]),
                           stats=json.loads(data["stats"].tobytes().decode()))
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as error:
            if isinstance(error, NavigableAreaError):
                raise
            raise NavigableAreaError(f"{path}: unreadable navigable-area cache ({error}); "
                                     "delete it to recompute") from None


def compute_navigable_area(mesh: MeshQuery, body: Body, resolution: float,
                           require_ceiling: bool = True) -> NavigableArea:
    """The navigable area of a mesh (world frame, +Y up) for `body` on a grid of `resolution` metres.

    With `require_ceiling` (the default) a floor must have a surface above it, so roofs and open
    ground are not navigable; scans with holes in their ceilings may turn it off.
    """
    lower = mesh.vertices.min(axis=0).astype(np.float64)
    upper = mesh.vertices.max(axis=0).astype(np.float64)
    rows = max(1, math.ceil((upper[2] - lower[2]) / resolution))
    cols = max(1, math.ceil((upper[0] - lower[0]) / resolution))
    if rows * cols > MAX_GRID_CELLS:
        raise NavigableAreaError(f"plan.grid_resolution: {resolution} m gives {rows}x{cols} cells for this scene; "
                                 f"use a coarser resolution (at most {MAX_GRID_CELLS} cells)")
    origin = np.array([lower[0], lower[2]])
    heights, floor_stats = _floor_heights(mesh, body, origin, resolution, rows, cols, float(upper[1]),
                                          require_ceiling)
    layers, node_rows, node_cols = np.nonzero(np.isfinite(heights))
    ids = np.full(heights.shape, -1, dtype=np.int64)
    ids[layers, node_rows, node_cols] = np.arange(len(layers))
    neighbours = _neighbour_nodes(heights, body.max_step, layers, node_rows, node_cols, ids)
    open_links = _open_links(mesh, body, heights, origin, resolution, layers, node_rows, node_cols, neighbours)
    boundary = ~open_links.all(axis=1)
    erosion_steps = math.ceil(body.radius / resolution - 1e-9) + 1
    removed = _dilate(boundary, neighbours, erosion_steps)
    navigable = np.zeros(heights.shape, dtype=bool)
    navigable[layers[~removed], node_rows[~removed], node_cols[~removed]] = True
    area = NavigableArea(origin=origin, resolution=resolution, heights=heights.astype(np.float32),
                         navigable=navigable, islands=np.full(heights.shape, -1, dtype=np.int32),
                         max_step=body.max_step)
    area.islands = label_islands(area)
    area.stats = {**floor_stats, "floor_nodes": int(len(layers)), "navigable_nodes": int(navigable.sum()),
                  "islands": area.island_count, "area_m2": round(area.area_m2, 4), "grid": [int(rows), int(cols)],
                  "erosion_steps": erosion_steps}
    return area


def _floor_heights(mesh: MeshQuery, body: Body, origin: np.ndarray, resolution: float, rows: int, cols: int,
                   top: float, require_ceiling: bool) -> tuple[np.ndarray, dict]:
    """(L, R, C) floor heights from one downward ray per cell, and the highest clearance of any floor."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    x = origin[0] + (c.ravel() + 0.5) * resolution
    z = origin[1] + (r.ravel() + 0.5) * resolution
    start = top + 1.0
    origins = np.stack([x, np.full_like(x, start), z], axis=1)
    directions = np.tile([0.0, -1.0, 0.0], (len(x), 1))
    ray, distance, triangle = mesh.all_hits(origins, directions)
    y = start - distance
    faces_up = mesh.face_normals[triangle, 1] >= math.cos(math.radians(body.max_slope))
    empty = np.full((1, rows, cols), np.nan, dtype=np.float64)
    if len(ray) == 0:
        return empty, {"ceiling_clearance_max_m": 0.0}
    # Merge hits of one ray that are the same surface; a group is a floor if any of its triangles faces up.
    first = np.ones(len(ray), dtype=bool)
    first[1:] = (ray[1:] != ray[:-1]) | (distance[1:] - distance[:-1] > SAME_SURFACE_M)
    starts = np.flatnonzero(first)
    group_ray, group_y = ray[starts], y[starts]
    group_up = np.logical_or.reduceat(faces_up, starts)
    covered = np.zeros(len(starts), dtype=bool)
    covered[1:] = group_ray[1:] == group_ray[:-1]
    clearance = np.full(len(starts), np.inf)
    clearance[1:] = group_y[:-1] - group_y[1:]
    clearance[~covered] = np.inf  # the top surface of a column: nothing above it
    candidate = group_up & (covered | (not require_ceiling))
    highest = float(clearance[candidate & covered].max()) if (candidate & covered).any() else 0.0
    floor = candidate & (clearance >= body.height)
    floor_ray, floor_y = group_ray[floor], group_y[floor]
    if len(floor_ray) == 0:
        return empty, {"ceiling_clearance_max_m": round(highest, 4)}
    # Groups come top-down per ray; count layers bottom-up so that layer 0 is the lowest floor.
    run_start = np.ones(len(floor_ray), dtype=bool)
    run_start[1:] = floor_ray[1:] != floor_ray[:-1]
    run_index = np.cumsum(run_start) - 1
    first_of_run = np.flatnonzero(run_start)
    rank_from_top = np.arange(len(floor_ray)) - first_of_run[run_index]
    per_ray = np.bincount(run_index)
    layer = per_ray[run_index] - 1 - rank_from_top
    heights = np.full((int(per_ray.max()), rows, cols), np.nan, dtype=np.float64)
    heights[layer, floor_ray // cols, floor_ray % cols] = floor_y
    return heights, {"ceiling_clearance_max_m": round(highest, 4)}


def _neighbour_nodes(heights: np.ndarray, max_step: float, layers: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                     ids: np.ndarray) -> np.ndarray:
    """(N, 8) id of the node in each neighbouring column within `max_step` of the node's floor, else -1."""
    count, height, width = heights.shape
    neighbours = np.full((len(layers), 8), -1, dtype=np.int64)
    own = heights[layers, rows, cols]
    for d, (dr, dc) in enumerate(DIRECTIONS):
        nr, nc = rows + dr, cols + dc
        inside = (nr >= 0) & (nr < height) & (nc >= 0) & (nc < width)
        nr, nc = np.clip(nr, 0, height - 1), np.clip(nc, 0, width - 1)
        rise = np.abs(heights[:, nr, nc] - own[None, :])  # (L, N); NaN where no floor
        rise = np.where(np.isfinite(rise), rise, np.inf)
        best = np.argmin(rise, axis=0)
        ok = inside & (rise[best, np.arange(len(layers))] <= max_step)
        neighbours[ok, d] = ids[best[ok], nr[ok], nc[ok]]
    return neighbours


def band_heights(body: Body, spacing: float = 0.25) -> np.ndarray:
    """Heights above the floor where horizontal rays look for thin obstacles: the body's band above its step."""
    low, high = body.max_step + 0.01, max(body.max_step + 0.01, body.height - 0.01)
    count = max(2, math.ceil((high - low) / spacing) + 1)
    return np.linspace(low, high, count)


def _open_links(mesh: MeshQuery, body: Body, heights: np.ndarray, origin: np.ndarray, resolution: float,
                layers: np.ndarray, rows: np.ndarray, cols: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """(N, 8) True where a link exists and no horizontal ray between the two cell centres hits the mesh."""
    open_links = np.zeros(neighbours.shape, dtype=bool)
    own = heights[layers, rows, cols]
    levels = band_heights(body)
    x, z = origin[0] + (cols + 0.5) * resolution, origin[1] + (rows + 0.5) * resolution
    for d in range(4):
        source = np.flatnonzero(neighbours[:, d] >= 0)
        target = neighbours[source, d]
        step = np.array(DIRECTIONS[d], dtype=np.float64) * resolution
        length = float(np.hypot(*step))
        base = np.maximum(own[source], own[target])
        origins = np.stack([np.repeat(x[source], len(levels)),
                            (base[:, None] + levels[None, :]).ravel(),
                            np.repeat(z[source], len(levels))], axis=1)
        direction = np.array([step[1], 0.0, step[0]]) / length
        hit = mesh.cast(origins, np.broadcast_to(direction, origins.shape)) <= length
        clear = ~hit.reshape(len(source), len(levels)).any(axis=1)
        open_links[source[clear], d] = True
        open_links[target[clear], OPPOSITE[d]] = True
    return open_links


def _dilate(seeds: np.ndarray, neighbours: np.ndarray, steps: int) -> np.ndarray:
    """Nodes within `steps` links of a seed node (a square erosion of the floor around its boundary)."""
    reached = seeds.copy()
    valid = neighbours >= 0
    safe = np.where(valid, neighbours, 0)
    for _ in range(steps):
        reached = reached | (reached[safe] & valid).any(axis=1)
    return reached


def label_islands(area: NavigableArea) -> np.ndarray:
    """(L, R, C) island index per navigable node (components in order of their first node), -1 elsewhere."""
    labels = np.full(area.navigable.shape, -1, dtype=np.int32)
    layers, rows, cols = area.node_cells()
    if len(layers) == 0:
        return labels
    _, components = connected_components(area.graph(), directed=False)
    labels[layers, rows, cols] = components
    return labels


# A building's entrance level: islands starting within this height of the lowest walkable floor are
# candidates (uneven ground, a few steps at the door); the largest of them sets the ground height.
GROUND_BAND_M = 1.0


def island_summary(area: NavigableArea) -> tuple[np.ndarray, np.ndarray]:
    """(islands,) area in m2 and (islands,) lowest floor height (world y) of each island."""
    layers, rows, cols = area.node_cells()
    labels = area.islands[layers, rows, cols]
    count = area.island_count
    sizes = np.bincount(labels, minlength=count) * area.resolution**2 if count else np.zeros(0)
    lowest = np.full(count, np.inf)
    np.minimum.at(lowest, labels, area.heights[layers, rows, cols].astype(np.float64))
    return sizes, lowest


def drawable_islands(area: NavigableArea, max_step: float, min_island_area: float,
                     reachable_only: bool = True) -> np.ndarray:
    """(islands,) bool: the islands trajectories may use.

    An island smaller than `min_island_area` never gets a path. With `reachable_only`, only the floor a
    robot put down at the building's entrance level could reach is kept: the largest island that starts
    within GROUND_BAND_M of the lowest walkable floor is the entrance level (with every storey its stairs
    reach, which are part of it), and other islands are kept only when they start within `max_step` of
    its lowest floor (rooms behind closed doors). Roofs, attics, closed-off upper storeys and the tops of
    furniture start higher and are left out.
    """
    sizes, lowest = island_summary(area)
    keep = sizes >= min_island_area
    if not reachable_only or not keep.any():
        return keep
    candidates = keep & (lowest <= lowest[keep].min() + GROUND_BAND_M)
    entrance = int(np.argmax(np.where(candidates, sizes, -1.0)))
    return keep & (np.abs(lowest - lowest[entrance]) <= max_step)


def restrict_to_islands(area: NavigableArea, keep: np.ndarray) -> NavigableArea:
    """A copy of `area` with only the kept islands navigable, islands renumbered 0.. in their old order."""
    new_index = np.full(len(keep) + 1, -1, dtype=np.int32)  # the extra slot maps -1 (no island) to -1
    new_index[np.flatnonzero(keep)] = np.arange(int(keep.sum()), dtype=np.int32)
    islands = new_index[area.islands]
    stats = {**area.stats, "drawable_islands": int(keep.sum()), "dropped_islands": int((~keep).sum()),
             "drawable_area_m2": round(float((islands >= 0).sum()) * area.resolution**2, 4)}
    return NavigableArea(origin=area.origin, resolution=area.resolution, heights=area.heights,
                         navigable=islands >= 0, islands=islands, max_step=area.max_step, stats=stats)
