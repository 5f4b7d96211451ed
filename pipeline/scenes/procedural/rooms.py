"""What goes in each kind of room: furniture groups, then wall items, ceiling items and clutter."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pipeline.scenes.procedural import furniture as fu
from pipeline.scenes.procedural.furniture import Piece
from pipeline.scenes.procedural.geometry import Box
from pipeline.scenes.procedural.layout import Opening
from pipeline.scenes.procedural.placement import SIDES, RoomFurnisher

FRONT = {"south": np.array([0.0, 0, 1]), "north": np.array([0.0, 0, -1]), "west": np.array([1.0, 0, 0]), "east": np.array([-1.0, 0, 0])}


def _centre(piece: Piece) -> np.ndarray:
    b = piece.bounds()
    return (b[0] + b[1]) / 2


def dining_set(f: RoomFurnisher, rng: np.random.Generator, names: tuple[str, ...]) -> None:
    """A table in the middle of the room with chairs on every side that has room for one."""
    w, d = float(rng.uniform(1.1, 1.8)), float(rng.uniform(0.8, 1.0))
    placed = f.in_middle(fu.table(rng, w, d, 0.75, names), margin=0.75)
    if placed is None:
        return
    lo, hi = placed.bounds()
    chair = fu.chair(rng)
    gap = 0.05 + 0.23
    centre_z, centre_x = (lo[2] + hi[2]) / 2, (lo[0] + hi[0]) / 2
    long_x = hi[0] - lo[0] >= hi[2] - lo[2]
    span = (lo[0], hi[0]) if long_x else (lo[2], hi[2])
    count = max(1, int((span[1] - span[0]) / 0.6))
    for k in range(count):
        along = span[0] + (k + 0.5) * (span[1] - span[0]) / count
        if long_x:
            f.at(chair, 0, np.array([along, 0, lo[2] - gap]))
            f.at(chair, 2, np.array([along, 0, hi[2] + gap]))
        else:
            f.at(chair, 1, np.array([lo[0] - gap, 0, along]))
            f.at(chair, 3, np.array([hi[0] + gap, 0, along]))
    if long_x:
        f.at(chair, 1, np.array([lo[0] - gap, 0, centre_z]))
    else:
        f.at(chair, 0, np.array([centre_x, 0, lo[2] - gap]))


def desk_with_chair(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """A desk against a wall and an office chair facing it."""
    desk, side = f.against_any_wall(fu.table(rng, float(rng.uniform(1.0, 1.6)), 0.65, 0.75, ("desk", "computer desk", "office table", "table")))
    if desk is None:
        return
    position = _centre(desk) + FRONT[side] * (0.325 + 0.3)
    position[1] = 0.0
    f.at(fu.chair(rng, office=True), SIDES[side] + 2, position)
    monitor = Piece(22, ("monitor", "computer monitor", "computer screen", "display"),
                    [fu.block(-0.08, 0, -0.08, 0.08, 0.02, 0.08, "plastic", (30, 30, 32)),
                     fu.block(-0.28, 0.1, -0.03, 0.28, 0.45, 0.0, "plastic", (15, 15, 18)),
                     fu.block(-0.02, 0.02, -0.03, 0.02, 0.1, -0.01, "plastic", (30, 30, 32))])
    if desk.surfaces:
        f.on_surface(monitor, desk.surfaces[0])


def living_room(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """Sofa, coffee table, armchairs, TV, shelves, maybe a fireplace, lamp, plants and a rug."""
    f.against_wall(fu.sofa(rng, int(rng.integers(2, 4))))
    f.in_middle(fu.table(rng, float(rng.uniform(0.8, 1.2)), float(rng.uniform(0.5, 0.7)), 0.45, ("coffee table", "table")), margin=0.6)
    for _ in range(int(rng.integers(1, 3))):
        f.against_wall(fu.sofa(rng, 1))
    f.against_wall(fu.tv_stand(rng))
    f.against_wall(fu.shelf_unit(rng, float(rng.uniform(0.7, 1.2)), float(rng.uniform(1.5, 2.0)), int(rng.integers(3, 6))))
    if rng.random() < 0.4:
        f.against_wall(fu.fireplace(rng))
    f.against_wall(fu.table(rng, 0.5, 0.45, 0.55, ("side table", "end table", "table")))
    f.against_wall(fu.floor_lamp(rng))
    for _ in range(int(rng.integers(1, 3))):
        f.against_wall(fu.plant(rng, float(rng.uniform(0.6, 1.5))))
    f.in_middle(fu.rug(rng, float(rng.uniform(1.4, 2.4)), float(rng.uniform(1.0, 1.8))), margin=0.3)


def kitchen(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """Counter runs with a sink and wall cabinets, fridge, stove, a table with chairs, stools, a bin."""
    x0, z0, x1, z1 = f.inner
    for _ in range(int(rng.integers(1, 3))):
        length = min(x1 - x0, z1 - z0)
        run, side = f.against_any_wall(fu.counter(rng, float(min(length - 0.3, rng.uniform(1.6, 3.0)))))
        if run is not None:
            sink = Piece(15, ("sink", "kitchen sink"), [fu.block(-0.3, 0, -0.22, 0.3, 0.1, 0.22, "metal", fu.METALS[2]),
                                                     fu.Cylinder((0, 0, -0.26), 0.02, 0.3, "metal", fu.METALS[2])])
            f.on_surface(sink, run.surfaces[0])
            for _ in range(2):
                f.on_wall(fu.wall_item(rng, "wall cabinet"), 1.5, side)
    f.against_wall(fu.appliance(rng, "fridge"))
    f.against_wall(fu.appliance(rng, "stove"))
    dining_set(f, rng, ("table", "kitchen table", "dining table"))
    for _ in range(int(rng.integers(0, 3))):
        f.against_wall(Piece(19, ("stool", "footstool"), [fu.Cylinder((0, 0, 0), 0.18, 0.65, "wood", fu.WOODS[0])]))
    trash = Piece(39, ("trash can", "trashcan", "bin"), [fu.Cylinder((0, 0, 0), 0.15, 0.45, "plastic", (60, 60, 62))])
    f.against_wall(trash)


def bedroom(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """A bed against a wall with nightstands beside it, dresser, wardrobe, maybe a chair, plant, rug."""
    placed, side = f.against_any_wall(fu.bed(rng, bool(rng.random() < 0.7)))
    if placed is not None:
        lo, hi = placed.bounds()
        stand = fu.drawers(rng, 0.45, 0.4, 0.55, 2, 13, ("nightstand", "bedside table", "night stand"))
        turns = SIDES[side]
        for end in (0, 1):
            if side in ("south", "north"):
                x = lo[0] - 0.26 if end == 0 else hi[0] + 0.26
                z = lo[2] + 0.21 if side == "south" else hi[2] - 0.21
            else:
                z = lo[2] - 0.26 if end == 0 else hi[2] + 0.26
                x = lo[0] + 0.21 if side == "west" else hi[0] - 0.21
            f.at(stand, turns, np.array([x, 0.0, z]))
    f.against_wall(fu.drawers(rng, float(rng.uniform(0.8, 1.4)), 0.5, float(rng.uniform(0.75, 1.0)), 3, 13, ("dresser", "chest of drawers", "drawers")))
    f.against_wall(fu.tall_cabinet(rng, float(rng.uniform(0.9, 1.6)), 0.6, 2.0, 36, ("wardrobe",)))
    if rng.random() < 0.5:
        f.against_wall(fu.chair(rng))
    if rng.random() < 0.5:
        f.against_wall(fu.plant(rng, float(rng.uniform(0.5, 1.2))))
    f.in_middle(fu.rug(rng, float(rng.uniform(1.0, 1.8)), float(rng.uniform(0.7, 1.2))), margin=0.2)


def bathroom(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """Bathtub or shower, toilet, vanity with a sink and a mirror above it, towels, mat, bin."""
    f.against_wall(fu.bathtub(rng) if rng.random() < 0.5 else fu.shower(rng))
    f.against_wall(fu.toilet(rng))
    cabinet, side = f.against_any_wall(fu.vanity(rng))
    if cabinet is not None:
        f.on_wall(fu.wall_item(rng, "mirror"), 1.15, side)
    for _ in range(int(rng.integers(1, 3))):
        f.on_wall(fu.wall_item(rng, "towel"), float(rng.uniform(0.9, 1.2)))
    f.on_wall(Piece(39, ("toilet paper",), [fu.Cylinder((-0.06, 0, 0), 0.055, 0.12, "paper", fu.WHITE, "x")]), 0.7)
    f.in_middle(Piece(2, ("bath mat", "mat", "rug"), [fu.block(-0.35, 0, -0.25, 0.35, 0.01, 0.25, "carpet", fu.FABRICS[int(rng.integers(8))])]), margin=0.1)
    f.against_wall(Piece(39, ("trash can", "bin"), [fu.Cylinder((0, 0, 0), 0.12, 0.3, "metal", fu.METALS[0])]))


def office(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """Desk with chair and monitor, shelves, file cabinet, a board, plant and lamp."""
    desk_with_chair(f, rng)
    for _ in range(int(rng.integers(1, 3))):
        f.against_wall(fu.shelf_unit(rng, float(rng.uniform(0.7, 1.1)), float(rng.uniform(1.6, 2.0)), int(rng.integers(4, 6))))
    f.against_wall(fu.drawers(rng, 0.5, 0.6, 1.1, 3, 7, ("file cabinet", "cabinet")))
    f.on_wall(fu.wall_item(rng, "board"), 1.0)
    f.against_wall(fu.plant(rng, float(rng.uniform(0.6, 1.3))))
    f.against_wall(fu.floor_lamp(rng))


def dining_room(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """A table with chairs, a china cabinet, a buffet and a plant."""
    dining_set(f, rng, ("dining table", "table"))
    f.against_wall(fu.tall_cabinet(rng, float(rng.uniform(0.8, 1.4)), 0.45, float(rng.uniform(1.6, 2.0)), 7, ("china cabinet", "display cabinet", "cabinet", "showcase")))
    f.against_wall(fu.drawers(rng, float(rng.uniform(1.2, 1.8)), 0.45, 0.85, 2, 26, ("buffet",)))
    f.against_wall(fu.plant(rng, float(rng.uniform(0.8, 1.5))))


def hallway(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """A bench, a low shelf, a plant and coats on the wall."""
    f.against_wall(Piece(34, ("bench", "seat"), [fu.block(-0.6, 0.4, -0.18, 0.6, 0.46, 0.18, "wood", fu.WOODS[2])]
                         + fu.legs(1.2, 0.36, 0.4, 0.05, "wood", fu.WOODS[2]), [fu.Surface(-0.6, -0.18, 0.6, 0.18, 0.46, 0.5)]))
    f.against_wall(fu.shelf_unit(rng, float(rng.uniform(0.6, 1.0)), 1.0, 3))
    f.against_wall(fu.plant(rng, float(rng.uniform(0.5, 1.2))))
    for _ in range(int(rng.integers(1, 3))):
        f.on_wall(Piece(38, ("coat", "jacket", "hat", "scarf"), [fu.block(-0.2, 0, -0.06, 0.2, 0.8, 0.06, "fabric", fu.FABRICS[int(rng.integers(8))])]), 0.9)


def laundry_room(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """Two washing machines, a shelf, a basket and a cabinet."""
    for _ in range(2):
        f.against_wall(fu.appliance(rng, "washer"))
    f.against_wall(fu.shelf_unit(rng, 0.9, 1.8, 4))
    f.against_wall(Piece(39, ("basket", "laundry basket"), [fu.Cylinder((0, 0, 0), 0.22, 0.4, "fabric", fu.FABRICS[6])]))
    f.against_wall(fu.drawers(rng, 0.8, 0.5, 0.9, 2, 7, ("cabinet", "storage cabinet")))


RECIPES: dict[str, Callable[[RoomFurnisher, np.random.Generator], None]] = {
    "living room": living_room, "kitchen": kitchen, "bedroom": bedroom, "bathroom": bathroom, "office": office,
    "dining room": dining_room, "hallway": hallway, "laundry room": laundry_room,
}


def _wall_side(opening: Opening, f: RoomFurnisher) -> str:
    """Which of the room's walls holds `opening`."""
    room = f.room
    if opening.axis == "x":
        return "south" if abs(opening.fixed - room.z0 / 100) < 1e-9 else "north"
    return "west" if abs(opening.fixed - room.x0 / 100) < 1e-9 else "east"


