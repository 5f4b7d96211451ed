"""House layout: rooms split from a rectangular footprint, doors between them, windows, and the
structural objects (one wall, floor and ceiling object per room, window panes, the entrance door).

Coordinates are whole centimetres while planning (exact adjacency tests), metres in the geometry.
Every room owns the inner half (0.05 m) of each of its walls, and rooms on the outside own the outer
half of the exterior wall beside them, so every wall is 0.10 m thick and each piece is a closed box.
Doorways are 0.9-1.1 m wide and 2.1 m tall, at least 0.15 m from any wall corner.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.scenes.procedural.geometry import Box
from pipeline.scenes.scene import SceneError

HALF_WALL = 0.05
SLAB = 0.05
DOOR_TOP = 2.10
MIN_SIDE_CM = 220
MIN_SHARED_CM = 120


@dataclass
class Room:
    """A rectangular room [x0, x1] x [z0, z1] in centimetres, with its kind (kitchen, bedroom, ...)."""

    index: int
    x0: int
    z0: int
    x1: int
    z1: int
    kind: str = "room"

    @property
    def area_m2(self) -> float:
        """Floor area to the wall centre lines, square metres."""
        return (self.x1 - self.x0) * (self.z1 - self.z0) / 1e4

    def inner(self) -> tuple[float, float, float, float]:
        """The free floor inside its walls (metres): x0, z0, x1, z1."""
        return (self.x0 / 100 + HALF_WALL, self.z0 / 100 + HALF_WALL, self.x1 / 100 - HALF_WALL, self.z1 / 100 - HALF_WALL)


@dataclass(frozen=True)
class Opening:
    """A hole in a wall line: `axis` is the direction the wall runs ("x" or "z"), `fixed` its other
    coordinate, [start, end] the span along it and [bottom, top] the height, all in metres."""

    kind: str  # "door", "entrance" or "window"
    axis: str
    fixed: float
    start: float
    end: float
    bottom: float
    top: float
    rooms: tuple[int, ...]


@dataclass
class Layout:
    """Rooms, openings, footprint (cm) and ceiling height (m) of a one-storey house."""

    rooms: list[Room]
    openings: list[Opening]
    footprint: tuple[int, int, int, int]
    ceiling: float
    doors: list[tuple[int, int]] = field(default_factory=list)
    hallway: int | None = None


def _split(rect: tuple[int, int, int, int], rng: np.random.Generator) -> tuple[tuple[int, int, int, int], ...] | None:
    x0, z0, x1, z1 = rect
    along_x = (x1 - x0) >= (z1 - z0)
    length = (x1 - x0) if along_x else (z1 - z0)
    if length < 2 * MIN_SIDE_CM:
        return None
    cut = int(round(length * rng.uniform(0.38, 0.62) / 10.0)) * 10
    cut = min(max(cut, MIN_SIDE_CM), length - MIN_SIDE_CM)
    if along_x:
        return (x0, z0, x0 + cut, z1), (x0 + cut, z0, x1, z1)
    return (x0, z0, x1, z0 + cut), (x0, z0 + cut, x1, z1)


def _bsp(rect: tuple[int, int, int, int], count: int, rng: np.random.Generator) -> list[tuple[int, int, int, int]]:
    """Split `rect` into `count` rooms (fewer if it is too small), always splitting the largest."""
    rects = [rect]
    while len(rects) < count:
        order = sorted(range(len(rects)), key=lambda i: -(rects[i][2] - rects[i][0]) * (rects[i][3] - rects[i][1]))
        for i in order:
            halves = _split(rects[i], rng)
            if halves is not None:
                rects[i:i + 1] = list(halves)
                break
        else:
            break
    return rects


def _shared(a: Room, b: Room) -> tuple[str, int, int, int] | None:
    """(axis the wall runs along, fixed coordinate, start, end) of the wall a and b share, in cm."""
    for first, second in ((a, b), (b, a)):
        if first.x1 == second.x0:
            lo, hi = max(first.z0, second.z0), min(first.z1, second.z1)
            if hi - lo >= MIN_SHARED_CM:
                return ("z", first.x1, lo, hi)
        if first.z1 == second.z0:
            lo, hi = max(first.x0, second.x0), min(first.x1, second.x1)
            if hi - lo >= MIN_SHARED_CM:
                return ("x", first.z1, lo, hi)
    return None


ROOM_KINDS = ("living room", "kitchen", "bathroom", "bedroom", "bedroom", "office", "dining room", "bathroom",
              "bedroom", "laundry room", "office", "bedroom")


UPPER_ROOM_KINDS = ("bedroom", "bathroom", "bedroom", "office", "bedroom", "bathroom", "office", "bedroom",
                    "laundry room", "bedroom", "office", "bedroom")


def _assign_kinds(rooms: list[Room], hallway: int | None, first_index: int = 0) -> None:
    others = [r for r in rooms if r.index != hallway]
    by_area = sorted(others, key=lambda r: (-r.area_m2, r.index))
    kinds = list((UPPER_ROOM_KINDS if first_index else ROOM_KINDS)[: len(others)])
    # Largest rooms get the living room and kitchen; the smallest get the bathrooms.
    bathrooms = [k for k in kinds if k in ("bathroom", "laundry room")]
    rest = [k for k in kinds if k not in ("bathroom", "laundry room")]
    for room, kind in zip(by_area, rest + bathrooms, strict=True):
        room.kind = kind
    if hallway is not None:
        rooms[hallway - first_index].kind = "hallway"


def plan_rooms(rng: np.random.Generator, count: int, footprint: tuple[int, int, int, int] | None = None,
               strip: tuple[int, int] | None = None, first_index: int = 0
               ) -> tuple[list[Room], tuple[int, int, int, int], int | None]:
    """Rooms of a rectangular footprint; from 5 rooms on (or when `strip` is given), a hallway strip
    [z0, z1] (cm) runs along the house. `footprint` and `strip` are fixed for the upper storey."""
    if footprint is None:
        area = count * rng.uniform(14.0, 20.0)
        aspect = rng.uniform(1.15, 1.7)
        width = int(round(np.sqrt(area * aspect) * 10)) * 10
        depth = int(round(area / (width / 100.0) * 10)) * 10
        footprint = (0, 0, width, depth)
    width, depth = footprint[2], footprint[3]
    if strip is None and count >= 5:
        wide = int(rng.integers(14, 18)) * 10
        front_depth = int(round((depth - wide) * rng.uniform(0.42, 0.58) / 10)) * 10
        strip = (front_depth, front_depth + wide)
    if strip is None:
        rects, hallway = _bsp(footprint, count, rng), None
    else:
        front, hall, back = (0, 0, width, strip[0]), (0, strip[0], width, strip[1]), (0, strip[1], width, depth)
        front_count = max(1, int(round((count - 1) * strip[0] / (depth - (strip[1] - strip[0])))))
        back_count = max(1, count - 1 - front_count)
        rects = _bsp(front, front_count, rng) + [hall] + _bsp(back, back_count, rng)
        hallway = rects.index(hall) + first_index
    rooms = [Room(first_index + i, *rect) for i, rect in enumerate(rects)]
    _assign_kinds(rooms, hallway, first_index)
    return rooms, footprint, hallway


def connect_rooms(rooms: list[Room], hallway: int | None, rng: np.random.Generator,
                  avoid: list[tuple[str, int, int, int]] | None = None) -> list[tuple[int, int]] | None:
    """Pairs of rooms joined by a door: a random spanning tree (hallway first) plus a few extra doors.

    Returns None when the rooms are not all connected through walls long enough for a door (outside
    the `avoid` spans).
    """
    edges = [(i, i + 1 + j) for i, a in enumerate(rooms) for j, b in enumerate(rooms[i + 1:])
             if _shared(a, b) and _door_spans(a, b, avoid or [])]
    hallway = None if hallway is None else hallway - rooms[0].index
    order = rng.permutation(len(edges))
    edges = [edges[i] for i in order]
    edges.sort(key=lambda e: 0 if hallway in e else 1)  # stable: random within each group
    parent = list(range(len(rooms)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    doors = []
    for a, b in edges:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[ra] = rb
            doors.append((a, b))
        elif "bathroom" not in (rooms[a].kind, rooms[b].kind) and rng.random() < 0.3:
            doors.append((a, b))
    if len({root(i) for i in range(len(rooms))}) != 1:
        return None
    return sorted(doors)  # positions in `rooms`


def _free_spans(lo: int, hi: int, blocked: list[tuple[int, int]]) -> list[tuple[int, int]]:
    spans, cursor = [], lo
    for b0, b1 in sorted(blocked):
        if b0 > cursor:
            spans.append((cursor, min(b0, hi)))
        cursor = max(cursor, b1)
    if cursor < hi:
        spans.append((cursor, hi))
    return [(a, b) for a, b in spans if b > a]


def _door_spans(a: Room, b: Room, avoid: list[tuple[str, int, int, int]]) -> list[tuple[int, int]]:
    """Spans (cm) of the wall a and b share where a door fits: 15 cm clear of corners and of `avoid`."""
    shared = _shared(a, b)
    if shared is None:
        return []
    axis, fixed, lo, hi = shared
    blocked = [(s0, s1) for ax, fx, s0, s1 in avoid if ax == axis and fx == fixed]
    return [(s0, s1) for s0, s1 in _free_spans(lo + 15, hi - 15, blocked) if s1 - s0 >= 90]


def _door_opening(a: Room, b: Room, rng: np.random.Generator, avoid: list[tuple[str, int, int, int]]) -> Opening:
    """A door somewhere on a free span of the wall a and b share (see `_door_spans`)."""
    axis, fixed, _, _ = _shared(a, b)  # type: ignore[misc]
    spans = _door_spans(a, b, avoid)
    s0, s1 = spans[int(rng.integers(len(spans)))]
    width = min(int(rng.integers(9, 12)) * 10, s1 - s0)
    start = int(rng.integers(s0, s1 - width + 1))
    return Opening("door", axis, fixed / 100, start / 100, (start + width) / 100, 0.0, DOOR_TOP, (a.index, b.index))


def exterior_sides(room: Room, footprint: tuple[int, int, int, int]) -> list[tuple[str, int, int, int, int]]:
    """(axis, fixed, start, end, outward sign) of each side of the room on the house's outline (cm)."""
    fx0, fz0, fx1, fz1 = footprint
    sides = []
    if room.z0 == fz0:
        sides.append(("x", room.z0, room.x0, room.x1, -1))
    if room.z1 == fz1:
        sides.append(("x", room.z1, room.x0, room.x1, +1))
    if room.x0 == fx0:
        sides.append(("z", room.x0, room.z0, room.z1, -1))
    if room.x1 == fx1:
        sides.append(("z", room.x1, room.z0, room.z1, +1))
    return sides


