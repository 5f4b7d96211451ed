"""Solid primitives (boxes, cylinders, ellipsoids) and their tessellation into one labelled mesh.

Every primitive is a closed solid with outward, counter-clockwise faces. Each box face is cut into a
grid of cells no larger than `cell` metres (that is what the `detail` knob scales); round shapes get
`segments` around. Faces of the same grid shape are tessellated together with numpy, so a 1 M
triangle house is built in a few vectorised passes rather than one Python call per triangle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from pipeline.scenes.procedural.textures import shade

# Axis frames (e1, axis, e2), right-handed in that order, so rotating a +Y-up local shape keeps winding.
_FRAMES = {
    "y": (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])),
    "x": (np.array([0, 0, 1.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])),
    "z": (np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), np.array([1.0, 0, 0])),
}


@dataclass(frozen=True)
class Box:
    """Axis-aligned box from `low` to `high` (metres), with a material and a base colour."""

    low: tuple[float, float, float]
    high: tuple[float, float, float]
    material: str
    color: tuple[int, int, int]

    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner."""
        return np.array([self.low, self.high], dtype=np.float64)


@dataclass(frozen=True)
class Cylinder:
    """Closed cylinder: `base` centre of one cap, extending `height` along `axis` ("x", "y" or "z")."""

    base: tuple[float, float, float]
    radius: float
    height: float
    material: str
    color: tuple[int, int, int]
    axis: str = "y"

    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner of the axis-aligned box around the cylinder."""
        _, axis, _ = _FRAMES[self.axis]
        low = np.array(self.base) - self.radius * (1 - axis)
        high = np.array(self.base) + self.radius * (1 - axis) + self.height * axis
        return np.array([low, high])


@dataclass(frozen=True)
class Ellipsoid:
    """Closed ellipsoid with a centre and three radii (x, y, z)."""

    center: tuple[float, float, float]
    radii: tuple[float, float, float]
    material: str
    color: tuple[int, int, int]

    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner of the axis-aligned box around the ellipsoid."""
        c, r = np.array(self.center), np.array(self.radii)
        return np.array([c - r, c + r])


Part = Box | Cylinder | Ellipsoid


def translate(part: Part, offset: np.ndarray) -> Part:
    """The part moved by `offset` (x, y, z)."""
    o = np.asarray(offset, dtype=np.float64)
    if isinstance(part, Box):
        return Box(_t(np.array(part.low) + o), _t(np.array(part.high) + o), part.material, part.color)
    if isinstance(part, Cylinder):
        return Cylinder(_t(np.array(part.base) + o), part.radius, part.height, part.material, part.color, part.axis)
    return Ellipsoid(_t(np.array(part.center) + o), part.radii, part.material, part.color)


def rotate_quarter(part: Part, turns: int) -> Part:
    """The part rotated by `turns` x 90 degrees about +Y through the origin (keeps boxes axis-aligned)."""
    turns %= 4
    if turns == 0:
        return part
    if isinstance(part, Box):
        corners = np.array([_rot(part.low, turns), _rot(part.high, turns)])
        return Box(_t(corners.min(0)), _t(corners.max(0)), part.material, part.color)
    if isinstance(part, Cylinder):
        axis = part.axis if part.axis == "y" or turns % 2 == 0 else ("z" if part.axis == "x" else "x")
        bounds = np.array([_rot(b, turns) for b in part.bounds()])
        low, high = bounds.min(0), bounds.max(0)
        _, direction, _ = _FRAMES[axis]
        base = (low + high) / 2 - direction * part.height / 2
        return Cylinder(_t(base), part.radius, part.height, part.material, part.color, axis)
    radii = part.radii if turns % 2 == 0 else (part.radii[2], part.radii[1], part.radii[0])
    return Ellipsoid(_t(_rot(part.center, turns)), radii, part.material, part.color)


def _rot(point: tuple[float, float, float] | np.ndarray, turns: int) -> np.ndarray:
    x, y, z = point
    for _ in range(turns):
        x, z = z, -x  # +90 degrees about +Y
    return np.array([x, y, z])


def _t(values: np.ndarray) -> tuple[float, float, float]:
    # Rounded to 0.1 mm so that rotations do not leave 1e-17 residues that differ between platforms.
    return tuple(round(float(v), 4) + 0.0 for v in values)  # type: ignore[return-value]


# ------------------------------------------------------------------------------------ tessellation


@dataclass
class MeshArrays:
    """Tessellated scene arrays (see `Scene`)."""

    vertices: np.ndarray
    faces: np.ndarray
    face_object_ids: np.ndarray
    vertex_colors: np.ndarray


