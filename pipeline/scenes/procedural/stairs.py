"""Stairs joining two storeys: a straight run along the south wall of the hallway, ending 1 m before
its east end so both storeys keep a landing; a hole in the ground hallway's ceiling and the upper
hallway's floor above the run, and a railing around the hole upstairs.

Steps rise at most 0.19 m (robots climb up to `body.max_step` = 0.2 m by default) and are solid
blocks down to the floor, so every step is a closed, walkable box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pipeline.scenes.procedural.geometry import Box, Part
from pipeline.scenes.procedural.layout import HALF_WALL, SLAB

MAX_RISE = 0.19
TREAD = 0.26
WIDTH = 0.9
LANDING = 1.0
HALLWAY_CM = (200, 230)  # a two-storey hallway is wide enough to pass beside the stairwell


@dataclass(frozen=True)
class Stairwell:
    """The stair run (metres): footprint [x0, x1] x [z0, z1] (also the slab hole), steps and rise."""

    x0: float
    z0: float
    x1: float
    z1: float
    steps: int
    rise: float

    @property
    def hole(self) -> tuple[float, float, float, float]:
        """(x0, z0, x1, z1) of the slab opening above the run."""
        return (self.x0, self.z0, self.x1, self.z1)


def storey_height(ceiling: float) -> float:
    """Floor-to-floor height: the ceiling plus the ground ceiling slab and the upper floor slab."""
    return round(ceiling + 2 * SLAB, 4)


def plan_stairwell(hallway_x1_cm: int, hallway_z0_cm: int, ceiling: float) -> Stairwell:
    """The stairwell at the east end of the hallway's south wall."""
    height = storey_height(ceiling)
    steps = math.ceil(height / MAX_RISE)
    x1 = round(hallway_x1_cm / 100 - HALF_WALL - LANDING, 4)
    x0 = round(x1 - steps * TREAD, 4)
    z0 = round(hallway_z0_cm / 100 + HALF_WALL, 4)
    return Stairwell(x0, z0, x1, round(z0 + WIDTH, 4), steps, height / steps)


def door_free_span(well: Stairwell) -> tuple[int, int]:
    """The span (cm) of the hallway's south wall where no door may open (stairs below, hole above)."""
    return (int(math.floor(well.x0 * 100)) - 100, int(math.ceil(well.x1 * 100)) + 10)


def stair_parts(well: Stairwell) -> list[Part]:
    """The steps, lowest at x0, each a block from the floor to its tread."""
    color = (150, 110, 75)
    return [Box((round(well.x0 + k * TREAD, 4), 0.0, well.z0), (round(well.x0 + (k + 1) * TREAD, 4), round((k + 1) * well.rise, 4), well.z1),
                "wood", color) for k in range(well.steps)]


def railing_parts(well: Stairwell) -> list[Part]:
    """Upstairs (local y = 0 is the upper floor): posts and a top rail along the hole's open sides."""
    metal = (90, 90, 95)
    z, x = well.z1, well.x0 - 0.05
    parts: list[Part] = [Box((x, 0.85, z), (well.x1, 0.9, z + 0.05), "metal", metal),
                         Box((x, 0.85, well.z0), (well.x0, 0.9, z), "metal", metal)]
    count = max(2, int((well.x1 - x) / 0.8) + 1)
    for k in range(count):
        px = round(x + k * (well.x1 - x - 0.05) / (count - 1), 4)
        parts.append(Box((px, 0.0, z), (round(px + 0.05, 4), 0.85, z + 0.05), "metal", metal))
    parts.append(Box((x, 0.0, well.z0), (well.x0, 0.85, well.z0 + 0.05), "metal", metal))
    return parts