def _windows(room: Room, footprint: tuple[int, int, int, int], taken: list[Opening], rng: np.random.Generator) -> list[Opening]:
    windows: list[Opening] = []
    if room.kind == "hallway":
        return windows
    sill, top = (1.4, 2.0) if room.kind in ("bathroom", "laundry room") else (rng.uniform(0.8, 0.95), 2.05)
    for axis, fixed, lo, hi, _ in exterior_sides(room, footprint):
        length = hi - lo
        if length < 150:
            continue
        count = 1 if length < 400 else 2
        for k in range(count):
            width = int(rng.integers(8, 15)) * 10
            centre = lo + length * (k + 0.5) / count + rng.uniform(-20, 20)
            start = int(round(centre - width / 2))
            start, end = max(start, lo + 40), min(start + width, hi - 40)
            clash = any(o.axis == axis and abs(o.fixed - fixed / 100) < 1e-9 and o.start < end / 100 + 0.2
                        and start / 100 - 0.2 < o.end for o in taken + windows)
            if end - start >= 60 and not clash:
                windows.append(Opening("window", axis, fixed / 100, start / 100, end / 100, round(sill, 3), top, (room.index,)))
    return windows


def _entrance(rooms: list[Room], footprint: tuple[int, int, int, int], hallway: int | None, rng: np.random.Generator) -> Opening | None:
    candidates = [rooms[hallway]] if hallway is not None else []
    candidates += [r for r in rooms if r.kind == "living room"] + rooms
    for room in candidates:
        for axis, fixed, lo, hi, _ in exterior_sides(room, footprint):
            if hi - lo >= 160:
                start = int(rng.integers(lo + 30, hi - 130 + 1))
                return Opening("entrance", axis, fixed / 100, start / 100, (start + 100) / 100, 0.0, DOOR_TOP, (room.index,))
    return None


