"""Scenes built from boxes (rooms, thin walls, doorways, furniture) for the plan tests and benchmarks.

They have known geometry, so tests can state what must be navigable: a wall 5 mm thick, a doorway of a
given width, two rooms without a door. World frame +Y up, floor top at y = 0, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from pipeline.scenes.scene import Scene, SceneObject

WALL = 1
FLOOR = 2
CEILING = 17
FURNITURE = 39


@dataclass(frozen=True)
class Box:
    """An axis-aligned box from `low` to `high` (x, y, z) labelled with an mpcat40 category."""

    low: tuple[float, float, float]
    high: tuple[float, float, float]
    category: int = WALL


def scene_from_boxes(scene_id: str, boxes: list[Box], subdivisions: int = 0) -> Scene:
    """A Scene whose objects are the boxes (object id = box index + 1), faces wound outwards.

    `subdivisions` splits every triangle into 4 that many times (to test meshes of a given size).
    """
    vertices, faces, labels = [], [], []
    offset = 0
    for index, box in enumerate(boxes):
        low, high = np.asarray(box.low, dtype=np.float64), np.asarray(box.high, dtype=np.float64)
        mesh = trimesh.creation.box(extents=high - low)
        mesh.apply_translation((low + high) / 2.0)
        v, f = mesh.vertices, mesh.faces
        for _ in range(subdivisions):
            v, f = trimesh.remesh.subdivide(v, f)
        vertices.append(v)
        faces.append(f + offset)
        labels.append(np.full(len(f), index + 1, dtype=np.uint32))
        offset += len(v)
    names = {WALL: "wall", FLOOR: "floor", CEILING: "ceiling", FURNITURE: "box"}
    objects = {i + 1: SceneObject(i + 1, names.get(b.category, "object"), b.category) for i, b in enumerate(boxes)}
    return Scene(scene_id=scene_id, vertices=np.concatenate(vertices).astype(np.float32),
                 faces=np.concatenate(faces).astype(np.int32), face_object_ids=np.concatenate(labels),
                 objects=objects, source="procedural")


def room_shell(x0: float, x1: float, z0: float, z1: float, ceiling: float = 2.5, wall: float = 0.1) -> list[Box]:
    """Floor slab, ceiling slab and four walls enclosing the free space [x0, x1] x [z0, z1]."""
    return [
        Box((x0 - wall, -0.1, z0 - wall), (x1 + wall, 0.0, z1 + wall), FLOOR),
        Box((x0 - wall, ceiling, z0 - wall), (x1 + wall, ceiling + 0.1, z1 + wall), CEILING),
        Box((x0 - wall, 0.0, z0 - wall), (x0, ceiling, z1 + wall)),
        Box((x1, 0.0, z0 - wall), (x1 + wall, ceiling, z1 + wall)),
        Box((x0, 0.0, z0 - wall), (x1, ceiling, z0)),
        Box((x0, 0.0, z1), (x1, ceiling, z1 + wall)),
    ]


def two_rooms(door_width: float | None, wall_thickness: float = 0.1, size: float = 4.0,
              ceiling: float = 2.5) -> Scene:
    """Two rooms of `size` x `size` side by side along x, split at x = 0 by a wall with a centred doorway.

    `door_width=None` makes the wall solid (two rooms with no connection).
    """
    half = wall_thickness / 2.0
    boxes = room_shell(-size, size, 0.0, size, ceiling)
    if door_width is None:
        boxes.append(Box((-half, 0.0, 0.0), (half, ceiling, size)))
    else:
        low, high = size / 2.0 - door_width / 2.0, size / 2.0 + door_width / 2.0
        boxes += [Box((-half, 0.0, 0.0), (half, ceiling, low)), Box((-half, 0.0, high), (half, ceiling, size)),
                  Box((-half, 2.0, low), (half, ceiling, high))]
    name = "none" if door_width is None else f"{round(door_width * 1000):04d}"
    return scene_from_boxes(f"rooms-door{name}-wall{round(wall_thickness * 1000):03d}", boxes)


def furnished_room(size: float = 5.0, ceiling: float = 2.5) -> Scene:
    """One room with a table (top at 0.75 m), a low box, a pillar and a thin wall stub."""
    boxes = room_shell(0.0, size, 0.0, size, ceiling)
    boxes += [
        Box((1.0, 0.7, 1.0), (2.0, 0.75, 1.6), FURNITURE),  # table top the body cannot pass under
        Box((1.0, 0.0, 1.0), (1.05, 0.7, 1.05), FURNITURE),
        Box((3.5, 0.0, 3.5), (4.0, 0.4, 4.2), FURNITURE),  # a box taller than the step
        Box((3.0, 0.0, 1.0), (3.2, ceiling, 1.2)),  # pillar
        Box((1.5, 0.0, 3.0), (1.505, ceiling, 4.5)),  # wall 5 mm thick: rays of the grid fall beside it
    ]
    return scene_from_boxes("furnished-room", boxes)


def house(rooms_x: int, rooms_z: int, room_size: float = 5.0, seed: int = 0, subdivisions: int = 0,
          ceiling: float = 2.6) -> Scene:
    """A grid of rooms joined by 0.9 m doorways, with a few random boxes of furniture per room."""
    rng = np.random.default_rng(seed)
    width, depth = rooms_x * room_size, rooms_z * room_size
    boxes = room_shell(0.0, width, 0.0, depth, ceiling)
    for i in range(1, rooms_x):
        boxes += _wall_with_door(axis="x", at=i * room_size, length=depth, room_size=room_size, ceiling=ceiling)
    for j in range(1, rooms_z):
        boxes += _wall_with_door(axis="z", at=j * room_size, length=width, room_size=room_size, ceiling=ceiling)
    for i in range(rooms_x):
        for j in range(rooms_z):
            for _ in range(3):
                size = rng.uniform([0.4, 0.3, 0.4], [1.2, 1.0, 1.2])
                corner = rng.uniform([i * room_size + 0.3, 0.0, j * room_size + 0.3],
                                     [(i + 1) * room_size - 0.3 - size[0], 0.0, (j + 1) * room_size - 0.3 - size[2]])
                boxes.append(Box(tuple(corner), tuple(corner + size), FURNITURE))
    return scene_from_boxes(f"house-{rooms_x}x{rooms_z}-{seed}", boxes, subdivisions)


def _wall_with_door(axis: str, at: float, length: float, room_size: float, ceiling: float) -> list[Box]:
    """An inner wall across the house with a 0.9 m doorway in the middle of every room it borders."""
    boxes = []
    for k in range(round(length / room_size)):
        low, high = k * room_size, (k + 1) * room_size
        door_low, door_high = (low + high) / 2 - 0.45, (low + high) / 2 + 0.45
        for a, b, y0 in ((low, door_low, 0.0), (door_high, high, 0.0), (door_low, door_high, 2.0)):
            if axis == "x":
                boxes.append(Box((at - 0.05, y0, a), (at + 0.05, ceiling, b)))
            else:
                boxes.append(Box((a, y0, at - 0.05), (b, ceiling, at + 0.05)))
    return boxes


def two_storey(steps: int = 16, rise: float = 0.175, run: float = 0.3) -> Scene:
    """Two 8 x 4 m storeys joined by a 1.2 m wide straight stair along +x (the upper floor at steps x rise).

    The upper floor slab has an opening above the stair, so the stair has headroom all the way up.
    """
    upper = steps * rise
    top = upper + 2.5
    stair_start, stair_end, stair_width = 1.0, 1.0 + steps * run, 1.2
    opening = stair_width + 0.1
    boxes = [b for b in room_shell(0.0, 8.0, 0.0, 4.0, ceiling=top) if b.category != CEILING]
    boxes.append(Box((-0.1, top, -0.1), (8.1, top + 0.1, 4.1), CEILING))
    slab = upper - 0.2
    boxes += [
        Box((0.0, slab, opening), (8.0, upper, 4.0), FLOOR),  # the upper floor, minus the opening
        Box((stair_end, slab, 0.0), (8.0, upper, opening), FLOOR),
        Box((0.0, slab, 0.0), (stair_start, upper, opening), FLOOR),
    ]
    for k in range(steps):
        boxes.append(Box((stair_start + k * run, 0.0, 0.0), (stair_start + (k + 1) * run, (k + 1) * rise, stair_width),
                         FURNITURE))
    return scene_from_boxes("two-storey", boxes)
