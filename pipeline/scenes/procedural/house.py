"""Generate a furnished house from a seed: layout -> structure -> trim -> furniture -> clutter -> mesh.

Deterministic: one numpy generator seeded from the house seed drives every choice, in a fixed
order, and the tessellation is pure numpy; the same seed and options give the same arrays (and so
byte-identical files). `detail` sets the triangle budget, about 1 M x detail triangles (0.05 -> 50 k,
1.0 -> 1 M), mostly by cutting large faces into smaller cells and by the segments of round shapes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.scenes.categories import category_of
from pipeline.scenes.procedural import layout as lay
from pipeline.scenes.procedural import procedural_scene_id
from pipeline.scenes.procedural import stairs
from pipeline.scenes.procedural.furniture import Piece
from pipeline.scenes.procedural.geometry import (Box, Cylinder, Ellipsoid, MeshAccumulator, add_boxes, add_cylinders,
                                                 add_ellipsoids, box_triangle_count)
from pipeline.scenes.procedural.placement import Placed, RoomFurnisher, placed_objects
from pipeline.scenes.procedural.rooms import RECIPES, decorate, trim
from pipeline.scenes.procedural.vocabulary import choose_name, clutter_name
from pipeline.scenes.scene import Scene, SceneError, SceneObject

TRIANGLES_AT_FULL_DETAIL = 1_000_000
# Odd multiplier: k -> k * M mod 2^24 is a bijection, so ids are distinct, non-zero and spread over
# the colour cube (the HM3DSem files paint each object with its id as 0xRRGGBB).
_ID_MULTIPLIER = 0x9E3779B1

WALL_COLORS = ((236, 232, 222), (222, 228, 232), (240, 226, 206), (210, 222, 206), (230, 214, 214), (245, 245, 240))
FLOOR_STYLE = {"kitchen": "tile", "bathroom": "tile", "laundry room": "tile", "hallway": "wood",
               "living room": "wood", "dining room": "wood", "bedroom": "carpet", "office": "wood"}
FLOOR_COLORS = {"tile": ((200, 196, 188), (150, 150, 155), (220, 215, 205)), "wood": ((160, 115, 70), (185, 140, 95), (120, 85, 55)),
                "carpet": ((150, 140, 125), (120, 125, 135), (170, 160, 150))}


def object_id(index: int) -> int:
    """The id of the index-th object (1-based) of a house: a distinct 24-bit colour, never 0."""
    return (index * _ID_MULTIPLIER) & 0xFFFFFF


@dataclass
class HouseObject:
    """One object instance of a planned house (world frame), before tessellation."""

    object_id: int
    raw_name: str
    category: int
    region: int
    piece: Piece


@dataclass
class HousePlan:
    """A house before tessellation: its (ground) layout, every storey's, and every object with its solid parts.

    Upper-storey rooms have indices after the ground floor's; their objects are already lifted by the
    storey height.
    """

    seed: int
    layout: lay.Layout
    objects: list[HouseObject]
    storeys: list[lay.Layout]


def _pick(rng: np.random.Generator, options: tuple) -> tuple:
    return options[int(rng.integers(len(options)))]


def _structure(layout: lay.Layout, rng: np.random.Generator, floor_hole: tuple | None = None,
               ceiling_hole: tuple | None = None) -> list[Placed]:
    """Wall, floor and ceiling objects of every room, window panes and the entrance door.

    The hallway's floor or ceiling leaves out `floor_hole` / `ceiling_hole` (the stairwell).
    """
    placed = []
    ceiling_color = (244, 244, 240)
    for room in layout.rooms:
        style = FLOOR_STYLE.get(room.kind, "wood")
        wall_material = "tile" if room.kind == "bathroom" else "paint"
        walls = lay.room_walls(room, layout, wall_material, _pick(rng, WALL_COLORS))
        in_hall = room.index == layout.hallway
        floor = lay.slab_boxes(room, -lay.SLAB, 0.0, floor_hole if in_hall else None, style, _pick(rng, FLOOR_COLORS[style]))
        ceiling = lay.slab_boxes(room, layout.ceiling, layout.ceiling + lay.SLAB, ceiling_hole if in_hall else None,
                                 "paint", ceiling_color)
        placed.append(Placed(Piece(1, ("wall",), list(walls)), room.index))
        placed.append(Placed(Piece(2, ("floor",), list(floor)), room.index))
        placed.append(Placed(Piece(17, ("ceiling",), list(ceiling)), room.index))
    for opening in layout.openings:
        if opening.kind == "window":
            placed.append(Placed(Piece(9, ("window",), [lay.window_pane(opening)]), opening.rooms[0]))
        elif opening.kind == "entrance":
            placed.append(Placed(Piece(4, ("door",), [lay.entrance_leaf(opening)]), opening.rooms[0]))
    return placed


def _furnish(seed: int, layout: lay.Layout, clutter_density: float, reserved: dict[int, list[Piece]]) -> list[Placed]:
    """Furniture, decoration and clutter of every room; `reserved` pieces (stairs, railings) go first."""
    placed = []
    for room in layout.rooms:
        # One generator per room, and clutter last in each room: the clutter density (which follows
        # `detail`) changes how many small things there are, never where the furniture stands.
        room_rng = np.random.default_rng([seed, 0x40C5E, room.index + 1])
        furnisher = RoomFurnisher(room, layout.openings, layout.ceiling, room_rng)
        for piece in reserved.get(room.index, []):
            furnisher.reserve(piece)
        trim(furnisher, room_rng)
        RECIPES[room.kind](furnisher, room_rng)
        decorate(furnisher, room_rng, layout.ceiling, clutter_density)
        placed += placed_objects(furnisher)
    return placed


def _keep_out(x0: float, y0: float, z0: float, x1: float, y1: float, z1: float) -> Piece:
    """An invisible reserved volume (category 0 pieces are dropped before tessellation)."""
    return Piece(0, (), [Box((x0, y0, z0), (x1, y1, z1), "paint", (0, 0, 0))])


def _two_storeys(seed: int, rng: np.random.Generator, min_rooms: int, max_rooms: int,
                 clutter_density: float) -> tuple[list[lay.Layout], list[Placed]]:
    """Ground and upper storey on one footprint, joined by stairs in a wide hallway."""
    ceiling = round(float(rng.uniform(2.5, 2.8)), 2)
    # Every storey has a hallway plus at least two rooms; the footprint fits the larger storey.
    fewest = max(min_rooms, 3)
    counts = [int(c) for c in rng.integers(fewest, max(max_rooms, fewest) + 1, size=2)]
    area = max(counts) * rng.uniform(15.0, 20.0)
    width = max(int(round(np.sqrt(area * rng.uniform(1.3, 1.7)) * 10)) * 10, 800)
    depth = max(int(round(area / (width / 100.0) * 10)) * 10, 2 * lay.MIN_SIDE_CM + stairs.HALLWAY_CM[1])
    footprint = (0, 0, width, depth)
    wide = int(rng.integers(stairs.HALLWAY_CM[0] // 10, stairs.HALLWAY_CM[1] // 10 + 1)) * 10
    front = int(round((depth - wide) * rng.uniform(0.42, 0.58) / 10)) * 10
    front = min(max(front, lay.MIN_SIDE_CM), depth - wide - lay.MIN_SIDE_CM)
    strip = (front, front + wide)
    well = stairs.plan_stairwell(width, strip[0], ceiling)
    avoid = [("x", strip[0], *stairs.door_free_span(well))]
    ground = lay.make_layout(rng, fewest, counts[0], footprint, strip, 0, avoid, ceiling, count=counts[0])
    upper = lay.make_layout(rng, fewest, counts[1], footprint, strip, len(ground.rooms), avoid, ceiling,
                            entrance=False, count=counts[1])
    stair = Piece(16, ("stairs", "stair", "staircase", "steps"), stairs.stair_parts(well))
    railing = Piece(30, ("railing", "handrail", "banister", "stair railing"), stairs.railing_parts(well))
    # Keep the foot of the stairs, the hole upstairs and the top landing free of furniture.
    foot = _keep_out(well.x0 - stairs.LANDING, 0.0, well.z0, well.x0, 0.3, well.z1)
    hole = _keep_out(well.x0, -1.0, well.z0, well.x1, upper.ceiling, well.z1)
    top = _keep_out(well.x1, 0.0, well.z0, well.x1 + stairs.LANDING - 0.01, 0.3, well.z1)
    placed = _structure(ground, rng, ceiling_hole=well.hole)
    placed += _furnish(seed, ground, clutter_density, {ground.hallway: [stair, foot]})  # type: ignore[dict-item]
    upstairs = _structure(upper, rng, floor_hole=well.hole)
    upstairs += _furnish(seed, upper, clutter_density, {upper.hallway: [railing, hole, top]})  # type: ignore[dict-item]
    lift = np.array([0.0, stairs.storey_height(ceiling), 0.0])
    placed += [Placed(item.piece.moved(0, lift), item.region) for item in upstairs]
    return [ground, upper], [item for item in placed if item.piece.category != 0]


def plan_house(seed: int, min_rooms: int = 3, max_rooms: int = 8, clutter_density: float = 1.0, floors: int = 1) -> HousePlan:
    """Lay out and furnish the house of `seed` (no tessellation yet); two storeys are joined by stairs."""
    rng = np.random.default_rng([seed, 0x40C5E])
    if floors == 2:
        storeys, placed = _two_storeys(seed, rng, min_rooms, max_rooms, clutter_density)
    else:
        layout = lay.make_layout(rng, min_rooms, max_rooms)
        storeys = [layout]
        placed = _structure(layout, rng) + _furnish(seed, layout, clutter_density, {})
    objects = []
    for index, item in enumerate(placed, start=1):
        name_rng = np.random.default_rng([seed, 0x4A3E, index])
        if item.piece.names:
            name, category = choose_name(name_rng, item.piece.category, item.piece.names), item.piece.category
        else:
            name, category = clutter_name(name_rng)
        objects.append(HouseObject(object_id(index), name, category, item.region, item.piece))
    return HousePlan(seed, storeys[0], objects, storeys)


def _cell_for_budget(boxes: list[Box], budget: int) -> float:
    """The largest cell size whose box tessellation stays within `budget` triangles (bisection)."""
    low, high = 0.01, 20.0
    if box_triangle_count(boxes, high) >= budget:
        return high
    for _ in range(40):
        middle = (low + high) / 2
        if box_triangle_count(boxes, middle) > budget:
            low = middle
        else:
            high = middle
    return high


def tessellate(plan: HousePlan, detail: float, scene_id: str) -> Scene:
    """Turn a planned house into a Scene with ~1 M x detail triangles and vertex colours."""
    boxes, box_ids, cylinders, cylinder_ids, ellipsoids, ellipsoid_ids = [], [], [], [], [], []
    for obj in plan.objects:
        for part in obj.piece.parts:
            if isinstance(part, Box):
                boxes.append(part)
                box_ids.append(obj.object_id)
            elif isinstance(part, Cylinder):
                cylinders.append(part)
                cylinder_ids.append(obj.object_id)
            elif isinstance(part, Ellipsoid):
                ellipsoids.append(part)
                ellipsoid_ids.append(obj.object_id)
    segments = int(round(8 + 40 * detail))
    round_triangles = len(cylinders) * 4 * segments + len(ellipsoids) * segments * (2 * max(segments // 2, 2) - 2)
    budget = max(int(TRIANGLES_AT_FULL_DETAIL * detail) - round_triangles, 0)
    cell = _cell_for_budget(boxes, budget)
    mesh = MeshAccumulator()
    add_boxes(mesh, boxes, box_ids, cell)
    add_cylinders(mesh, cylinders, cylinder_ids, segments)
    add_ellipsoids(mesh, ellipsoids, ellipsoid_ids, segments)
    arrays = mesh.build()
    objects = {o.object_id: SceneObject(o.object_id, o.raw_name, category_of(o.raw_name) or o.category, o.region)
               for o in plan.objects}
    return Scene(scene_id, arrays.vertices, arrays.faces, arrays.face_object_ids, objects,
                 vertex_colors=arrays.vertex_colors, source="procedural")


def generate_house(seed: int, detail: float = 0.1, min_rooms: int = 3, max_rooms: int = 8, floors: int = 1) -> Scene:
    """The furnished house of `seed` as a Scene (id `proc-<seed:06d>`), deterministic."""
    if floors not in (1, 2):
        raise SceneError(f"procedural house {seed}: floors={floors}; use 1 or 2 (scenes.procedural.floors)")
    if not 0 < detail <= 1:
        raise SceneError(f"procedural house {seed}: detail {detail} outside (0, 1]; use 0.05 (50 k) to 1.0 (1 M triangles)")
    plan = plan_house(seed, min_rooms, max_rooms, clutter_density=0.8 + 0.7 * detail, floors=floors)
    return tessellate(plan, detail, procedural_scene_id(seed))