# Trim: frames 6 cm wide standing 1.5 cm off the wall; baseboards thinner than the gap furniture keeps
# to the wall (placement.WALL_GAP), so a cabinet stands in front of one, never through it.
FRAME_WIDTH, FRAME_DEPTH = 0.06, 0.015
BASEBOARD_HEIGHT, BASEBOARD_DEPTH = 0.07, 0.009


def _on_wall_face(f: RoomFurnisher, side: str, start: float, end: float, bottom: float, top: float,
                  depth: float, color: tuple[int, int, int]) -> Box:
    """A box on the inside face of wall `side`, spanning [start, end] along it (clipped to the room)."""
    x0, z0, x1, z1 = f.inner
    if side in ("south", "north"):
        start, end = max(start, x0), min(end, x1)
        z = z0 if side == "south" else z1 - depth
        return fu.block(start, bottom, z, end, top, z + depth, "paint", color)
    start, end = max(start, z0), min(end, z1)
    x = x0 if side == "west" else x1 - depth
    return fu.block(x, bottom, start, x + depth, top, end, "paint", color)


def trim(f: RoomFurnisher, rng: np.random.Generator) -> None:
    """Door and window frames around every opening of the room and baseboards along its walls: the
    thin, often-seen instances that make up much of a real scan's annotations."""
    color = fu.WHITE if rng.random() < 0.7 else fu.WOODS[int(rng.integers(len(fu.WOODS)))]
    w = FRAME_WIDTH
    for opening in f.openings:
        side = _wall_side(opening, f)
        jambs = [(opening.start - w, opening.start), (opening.end, opening.end + w)]
        parts = [_on_wall_face(f, side, a, b, opening.bottom, opening.top, FRAME_DEPTH, color) for a, b in jambs]
        parts.append(_on_wall_face(f, side, opening.start - w, opening.end + w, opening.top, opening.top + w, FRAME_DEPTH, color))
        if opening.kind == "window":
            parts.append(_on_wall_face(f, side, opening.start - w, opening.end + w, opening.bottom - w, opening.bottom,
                                       FRAME_DEPTH, color))
            f.fixture(Piece(9, ("window frame", "windowframe", "windowsill"), parts))
        else:
            f.fixture(Piece(4, ("doorframe", "door frame"), parts))
    x0, z0, x1, z1 = f.inner
    boards = []
    for side, (low, high) in (("south", (x0, x1)), ("north", (x0, x1)), ("west", (z0, z1)), ("east", (z0, z1))):
        doors = sorted((o.start - w, o.end + w) for o in f.openings if o.kind != "window" and _wall_side(o, f) == side)
        for start, end in zip([low] + [b for _, b in doors], [a for a, _ in doors] + [high], strict=True):
            if end - start > 0.05:
                boards.append(_on_wall_face(f, side, start, end, 0.0, BASEBOARD_HEIGHT, BASEBOARD_DEPTH, color))
    f.fixture(Piece(1, ("baseboard", "molding", "trim", "skirting board"), boards))