def _box_faces(boxes: list[Box]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(6B, 3) origin, edge U and edge V of each box face; U x V points outward."""
    low = np.array([b.low for b in boxes], dtype=np.float64)
    high = np.array([b.high for b in boxes], dtype=np.float64)
    d = high - low
    zero = np.zeros(len(boxes))
    dx, dy, dz = (np.stack([d[:, 0], zero, zero], 1), np.stack([zero, d[:, 1], zero], 1), np.stack([zero, zero, d[:, 2]], 1))
    hx = low.copy()
    hx[:, 0] = high[:, 0]
    hy = low.copy()
    hy[:, 1] = high[:, 1]
    hz = low.copy()
    hz[:, 2] = high[:, 2]
    origins = np.stack([hx, low, hy, low, hz, low], 1)
    edge_u = np.stack([dy, dz, dz, dx, dx, dy], 1)
    edge_v = np.stack([dz, dy, dx, dz, dy, dx], 1)
    return origins.reshape(-1, 3), edge_u.reshape(-1, 3), edge_v.reshape(-1, 3)


def grid_cells(edge_u: np.ndarray, edge_v: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Cells along U and V for faces of the given edges (at least 1, at most 400)."""
    nu = np.clip(np.ceil(np.linalg.norm(edge_u, axis=1) / cell - 1e-9), 1, 400).astype(np.int64)
    nv = np.clip(np.ceil(np.linalg.norm(edge_v, axis=1) / cell - 1e-9), 1, 400).astype(np.int64)
    return nu, nv


def box_triangle_count(boxes: list[Box], cell: float) -> int:
    """Triangles the boxes tessellate into at this cell size (to pick the cell size for a budget)."""
    if not boxes:
        return 0
    _, edge_u, edge_v = _box_faces(boxes)
    nu, nv = grid_cells(edge_u, edge_v, cell)
    return int((2 * nu * nv).sum())


@lru_cache(maxsize=512)
def _grid_template(nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit grid parameters (P, 2) and triangles (2 nu nv, 3), counter-clockwise in (U, V)."""
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
    params = np.stack([i.ravel() / nu, j.ravel() / nv], 1)
    a = (i[:-1, :-1] * (nv + 1) + j[:-1, :-1]).ravel()
    b = a + (nv + 1)
    c = b + 1
    d = a + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return params, faces


class MeshAccumulator:
    """Collects vertex/face blocks with their object ids and materials, then concatenates them."""

    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.face_ids: list[np.ndarray] = []
        self.colors: list[np.ndarray] = []
        self.count = 0

    def add(self, vertices: np.ndarray, faces: np.ndarray, face_ids: np.ndarray, colors: np.ndarray) -> None:
        """Append a block; its face indices are local to its vertices."""
        self.vertices.append(vertices)
        self.faces.append(faces + self.count)
        self.face_ids.append(face_ids)
        self.colors.append(colors)
        self.count += len(vertices)

    def build(self) -> MeshArrays:
        """All blocks as one set of arrays (float32 vertices, int32 faces, uint32 ids, uint8 colours)."""
        return MeshArrays(
            np.concatenate(self.vertices).astype(np.float32),
            np.concatenate(self.faces).astype(np.int32),
            np.concatenate(self.face_ids).astype(np.uint32),
            np.concatenate(self.colors).astype(np.uint8),
        )


def add_boxes(mesh: MeshAccumulator, boxes: list[Box], ids: list[int], cell: float) -> None:
    """Tessellate boxes into `mesh`, grouping faces of equal grid shape into one numpy pass."""
    if not boxes:
        return
    origins, edge_u, edge_v = _box_faces(boxes)
    nu, nv = grid_cells(edge_u, edge_v, cell)
    face_box = np.repeat(np.arange(len(boxes)), 6)
    materials = np.array([b.material for b in boxes])[face_box]
    colors = np.array([b.color for b in boxes], dtype=np.float64)[face_box]
    face_ids = np.array(ids, dtype=np.uint32)[face_box]
    shapes = np.unique(np.stack([nu, nv], 1), axis=0)
    for shape_u, shape_v in shapes:
        select = np.flatnonzero((nu == shape_u) & (nv == shape_v))
        params, tris = _grid_template(int(shape_u), int(shape_v))
        points = (origins[select, None, :] + params[None, :, 0:1] * edge_u[select, None, :]
                  + params[None, :, 1:2] * edge_v[select, None, :])
        _add_instances(mesh, points, tris, face_ids[select], materials[select], colors[select])


def _add_instances(mesh: MeshAccumulator, points: np.ndarray, tris: np.ndarray, ids: np.ndarray,
                   materials: np.ndarray, colors: np.ndarray) -> None:
    """Add K copies of a template (points (K, P, 3), shared triangles) with per-instance id and colour."""
    k, p, _ = points.shape
    vertices = points.reshape(-1, 3)
    faces = (tris[None, :, :] + (np.arange(k) * p)[:, None, None]).reshape(-1, 3)
    face_ids = np.repeat(ids, len(tris))
    shaded = shade(vertices, np.repeat(materials, p), np.repeat(colors, p, axis=0))
    mesh.add(vertices, faces, face_ids, shaded)


@lru_cache(maxsize=64)
def _cylinder_template(segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit cylinder (radius 1, height 1, +Y) as local (a, h, b) points and outward triangles."""
    angle = np.arange(segments) * (2 * math.pi / segments)
    ring = np.stack([np.cos(angle), np.sin(angle)], 1)
    side_bottom = np.column_stack([ring[:, 0], np.zeros(segments), ring[:, 1]])
    side_top = side_bottom + [0, 1, 0]
    centres = np.array([[0.0, 0, 0], [0, 1, 0]])
    points = np.concatenate([side_bottom, side_top, side_bottom, side_top, centres])
    s = np.arange(segments)
    n = (s + 1) % segments
    # With e1 = x, e2 = z, angle grows from x toward z, i.e. clockwise seen from +Y: wind accordingly.
    side = np.concatenate([np.stack([s, segments + s, segments + n], 1), np.stack([s, segments + n, n], 1)])
    bottom_centre, top_centre = 4 * segments, 4 * segments + 1
    bottom = np.stack([np.full(segments, bottom_centre), 2 * segments + s, 2 * segments + n], 1)
    top = np.stack([np.full(segments, top_centre), 3 * segments + n, 3 * segments + s], 1)
    return points, np.concatenate([side, bottom, top])


@lru_cache(maxsize=64)
def _sphere_template(segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere: `segments` around, segments // 2 bands, pole fans (no degenerate triangles)."""
    bands = max(segments // 2, 2)
    theta = np.arange(1, bands) * (math.pi / bands)  # latitude rings, excluding poles
    phi = np.arange(segments) * (2 * math.pi / segments)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    rings = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    points = np.concatenate([rings, [[0, 1.0, 0], [0, -1.0, 0]]])
    north, south = len(rings), len(rings) + 1
    s = np.arange(segments)
    n = (s + 1) % segments
    tris = [np.stack([np.full(segments, north), n, s], 1)]
    for r in range(bands - 2):
        a, b = r * segments + s, r * segments + n
        c, d = (r + 1) * segments + n, (r + 1) * segments + s
        tris += [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]
    last = (bands - 2) * segments
    tris.append(np.stack([np.full(segments, south), last + s, last + n], 1))
    return points, np.concatenate(tris)


def add_cylinders(mesh: MeshAccumulator, cylinders: list[Cylinder], ids: list[int], segments: int) -> None:
    """Tessellate cylinders (any of the three axes) into `mesh`."""
    if not cylinders:
        return
    template, tris = _cylinder_template(segments)
    points = np.empty((len(cylinders), len(template), 3))
    for k, cylinder in enumerate(cylinders):
        e1, axis, e2 = _FRAMES[cylinder.axis]
        local = template * [cylinder.radius, cylinder.height, cylinder.radius]
        points[k] = np.array(cylinder.base) + np.outer(local[:, 0], e1) + np.outer(local[:, 1], axis) + np.outer(local[:, 2], e2)
    _add_instances(mesh, points, tris, np.array(ids, np.uint32), np.array([c.material for c in cylinders]),
                   np.array([c.color for c in cylinders], np.float64))


def add_ellipsoids(mesh: MeshAccumulator, ellipsoids: list[Ellipsoid], ids: list[int], segments: int) -> None:
    """Tessellate ellipsoids into `mesh`."""
    if not ellipsoids:
        return
    template, tris = _sphere_template(segments)
    centres = np.array([e.center for e in ellipsoids])
    radii = np.array([e.radii for e in ellipsoids])
    points = centres[:, None, :] + template[None, :, :] * radii[:, None, :]
    _add_instances(mesh, points, tris, np.array(ids, np.uint32), np.array([e.material for e in ellipsoids]),
                   np.array([e.color for e in ellipsoids], np.float64))