def make_layout(rng: np.random.Generator, min_rooms: int, max_rooms: int, footprint: tuple[int, int, int, int] | None = None,
                strip: tuple[int, int] | None = None, first_index: int = 0, avoid: list[tuple[str, int, int, int]] | None = None,
                ceiling: float | None = None, entrance: bool = True, count: int | None = None) -> Layout:
    """A connected storey plan with doors and windows; retries until every room is reachable.

    The upper storey passes the ground floor's footprint, hallway strip and ceiling height, its first
    room index, and `avoid`: wall spans (axis, fixed, start, end in cm) where no door may open.
    """
    for _ in range(50):
        wanted = count if count is not None else int(rng.integers(min_rooms, max_rooms + 1))
        rooms, shape, hallway = plan_rooms(rng, wanted, footprint, strip, first_index)
        doors = connect_rooms(rooms, hallway, rng, avoid)
        if doors is None or len(rooms) < min(min_rooms, wanted):
            continue
        door_openings = [_door_opening(rooms[a], rooms[b], rng, avoid or []) for a, b in doors]
        front = _entrance(rooms, shape, hallway - first_index if hallway is not None else None, rng) if entrance else None
        if front is not None:
            door_openings.append(front)
        for room in rooms:
            door_openings += _windows(room, shape, door_openings, rng)
        height = ceiling if ceiling is not None else round(float(rng.uniform(2.5, 2.8)), 2)
        pairs = [(rooms[a].index, rooms[b].index) for a, b in doors]
        return Layout(rooms, door_openings, shape, height, pairs, hallway)
    raise SceneError(f"procedural layout: no connected plan of {min_rooms}-{max_rooms} rooms in 50 attempts; "
                     "widen scenes.procedural.min_rooms..max_rooms")