def decorate(f: RoomFurnisher, rng: np.random.Generator, ceiling: float, clutter_density: float) -> None:
    """Curtains, pictures, switches, ceiling items and clutter on every surface of the room."""
    x0, z0, x1, z1 = f.inner
    if f.room.kind not in ("bathroom", "laundry room"):
        for window in [o for o in f.openings if o.kind == "window"]:
            side = _wall_side(window, f)
            curtain = fu.wall_item(rng, "curtain")
            width = curtain.bounds()[1, 0] - curtain.bounds()[0, 0]
            height = min(ceiling - 0.05, window.top + 0.15) - (curtain.bounds()[1, 1])
            beside = width / 2 + FRAME_WIDTH + 0.02
            for along in (window.start - beside, window.end + beside):
                f.at_wall_position(curtain, side, along, max(0.05, height))
    for _ in range(int(rng.integers(1, 4)) if f.room.kind != "bathroom" else 0):
        f.on_wall(fu.wall_item(rng, "picture"), float(rng.uniform(1.2, 1.6)))
    f.on_wall(fu.wall_item(rng, "switch"), 1.1)
    for _ in range(int(rng.integers(1, 4))):
        f.on_wall(fu.wall_item(rng, "outlet"), 0.3)
    if rng.random() < 0.4:
        f.on_wall(fu.wall_item(rng, "clock" if rng.random() < 0.5 else "sconce"), float(rng.uniform(1.6, 1.9)))
    centre = ((x0 + x1) / 2, (z0 + z1) / 2)
    fan = f.room.kind in ("living room", "bedroom") and rng.random() < 0.3
    f.on_ceiling(fu.ceiling_item(rng, "fan" if fan else "lamp"), *centre)
    f.on_ceiling(fu.ceiling_item(rng, "detector"), float(rng.uniform(x0 + 0.3, x1 - 0.3)), float(rng.uniform(z0 + 0.3, z1 - 0.3)))
    if rng.random() < 0.6:
        f.on_ceiling(fu.ceiling_item(rng, "vent"), float(rng.uniform(x0 + 0.3, x1 - 0.3)), float(rng.uniform(z0 + 0.3, z1 - 0.3)))
    if f.room.kind not in ("bathroom", "kitchen"):
        for _ in range(int(rng.integers(0, 4))):
            f.against_wall(fu.floor_item(rng))
    clutter_on_surfaces(f, rng, clutter_density)


def clutter_on_surfaces(f: RoomFurnisher, rng: np.random.Generator, density: float) -> None:
    """Small objects on tables, counters, shelves: about `density` per 0.1 square metres, 6 at most."""
    for surface in list(f.surfaces):
        area = (surface.x1 - surface.x0) * (surface.z1 - surface.z0)
        count = min(6, int(rng.poisson(density * area / 0.1)))
        if f.room.kind in ("bedroom", "office", "living room") and surface.y < 0.8 and rng.random() < 0.35:
            f.on_surface(fu.table_lamp(rng), surface)
        for _ in range(count):
            f.on_surface(fu.clutter(rng, surface.clearance - 0.01), surface)
