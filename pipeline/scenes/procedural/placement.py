"""Furnishing one room without interpenetration.

Each placed object is checked against what is already in the room with axis-aligned boxes:
floor furniture against the whole boxes of other floor furniture and of the keep-out zones (the
space in front of doors, the window openings); things on surfaces and on walls against every part
placed so far. Two boxes may touch (a vase on a table) but never overlap by more than `EPSILON`.
All choices come from the house's seeded generator, in a fixed order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.scenes.procedural.furniture import Piece, Surface
from pipeline.scenes.procedural.layout import HALF_WALL, Opening, Room

EPSILON = 1e-6
WALL_GAP = 0.01
# Wall sides: name -> quarter turns that make a piece's front (+Z) face into the room.
SIDES = {"south": 0, "west": 1, "north": 2, "east": 3}


def overlaps(box: np.ndarray, others: np.ndarray) -> bool:
    """Whether (2, 3) `box` overlaps any of `others` (N, 2, 3) by more than EPSILON on all axes."""
    if len(others) == 0:
        return False
    depth = np.minimum(box[1], others[:, 1]) - np.maximum(box[0], others[:, 0])
    return bool(np.all(depth > EPSILON, axis=1).any())


@dataclass
class Placed:
    """A placed object (world frame) with the room it is in."""

    piece: Piece
    region: int


class RoomFurnisher:
    """Places pieces in one room and remembers what is where."""

    def __init__(self, room: Room, openings: list[Opening], ceiling: float, rng: np.random.Generator):
        self.room = room
        self.rng = rng
        self.ceiling = ceiling
        self.inner = np.array(room.inner())
        mine = [o for o in openings if room.index in o.rooms]
        self.openings = mine
        self.floor_boxes: list[np.ndarray] = [_keep_out(o, room) for o in mine]
        # Windows also keep shelf clutter and wall items out of their openings.
        self.part_boxes: list[np.ndarray] = [_keep_out(o, room) for o in mine if o.kind == "window"]
        self.surfaces: list[Surface] = []
        self.placed: list[Placed] = []

    # ------------------------------------------------------------------------------ bookkeeping
    def _inside(self, box: np.ndarray) -> bool:
        x0, z0, x1, z1 = self.inner
        return bool(box[0, 0] >= x0 - EPSILON and box[1, 0] <= x1 + EPSILON and box[0, 2] >= z0 - EPSILON
                    and box[1, 2] <= z1 + EPSILON and box[1, 1] <= self.ceiling + EPSILON)

    def _parts_free(self, piece: Piece) -> bool:
        others = np.array(self.part_boxes) if self.part_boxes else np.zeros((0, 2, 3))
        return not any(overlaps(p.bounds(), others) for q in _with_extras(piece) for p in q.parts)

    def _commit(self, piece: Piece, floor: bool) -> Piece:
        if floor:
            self.floor_boxes.append(_full_bounds(piece))
        for q in _with_extras(piece):
            self.part_boxes.extend(p.bounds() for p in q.parts)
            self.surfaces.extend(q.surfaces)
        self.placed.append(Placed(piece, self.room.index))
        return piece

    def reserve(self, piece: Piece) -> None:
        """Claim space before furnishing (stairs, railings, landings); category-0 pieces are only
        keep-outs and are dropped from the house."""
        self._commit(piece, floor=True)

    # ------------------------------------------------------------------------------------ floor
    def against_wall(self, piece: Piece, side: str | None = None, attempts: int = 12) -> Piece | None:
        """Stand `piece` with its back to a wall (a random one unless `side` is given)."""
        for _ in range(attempts):
            chosen = side or list(SIDES)[int(self.rng.integers(4))]
            turned = piece.moved(SIDES[chosen], np.zeros(3))
            bounds = _full_bounds(turned)
            offset = self._wall_offset(chosen, bounds, WALL_GAP)
            if offset is not None and self._try_floor(turned, offset):
                return self.placed[-1].piece
        return None

    def against_any_wall(self, piece: Piece, attempts: int = 6) -> tuple[Piece | None, str]:
        """Try the four walls in a random order; returns the placed piece (or None) and its wall."""
        sides = list(SIDES)
        for index in self.rng.permutation(4):
            placed = self.against_wall(piece, sides[int(index)], attempts)
            if placed is not None:
                return placed, sides[int(index)]
        return None, sides[0]

    def in_middle(self, piece: Piece, attempts: int = 12, margin: float = 0.5) -> Piece | None:
        """Stand `piece` somewhere away from the walls, turned by a random multiple of 90 degrees."""
        x0, z0, x1, z1 = self.inner
        for _ in range(attempts):
            turned = piece.moved(int(self.rng.integers(4)), np.zeros(3))
            b = _full_bounds(turned)
            lo_x, hi_x = x0 + margin - b[0, 0], x1 - margin - b[1, 0]
            lo_z, hi_z = z0 + margin - b[0, 2], z1 - margin - b[1, 2]
            if lo_x > hi_x or lo_z > hi_z:
                continue
            offset = np.array([self.rng.uniform(lo_x, hi_x), 0.0, self.rng.uniform(lo_z, hi_z)])
            if self._try_floor(turned, offset):
                return self.placed[-1].piece
        return None

    def at(self, piece: Piece, turns: int, position: np.ndarray) -> Piece | None:
        """Stand `piece` exactly there (used for chairs around a table); None if it does not fit."""
        turned = piece.moved(turns, np.zeros(3))
        return self.placed[-1].piece if self._try_floor(turned, np.asarray(position, dtype=np.float64)) else None

    def _wall_offset(self, side: str, bounds: np.ndarray, gap: float) -> np.ndarray | None:
        x0, z0, x1, z1 = self.inner
        if side in ("south", "north"):
            lo, hi = x0 - bounds[0, 0], x1 - bounds[1, 0]
            if lo > hi:
                return None
            z = z0 + gap - bounds[0, 2] if side == "south" else z1 - gap - bounds[1, 2]
            return np.array([self.rng.uniform(lo, hi), 0.0, z])
        lo, hi = z0 - bounds[0, 2], z1 - bounds[1, 2]
        if lo > hi:
            return None
        x = x0 + gap - bounds[0, 0] if side == "west" else x1 - gap - bounds[1, 0]
        return np.array([x, 0.0, self.rng.uniform(lo, hi)])

    def _try_floor(self, turned: Piece, offset: np.ndarray) -> bool:
        offset = np.round(offset, 3)
        moved = turned.moved(0, offset)
        box = _full_bounds(moved)
        others = np.array(self.floor_boxes) if self.floor_boxes else np.zeros((0, 2, 3))
        if not self._inside(box) or overlaps(box, others) or not self._parts_free(moved):
            return False
        self._commit(moved, floor=True)
        return True

    # --------------------------------------------------------------------------- surfaces, walls
    def on_surface(self, piece: Piece, surface: Surface, attempts: int = 6) -> Piece | None:
        """Put a small piece on a surface (a table top, a shelf board)."""
        for _ in range(attempts):
            turned = piece.moved(int(self.rng.integers(4)), np.zeros(3))
            b = _full_bounds(turned)
            if b[1, 1] - b[0, 1] > surface.clearance:
                return None
            lo_x, hi_x = surface.x0 + 0.01 - b[0, 0], surface.x1 - 0.01 - b[1, 0]
            lo_z, hi_z = surface.z0 + 0.01 - b[0, 2], surface.z1 - 0.01 - b[1, 2]
            if lo_x > hi_x or lo_z > hi_z:
                return None
            offset = np.round(np.array([self.rng.uniform(lo_x, hi_x), surface.y, self.rng.uniform(lo_z, hi_z)]), 3)
            offset[1] = surface.y
            moved = turned.moved(0, offset)
            if self._inside(_full_bounds(moved)) and self._parts_free(moved):
                return self._commit(moved, floor=False)
        return None

    def on_wall(self, piece: Piece, height: float, side: str | None = None, attempts: int = 10) -> Piece | None:
        """Hang `piece` on a wall with its bottom at `height` metres."""
        for _ in range(attempts):
            chosen = side or list(SIDES)[int(self.rng.integers(4))]
            turned = piece.moved(SIDES[chosen], np.zeros(3))
            offset = self._wall_offset(chosen, _full_bounds(turned), 0.0)
            if offset is None:
                continue
            offset = np.round(offset, 3)
            offset[1] = height
            moved = turned.moved(0, offset)
            box = _full_bounds(moved)
            others = np.array(self.floor_boxes) if self.floor_boxes else np.zeros((0, 2, 3))
            if self._inside(box) and not overlaps(box, others) and self._parts_free(moved):
                return self._commit(moved, floor=False)
        return None

    def on_ceiling(self, piece: Piece, x: float, z: float) -> Piece | None:
        """Hang `piece` (built downwards from y = 0) from the ceiling at (x, z)."""
        moved = piece.moved(0, np.round(np.array([x, self.ceiling, z]), 3))
        box = _full_bounds(moved)
        others = np.array(self.floor_boxes) if self.floor_boxes else np.zeros((0, 2, 3))
        if self._inside(box) and not overlaps(box, others) and self._parts_free(moved):
            return self._commit(moved, floor=False)
        return None

    def fixture(self, piece: Piece) -> Piece | None:
        """Fix trim (frames, baseboards) to the walls part by part, leaving out the parts that would
        cut into something already there (a staircase, a window's opening) or that clipping to the room
        left flat (a jamb beside an opening in a corner); None if no part fits."""
        taken = np.array(self.part_boxes) if self.part_boxes else np.zeros((0, 2, 3))
        free = [p for p in piece.parts if np.all(np.diff(p.bounds(), axis=0) > EPSILON)
                and self._inside(p.bounds()) and not overlaps(p.bounds(), taken)]
        return self._commit(Piece(piece.category, piece.names, free), floor=False) if free else None

    def at_wall_position(self, piece: Piece, side: str, along: float, height: float) -> Piece | None:
        """Hang `piece` centred at `along` (x for south/north walls, z for west/east) on a given wall."""
        turned = piece.moved(SIDES[side], np.zeros(3))
        b = _full_bounds(turned)
        x0, z0, x1, z1 = self.inner
        centre = (b[0] + b[1]) / 2
        if side in ("south", "north"):
            z = z0 - b[0, 2] if side == "south" else z1 - b[1, 2]
            offset = np.array([along - centre[0], height, z])
        else:
            x = x0 - b[0, 0] if side == "west" else x1 - b[1, 0]
            offset = np.array([x, height, along - centre[2]])
        moved = turned.moved(0, np.round(offset, 3))
        box = _full_bounds(moved)
        others = np.array(self.floor_boxes) if self.floor_boxes else np.zeros((0, 2, 3))
        if self._inside(box) and not overlaps(box, others) and self._parts_free(moved):
            return self._commit(moved, floor=False)
        return None


def _with_extras(piece: Piece) -> list[Piece]:
    return [piece] + [e for extra in piece.extras for e in _with_extras(extra)]


def _full_bounds(piece: Piece) -> np.ndarray:
    boxes = np.stack([p.bounds() for q in _with_extras(piece) for p in q.parts])
    return np.array([boxes[:, 0].min(0), boxes[:, 1].max(0)])


def _keep_out(opening: Opening, room: Room) -> np.ndarray:
    """The space a door swings through (0.9 m into the room) or a window's opening (wall depth only;
    its frame may touch it on every side)."""
    door = opening.kind in ("door", "entrance")
    depth = 0.9 if door else HALF_WALL + 0.02
    margin = 0.1 if door else 0.0
    inward = 1.0 if (opening.axis == "x" and abs(opening.fixed - room.z0 / 100) < 1e-9) or \
        (opening.axis == "z" and abs(opening.fixed - room.x0 / 100) < 1e-9) else -1.0
    near, far = sorted((opening.fixed, opening.fixed + inward * depth))
    top = opening.top + (0.05 if door else 0.0)
    if opening.axis == "x":
        return np.array([[opening.start - margin, opening.bottom, near], [opening.end + margin, top, far]])
    return np.array([[near, opening.bottom, opening.start - margin], [far, top, opening.end + margin]])


def placed_objects(furnisher: RoomFurnisher) -> list[Placed]:
    """Every object placed in the room, extras (cushions, sinks, TVs) as objects of their own."""
    flat = []
    for placed in furnisher.placed:
        for piece in _with_extras(placed.piece):
            flat.append(Placed(Piece(piece.category, piece.names, piece.parts, piece.surfaces), placed.region))
    return flat
