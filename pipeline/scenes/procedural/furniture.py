"""Furniture and clutter templates built from boxes, cylinders and ellipsoids.

A template returns a `Piece` in a local frame: footprint centred on the origin, standing on y = 0,
its front facing +Z (so its back goes against a wall). `surfaces` are the tops other things may
stand on; `extras` are separate objects that come with it (sofa cushions, pillows, a sink on a
vanity, a TV on its stand), in the same local frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.scenes.procedural.geometry import Box, Cylinder, Ellipsoid, Part, rotate_quarter, translate

Color = tuple[int, int, int]
WOODS: tuple[Color, ...] = ((150, 105, 65), (120, 80, 50), (185, 145, 100), (95, 65, 45), (205, 175, 135), (60, 45, 35))
FABRICS: tuple[Color, ...] = ((90, 110, 140), (150, 60, 60), (200, 190, 170), (80, 120, 90), (110, 100, 120),
                              (60, 60, 70), (190, 150, 90), (170, 170, 175))
METALS: tuple[Color, ...] = ((165, 165, 170), (90, 90, 95), (205, 205, 210), (40, 40, 45))
WHITE: Color = (235, 235, 232)


@dataclass(frozen=True)
class Surface:
    """A horizontal top at height `y` over [x0, x1] x [z0, z1], with `clearance` metres free above."""

    x0: float
    z0: float
    x1: float
    z1: float
    y: float
    clearance: float


@dataclass
class Piece:
    """One object instance before it is placed: category, raw-name choices and its solid parts."""

    category: int
    names: tuple[str, ...]
    parts: list[Part]
    surfaces: list[Surface] = field(default_factory=list)
    extras: list[Piece] = field(default_factory=list)

    def bounds(self) -> np.ndarray:
        """(2, 3) box around its own parts (extras excluded)."""
        stacked = np.stack([p.bounds() for p in self.parts])
        return np.array([stacked[:, 0].min(0), stacked[:, 1].max(0)])

    def moved(self, turns: int, offset: np.ndarray) -> Piece:
        """The piece turned by `turns` x 90 degrees about +Y, then moved by `offset`."""
        parts = [translate(rotate_quarter(p, turns), offset) for p in self.parts]
        surfaces = [_move_surface(s, turns, offset) for s in self.surfaces]
        extras = [e.moved(turns, offset) for e in self.extras]
        return Piece(self.category, self.names, parts, surfaces, extras)


def _move_surface(surface: Surface, turns: int, offset: np.ndarray) -> Surface:
    corners = np.array([[surface.x0, surface.z0], [surface.x1, surface.z1]])
    for _ in range(turns % 4):
        corners = np.stack([corners[:, 1], -corners[:, 0]], 1)
    low, high = corners.min(0), corners.max(0)
    return Surface(low[0] + offset[0], low[1] + offset[2], high[0] + offset[0], high[1] + offset[2],
                   surface.y + offset[1], surface.clearance)


def _pick(rng: np.random.Generator, options: tuple[Color, ...]) -> Color:
    return options[int(rng.integers(len(options)))]


def block(x0: float, y0: float, z0: float, x1: float, y1: float, z1: float, material: str, color: Color) -> Box:
    """A box part from its two corners."""
    return Box((x0, y0, z0), (x1, y1, z1), material, color)


def legs(w: float, d: float, h: float, size: float, material: str, color: Color) -> list[Part]:
    """Four square legs at the corners of a w x d footprint."""
    hw, hd = w / 2, d / 2
    return [block(x, 0, z, x + size, h, z + size, material, color)
            for x in (-hw, hw - size) for z in (-hd, hd - size)]


# ----------------------------------------------------------------------------------- tables/seats


def table(rng: np.random.Generator, w: float, d: float, h: float, names: tuple[str, ...], category: int = 5) -> Piece:
    """A four-legged table with a 4 cm top."""
    color = _pick(rng, WOODS)
    parts = legs(w, d, h - 0.04, 0.05, "wood", color) + [block(-w / 2, h - 0.04, -d / 2, w / 2, h, d / 2, "wood", color)]
    return Piece(category, names, parts, [Surface(-w / 2, -d / 2, w / 2, d / 2, h, 0.6)])


def chair(rng: np.random.Generator, office: bool = False) -> Piece:
    """A chair facing +Z: legs (or a pedestal), seat and back."""
    w, d = 0.46, 0.46
    if office:
        color = _pick(rng, FABRICS)
        parts: list[Part] = [Cylinder((0, 0, 0), 0.25, 0.06, "plastic", (40, 40, 45)),
                             Cylinder((0, 0.06, 0), 0.03, 0.36, "metal", (120, 120, 125))]
        names = ("office chair", "desk chair", "swivel chair", "computer chair")
        w, d = 0.5, 0.5
    else:
        color = _pick(rng, WOODS)
        parts = legs(w, d, 0.42, 0.04, "wood", color)
        names = ("chair", "dining chair", "wooden chair")
    parts.append(block(-w / 2, 0.42, -d / 2, w / 2, 0.47, d / 2, "fabric" if office else "wood", color))
    parts.append(block(-w / 2, 0.47, -d / 2, w / 2, 0.92, -d / 2 + 0.05, "fabric" if office else "wood", color))
    return Piece(3, names, parts)


def sofa(rng: np.random.Generator, seats: int) -> Piece:
    """A sofa (or an armchair for one seat) with cushions leaning on its back as separate objects."""
    seat_w = 0.62
    w, d = seats * seat_w + 0.3, 0.88
    color = _pick(rng, FABRICS)
    parts: list[Part] = [
        block(-w / 2, 0.0, -d / 2, w / 2, 0.42, d / 2, "fabric", color),
        block(-w / 2, 0.42, -d / 2, w / 2, 0.85, -d / 2 + 0.2, "fabric", color),
        block(-w / 2, 0.42, -d / 2 + 0.2, -w / 2 + 0.15, 0.62, d / 2, "fabric", color),
        block(w / 2 - 0.15, 0.42, -d / 2 + 0.2, w / 2, 0.62, d / 2, "fabric", color),
    ]
    cushions = []
    for k in range(seats if seats > 1 else int(rng.integers(0, 2))):
        x = -w / 2 + 0.15 + (k + 0.5) * seat_w
        tint = _pick(rng, FABRICS)
        cushions.append(Piece(8, ("pillow", "cushion", "throw pillow", "couch pillow"),
                              [block(x - 0.2, 0.42, -d / 2 + 0.2, x + 0.2, 0.8, -d / 2 + 0.32, "fabric", tint)]))
    if seats == 1:
        return Piece(3, ("armchair", "sofa chair", "lounge chair", "easy chair", "recliner"), parts, [], cushions)
    return Piece(10, ("couch", "sofa", "loveseat"), parts, [], cushions)


def bed(rng: np.random.Generator, double: bool) -> Piece:
    """Bed frame, mattress and headboard (against the wall), with pillows as separate objects."""
    w, d = (rng.uniform(1.4, 1.8) if double else 0.95), 2.05
    wood = _pick(rng, WOODS)
    sheet = _pick(rng, FABRICS)
    parts: list[Part] = [
        block(-w / 2, 0, -d / 2 + 0.06, w / 2, 0.3, d / 2, "wood", wood),
        block(-w / 2 + 0.02, 0.3, -d / 2 + 0.06, w / 2 - 0.02, 0.55, d / 2 - 0.02, "fabric", sheet),
        block(-w / 2, 0, -d / 2, w / 2, 1.05, -d / 2 + 0.06, "wood", wood),
    ]
    pillows = []
    count = 2 if double else 1
    for k in range(count):
        x = -w / 2 + (k + 0.5) * w / count
        pillows.append(Piece(8, ("pillow", "pillows", "cushion"),
                             [block(x - 0.3, 0.55, -d / 2 + 0.1, x + 0.3, 0.7, -d / 2 + 0.5, "fabric", WHITE)]))
    return Piece(11, ("bed",), parts, [], pillows)


# -------------------------------------------------------------------------------------- storage


def drawers(rng: np.random.Generator, w: float, d: float, h: float, rows: int, category: int,
            names: tuple[str, ...], material: str = "wood") -> Piece:
    """A box of drawers (nightstand, dresser, kitchen cabinet) with slightly proud drawer fronts."""
    color = _pick(rng, WOODS) if material == "wood" else WHITE
    parts: list[Part] = [block(-w / 2, 0, -d / 2, w / 2, h, d / 2 - 0.02, material, color)]
    front = tuple(int(c * 0.85) for c in color)
    step = (h - 0.1) / rows
    for r in range(rows):
        y0 = 0.08 + r * step
        parts.append(block(-w / 2 + 0.03, y0, d / 2 - 0.02, w / 2 - 0.03, y0 + step - 0.03, d / 2, material, front))  # type: ignore[arg-type]
    return Piece(category, names, parts, [Surface(-w / 2, -d / 2, w / 2, d / 2 - 0.02, h, 0.5)])


def shelf_unit(rng: np.random.Generator, w: float, h: float, boards: int) -> Piece:
    """An open bookshelf: sides, back and `boards` shelves, each a surface for clutter."""
    d = 0.32
    color = _pick(rng, WOODS)
    t = 0.025
    parts: list[Part] = [
        block(-w / 2, 0, -d / 2, -w / 2 + t, h, d / 2, "wood", color),
        block(w / 2 - t, 0, -d / 2, w / 2, h, d / 2, "wood", color),
        block(-w / 2 + t, 0, -d / 2, w / 2 - t, h, -d / 2 + 0.01, "wood", color),
    ]
    surfaces = []
    gap = (h - t) / boards
    for k in range(boards + 1):
        y = min(k * gap, h - t)
        parts.append(block(-w / 2 + t, y, -d / 2 + 0.01, w / 2 - t, y + t, d / 2, "wood", color))
        if k < boards:
            surfaces.append(Surface(-w / 2 + t, -d / 2 + 0.01, w / 2 - t, d / 2, y + t, gap - t - 0.01))
    return Piece(31, ("shelf", "bookshelf", "shelves", "bookcase", "shelving"), parts, surfaces)


def tall_cabinet(rng: np.random.Generator, w: float, d: float, h: float, category: int, names: tuple[str, ...]) -> Piece:
    """A closed tall cabinet or wardrobe with two door panels and handles."""
    color = _pick(rng, WOODS + (WHITE,))
    parts: list[Part] = [block(-w / 2, 0, -d / 2, w / 2, h, d / 2 - 0.02, "wood", color)]
    for side in (-1, 1):
        x0, x1 = sorted((0.0, side * (w / 2 - 0.02)))
        parts.append(block(x0 + 0.005, 0.05, d / 2 - 0.02, x1 - 0.005, h - 0.05, d / 2, "wood", color))
        parts.append(block(side * 0.06 - 0.01, h * 0.5 - 0.1, d / 2, side * 0.06 + 0.01, h * 0.5 + 0.1, d / 2 + 0.02, "metal", METALS[0]))
    return Piece(category, names, parts, [Surface(-w / 2, -d / 2, w / 2, d / 2 - 0.02, h, 0.3)])


def counter(rng: np.random.Generator, w: float) -> Piece:
    """A kitchen counter run: cabinet base and a stone top (a surface for appliances and clutter)."""
    d, h = 0.62, 0.9
    base = _pick(rng, WOODS + (WHITE,))
    top = _pick(rng, ((60, 60, 62), (210, 205, 195), (150, 140, 130)))
    parts: list[Part] = [block(-w / 2, 0, -d / 2, w / 2, h - 0.04, d / 2 - 0.04, "wood", base),
                         block(-w / 2, h - 0.04, -d / 2, w / 2, h, d / 2, "stone", top)]
    return Piece(26, ("counter", "kitchen counter", "countertop", "kitchen island"), parts, [Surface(-w / 2, -d / 2, w / 2, d / 2, h, 0.6)])


# ----------------------------------------------------------------------------------- appliances


def appliance(rng: np.random.Generator, kind: str) -> Piece:
    """Fridge, stove or washing machine: a box with a handle, burners or a round door."""
    metal = _pick(rng, METALS[:3] + (WHITE,))
    if kind == "fridge":
        w, d, h = 0.72, 0.7, 1.8
        parts: list[Part] = [block(-w / 2, 0, -d / 2, w / 2, h, d / 2, "metal", metal),
                             block(w / 2 - 0.08, 0.9, d / 2, w / 2 - 0.06, 1.5, d / 2 + 0.04, "metal", METALS[1])]
        return Piece(37, ("refrigerator", "fridge"), parts, [Surface(-w / 2, -d / 2, w / 2, d / 2, h, 0.3)])
    if kind == "stove":
        w, d, h = 0.6, 0.62, 0.9
        parts = [block(-w / 2, 0, -d / 2, w / 2, h, d / 2, "metal", metal)]
        parts += [Cylinder((x, h, z), 0.09, 0.01, "metal", METALS[3]) for x in (-0.14, 0.14) for z in (-0.14, 0.14)]
        return Piece(37, ("stove", "oven", "range"), parts)
    w, d, h = 0.6, 0.6, 0.85
    parts = [block(-w / 2, 0, -d / 2, w / 2, h, d / 2, "plastic", WHITE),
             Cylinder((0, 0.4, d / 2), 0.2, 0.02, "glass", (60, 70, 80), "z")]
    return Piece(37, ("washing machine", "clothes dryer", "dryer", "laundry machine"), parts, [Surface(-w / 2, -d / 2, w / 2, d / 2, h, 0.4)])


def toilet(rng: np.random.Generator) -> Piece:
    """Tank against the wall, round bowl and a lid."""
    parts: list[Part] = [block(-0.2, 0.4, -0.36, 0.2, 0.8, -0.18, "ceramic", WHITE),
                         Cylinder((0, 0, 0.02), 0.18, 0.42, "ceramic", WHITE),
                         block(-0.19, 0.42, -0.18, 0.19, 0.45, 0.2, "ceramic", WHITE)]
    return Piece(18, ("toilet",), parts)


def bathtub(rng: np.random.Generator) -> Piece:
    """A hollow tub: floor and four rims."""
    w, d, h, t = 1.6, 0.75, 0.55, 0.08
    parts: list[Part] = [block(-w / 2, 0, -d / 2, w / 2, 0.1, d / 2, "ceramic", WHITE),
                         block(-w / 2, 0.1, -d / 2, w / 2, h, -d / 2 + t, "ceramic", WHITE),
                         block(-w / 2, 0.1, d / 2 - t, w / 2, h, d / 2, "ceramic", WHITE),
                         block(-w / 2, 0.1, -d / 2 + t, -w / 2 + t, h, d / 2 - t, "ceramic", WHITE),
                         block(w / 2 - t, 0.1, -d / 2 + t, w / 2, h, d / 2 - t, "ceramic", WHITE)]
    return Piece(25, ("bathtub", "tub"), parts)


def shower(rng: np.random.Generator) -> Piece:
    """A shower tray with two glass walls."""
    s = 0.9
    parts: list[Part] = [block(-s / 2, 0, -s / 2, s / 2, 0.08, s / 2, "ceramic", WHITE),
                         block(-s / 2, 0.08, s / 2 - 0.02, s / 2, 2.0, s / 2, "glass", (190, 210, 220)),
                         block(s / 2 - 0.02, 0.08, -s / 2, s / 2, 2.0, s / 2 - 0.02, "glass", (190, 210, 220))]
    return Piece(23, ("shower", "shower wall"), parts)


def vanity(rng: np.random.Generator) -> Piece:
    """A bathroom cabinet with a sink (basin and faucet) on top as a separate object."""
    cabinet = drawers(rng, 0.8, 0.5, 0.8, 2, 7, ("bathroom cabinet", "sink cabinet", "bath cabinet", "cabinet"))
    sink = Piece(15, ("sink", "bathroom sink", "washbasin"),
                 [block(-0.25, 0.8, -0.18, 0.25, 0.92, 0.18, "ceramic", WHITE),
                  Cylinder((0, 0.92, -0.2), 0.02, 0.2, "metal", METALS[2])])
    cabinet.surfaces = []
    return Piece(cabinet.category, cabinet.names, cabinet.parts, [], [sink])


def tv_stand(rng: np.random.Generator) -> Piece:
    """A low cabinet with a flat TV on a foot standing on it."""
    w = float(rng.uniform(1.2, 1.8))
    stand = drawers(rng, w, 0.45, 0.5, 1, 36, ("tv stand", "tv cabinet", "television table"))
    size = float(rng.uniform(0.9, min(1.4, w - 0.1)))
    tv = Piece(22, ("tv", "television", "display"),
               [block(-0.15, 0.5, -0.12, 0.15, 0.52, 0.08, "plastic", (30, 30, 32)),
                Cylinder((0, 0.52, -0.05), 0.02, 0.1, "metal", (30, 30, 32)),
                block(-size / 2, 0.62, -0.08, size / 2, 0.62 + size * 0.58, -0.03, "plastic", (15, 15, 18))])
    surfaces = [Surface(-w / 2, -0.225, w / 2, 0.205, 0.5, 0.4)]  # the TV's parts are obstacles for clutter
    return Piece(stand.category, stand.names, stand.parts, surfaces, [tv])


def fireplace(rng: np.random.Generator) -> Piece:
    """A stone fireplace with a dark firebox and a mantel shelf (a surface)."""
    w, d, h = float(rng.uniform(1.2, 1.6)), 0.4, 1.1
    stone = _pick(rng, ((150, 140, 130), (180, 170, 160), (120, 100, 90)))
    parts: list[Part] = [block(-w / 2, 0, -d / 2, -0.35, h - 0.08, d / 2, "stone", stone),
                         block(0.35, 0, -d / 2, w / 2, h - 0.08, d / 2, "stone", stone),
                         block(-0.35, 0.75, -d / 2, 0.35, h - 0.08, d / 2, "stone", stone),
                         block(-0.35, 0, -d / 2, 0.35, 0.75, -d / 2 + 0.1, "stone", (30, 25, 25)),
                         block(-w / 2 - 0.05, h - 0.08, -d / 2, w / 2 + 0.05, h, d / 2 + 0.05, "wood", _pick(rng, WOODS))]
    return Piece(27, ("fireplace", "mantel"), parts, [Surface(-w / 2, -d / 2, w / 2, d / 2 + 0.05, h, 0.5)])


# ---------------------------------------------------------------------------- decor and lighting


def plant(rng: np.random.Generator, height: float) -> Piece:
    """A pot with an ellipsoid of foliage."""
    pot_r = max(0.06, height * 0.16)
    pot_h = max(0.08, height * 0.3)
    green = _pick(rng, ((60, 110, 50), (80, 130, 60), (45, 95, 55), (100, 140, 70)))
    leaf_r = pot_r * 1.6
    parts: list[Part] = [Cylinder((0, 0, 0), pot_r, pot_h, "ceramic", _pick(rng, ((170, 90, 60), WHITE, (60, 60, 65)))),
                         Ellipsoid((0, pot_h + (height - pot_h) / 2, 0), (leaf_r, (height - pot_h) / 2, leaf_r), "leaf", green)]
    return Piece(14, ("plant", "potted plant", "flowers", "flower"), parts)


def floor_lamp(rng: np.random.Generator) -> Piece:
    """Base, pole and shade."""
    shade = _pick(rng, ((240, 230, 200), WHITE, (200, 180, 150)))
    parts: list[Part] = [Cylinder((0, 0, 0), 0.15, 0.03, "metal", METALS[1]),
                         Cylinder((0, 0.03, 0), 0.015, 1.3, "metal", METALS[1]),
                         Cylinder((0, 1.33, 0), 0.2, 0.28, "fabric", shade)]
    return Piece(28, ("floor lamp", "lamp", "light"), parts)


def table_lamp(rng: np.random.Generator) -> Piece:
    """A small lamp for a table or nightstand."""
    shade = _pick(rng, ((240, 230, 200), WHITE, (200, 180, 150)))
    parts: list[Part] = [Cylinder((0, 0, 0), 0.07, 0.2, "ceramic", _pick(rng, FABRICS)),
                         Cylinder((0, 0.2, 0), 0.13, 0.18, "fabric", shade)]
    return Piece(28, ("table lamp", "lamp", "bedside lamp", "desk lamp"), parts)


def rug(rng: np.random.Generator, w: float, d: float) -> Piece:
    """A 1 cm carpet lying on the floor."""
    return Piece(2, ("rug", "carpet", "mat"), [block(-w / 2, 0, -d / 2, w / 2, 0.01, d / 2, "carpet", _pick(rng, FABRICS))])


def wall_item(rng: np.random.Generator, kind: str) -> Piece:
    """Something hung on a wall, back on z = -depth/2 (the wall): picture, mirror, clock, ..."""
    if kind == "picture":
        w, h = float(rng.uniform(0.3, 1.2)), float(rng.uniform(0.3, 0.9))
        art = tuple(int(c) for c in rng.integers(40, 230, 3))
        parts: list[Part] = [block(-w / 2, 0, -0.015, w / 2, h, 0.015, "wood", _pick(rng, WOODS)),
                             block(-w / 2 + 0.04, 0.04, 0.015, w / 2 - 0.04, h - 0.04, 0.02, "paint", art)]  # type: ignore[arg-type]
        return Piece(6, ("picture", "painting", "photo", "art", "poster", "picture frame"), parts)
    if kind == "mirror":
        w, h = float(rng.uniform(0.5, 0.9)), float(rng.uniform(0.6, 1.0))
        return Piece(21, ("mirror", "bathroom mirror", "wall mirror"), [block(-w / 2, 0, -0.015, w / 2, h, 0.015, "glass", (200, 210, 215))])
    if kind == "towel":
        w, h = float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.4, 0.8))
        return Piece(20, ("towel", "bath towel", "towels"), [block(-w / 2, 0, -0.02, w / 2, h, 0.02, "fabric", _pick(rng, FABRICS + (WHITE,)))])
    if kind == "board":
        w, h = float(rng.uniform(0.8, 1.5)), float(rng.uniform(0.6, 1.0))
        return Piece(35, ("board", "panel"), [block(-w / 2, 0, -0.01, w / 2, h, 0.01, "plastic", WHITE)])
    if kind == "wall cabinet":
        w = float(rng.uniform(0.6, 1.2))
        piece = drawers(rng, w, 0.35, 0.7, 1, 7, ("kitchen cabinet", "wall cabinet", "kitchen upper cabinet", "cabinet", "cupboard"))
        return Piece(piece.category, piece.names, piece.parts)
    if kind == "curtain":
        w, h = float(rng.uniform(0.3, 0.5)), float(rng.uniform(1.6, 2.0))
        return Piece(12, ("curtain", "curtains", "window curtain"), [block(-w / 2, 0, -0.03, w / 2, h, 0.03, "fabric", _pick(rng, FABRICS))])
    if kind == "sconce":
        return Piece(28, ("wall sconce", "sconce", "wall lamp", "wall light"), [block(-0.06, 0, -0.05, 0.06, 0.2, 0.05, "metal", (230, 220, 190))])
    if kind == "switch":
        return Piece(39, ("light switch",), [block(-0.04, 0, -0.005, 0.04, 0.12, 0.005, "plastic", WHITE)])
    if kind == "outlet":
        return Piece(39, ("outlet", "electric outlet", "socket", "power outlet"),
                     [block(-0.04, 0, -0.005, 0.04, 0.08, 0.005, "plastic", WHITE)])
    if kind == "clock":
        return Piece(39, ("clock",), [Cylinder((0, 0.15, -0.02), 0.15, 0.04, "plastic", _pick(rng, (WHITE, (30, 30, 30))), "z")])
    raise ValueError(f"unknown wall item {kind!r}")


def ceiling_item(rng: np.random.Generator, kind: str) -> Piece:
    """Something hanging from the ceiling; local y = 0 is the ceiling, the piece extends downwards."""
    if kind == "lamp":
        parts: list[Part] = [Cylinder((0, -0.3, 0), 0.01, 0.3, "metal", METALS[1]),
                             Ellipsoid((0, -0.4, 0), (0.22, 0.12, 0.22), "glass", (245, 240, 220))]
        return Piece(28, ("ceiling light", "chandelier", "ceiling lamp", "light fixture", "light"), parts)
    if kind == "fan":
        parts = [Cylinder((0, -0.3, 0), 0.1, 0.3, "metal", METALS[0]),
                 block(-0.6, -0.32, -0.06, 0.6, -0.3, 0.06, "wood", _pick(rng, WOODS)),
                 block(-0.06, -0.32, -0.6, 0.06, -0.3, 0.6, "wood", _pick(rng, WOODS))]
        return Piece(39, ("ceiling fan",), parts)
    if kind == "detector":
        return Piece(39, ("firealarm", "smoke detector", "smoke alarm"), [Cylinder((0, -0.04, 0), 0.06, 0.04, "plastic", WHITE)])
    if kind == "vent":
        return Piece(40, ("vent",), [block(-0.15, -0.02, -0.1, 0.15, 0, 0.1, "metal", METALS[2])])
    raise ValueError(f"unknown ceiling item {kind!r}")


def clutter(rng: np.random.Generator, max_height: float) -> Piece:
    """A small object for a table, counter or shelf: a box, stack, bottle, bowl or vase (name chosen later)."""
    color = tuple(int(c) for c in rng.integers(30, 240, 3))
    shape = int(rng.integers(4))
    height = float(min(max_height, rng.uniform(0.05, 0.35)))
    if shape == 0:
        w, d = rng.uniform(0.08, 0.35, 2)
        parts: list[Part] = [block(-w / 2, 0, -d / 2, w / 2, height, d / 2, "plastic", color)]  # type: ignore[arg-type]
    elif shape == 1:
        r = float(rng.uniform(0.03, 0.12))
        parts = [Cylinder((0, 0, 0), r, height, "ceramic", color)]  # type: ignore[arg-type]
    elif shape == 2:
        r = float(rng.uniform(0.04, 0.09))
        neck = min(height * 0.3, 0.08)
        parts = [Cylinder((0, 0, 0), r, height - neck, "glass", color),  # type: ignore[arg-type]
                 Cylinder((0, height - neck, 0), r * 0.35, neck, "glass", color)]  # type: ignore[arg-type]
    else:
        w, d = rng.uniform(0.12, 0.3, 2)
        layers = max(1, int(height / 0.04))
        parts = [block(-w / 2, k * 0.04, -d / 2, w / 2, (k + 1) * 0.04, d / 2, "paint",
                      tuple(int(c) for c in rng.integers(30, 240, 3))) for k in range(min(layers, 6))]  # type: ignore[arg-type]
    return Piece(39, (), parts)


def floor_item(rng: np.random.Generator) -> Piece:
    """Something left on the floor by a wall: a box, basket, bag, shoes or a toy."""
    return Piece(39, ("box", "boxes", "basket", "bag", "shoes", "toy", "backpack"), clutter(rng, 0.45).parts)