# ------------------------------------------------------------------------------------------ geometry


def _cut_wall(axis: str, fixed: float, sign: int, start: float, end: float, bottom: float, top: float,
              holes: list[Opening], material: str, color: tuple[int, int, int]) -> list[Box]:
    """Boxes of a wall of thickness HALF_WALL on side `sign` of the line, minus the holes."""
    pieces: list[tuple[float, float, float, float]] = []  # (s, e, y0, y1)
    cursor = start
    for hole in sorted(holes, key=lambda h: h.start):
        s, e = max(hole.start, start), min(hole.end, end)
        if e <= s:
            continue
        if s > cursor:
            pieces.append((cursor, s, bottom, top))
        if hole.bottom > bottom:
            pieces.append((s, e, bottom, hole.bottom))
        if hole.top < top:
            pieces.append((s, e, hole.top, top))
        cursor = max(cursor, e)
    if cursor < end:
        pieces.append((cursor, end, bottom, top))
    near, far = sorted((fixed, fixed + sign * HALF_WALL))
    boxes = []
    for s, e, y0, y1 in pieces:
        if axis == "x":
            boxes.append(Box((s, y0, near), (e, y1, far), material, color))
        else:
            boxes.append(Box((near, y0, s), (far, y1, e), material, color))
    return boxes


def room_walls(room: Room, layout: Layout, material: str, color: tuple[int, int, int]) -> list[Box]:
    """The room's inner half-walls on all four sides, and the outer half of its exterior walls."""
    x0, z0, x1, z1 = room.x0 / 100, room.z0 / 100, room.x1 / 100, room.z1 / 100
    ceiling = layout.ceiling
    mine = [o for o in layout.openings if room.index in o.rooms]

    def holes(axis: str, fixed: float) -> list[Opening]:
        return [o for o in mine if o.axis == axis and abs(o.fixed - fixed) < 1e-9]

    boxes = []
    boxes += _cut_wall("x", z0, +1, x0, x1, 0.0, ceiling, holes("x", z0), material, color)
    boxes += _cut_wall("x", z1, -1, x0, x1, 0.0, ceiling, holes("x", z1), material, color)
    boxes += _cut_wall("z", x0, +1, z0 + HALF_WALL, z1 - HALF_WALL, 0.0, ceiling, holes("z", x0), material, color)
    boxes += _cut_wall("z", x1, -1, z0 + HALF_WALL, z1 - HALF_WALL, 0.0, ceiling, holes("z", x1), material, color)
    fx0, fz0, fx1, fz1 = layout.footprint
    outside = (200, 196, 188)
    for axis, fixed_cm, lo, hi, sign in exterior_sides(room, layout.footprint):
        start, end = lo / 100, hi / 100
        if axis == "x":  # walls along x also close the house's corners
            start -= HALF_WALL if lo == fx0 else 0.0
            end += HALF_WALL if hi == fx1 else 0.0
        boxes += _cut_wall(axis, fixed_cm / 100, sign, start, end, -SLAB, ceiling + SLAB,
                           holes(axis, fixed_cm / 100), "paint", outside)
    return boxes


def window_pane(opening: Opening) -> Box:
    """Glass filling a window opening, 2 cm thick, centred in the wall."""
    if opening.axis == "x":
        return Box((opening.start, opening.bottom, opening.fixed - 0.01), (opening.end, opening.top, opening.fixed + 0.01), "glass", (170, 200, 215))
    return Box((opening.fixed - 0.01, opening.bottom, opening.start), (opening.fixed + 0.01, opening.top, opening.end), "glass", (170, 200, 215))


def entrance_leaf(opening: Opening) -> Box:
    """The closed front door filling the entrance opening, 4 cm thick, centred in the wall."""
    color = (120, 80, 50)
    if opening.axis == "x":
        return Box((opening.start, 0.0, opening.fixed - 0.02), (opening.end, opening.top, opening.fixed + 0.02), "wood", color)
    return Box((opening.fixed - 0.02, 0.0, opening.start), (opening.fixed + 0.02, opening.top, opening.end), "wood", color)


def slab_boxes(room: Room, y0: float, y1: float, hole: tuple[float, float, float, float] | None,
               material: str, color: tuple[int, int, int]) -> list[Box]:
    """A floor or ceiling slab over the room, minus a rectangular `hole` (x0, z0, x1, z1 in metres)."""
    x0, z0, x1, z1 = room.x0 / 100, room.z0 / 100, room.x1 / 100, room.z1 / 100
    if hole is None or hole[0] >= x1 or hole[2] <= x0 or hole[1] >= z1 or hole[3] <= z0:
        return [Box((x0, y0, z0), (x1, y1, z1), material, color)]
    hx0, hz0, hx1, hz1 = max(hole[0], x0), max(hole[1], z0), min(hole[2], x1), min(hole[3], z1)
    pieces = [(x0, z0, hx0, z1), (hx1, z0, x1, z1), (hx0, z0, hx1, hz0), (hx0, hz1, hx1, z1)]
    return [Box((a, y0, b), (c, y1, d), material, color) for a, b, c, d in pieces if c - a > 1e-6 and d - b > 1e-6]
