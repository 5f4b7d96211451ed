"""Tiny scenes with known geometry for the render tests (planes and boxes, a few hundred triangles)."""

from __future__ import annotations

import numpy as np

from pipeline.config import Embodiment, Illumination, Sensor
from pipeline.scenes.scene import Scene, SceneObject

WALL, FLOOR, CEILING, TABLE, CHAIR = 11, 12, 13, 21, 22
CATEGORIES = {WALL: 1, FLOOR: 2, CEILING: 17, TABLE: 5, CHAIR: 3}


def look_at(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world pose (OpenCV axes: x right, y down, z forward) with world +Y up."""
    forward = np.asarray(target, float) - np.asarray(position, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward], axis=1)
    pose[:3, 3] = position
    return pose


class _Builder:
    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.ids: list[np.ndarray] = []
        self.colors: list[np.ndarray] = []
        self.count = 0

    def quad(self, corners: np.ndarray, object_id: int, color: tuple[int, int, int]) -> None:
        self.vertices.append(np.asarray(corners, np.float32))
        base = self.count
        self.faces.append(np.array([[base, base + 1, base + 2], [base, base + 2, base + 3]], np.int32))
        self.ids.append(np.full(2, object_id, np.uint32))
        self.colors.append(np.tile(np.array(color, np.uint8), (4, 1)))
        self.count += 4

    def box(self, low: np.ndarray, high: np.ndarray, object_id: int, color: tuple[int, int, int]) -> None:
        (x0, y0, z0), (x1, y1, z1) = low, high
        for corners in ([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]],
                        [[x0, y0, z1], [x0, y1, z1], [x1, y1, z1], [x1, y0, z1]],
                        [[x0, y0, z0], [x0, y1, z0], [x0, y1, z1], [x0, y0, z1]],
                        [[x1, y0, z0], [x1, y0, z1], [x1, y1, z1], [x1, y1, z0]],
                        [[x0, y1, z0], [x1, y1, z0], [x1, y1, z1], [x0, y1, z1]],
                        [[x0, y0, z0], [x0, y0, z1], [x1, y0, z1], [x1, y0, z0]]):
            self.quad(np.array(corners), object_id, color)

    def scene(self, scene_id: str) -> Scene:
        ids = np.concatenate(self.ids)
        objects = {int(i): SceneObject(int(i), f"object {i}", CATEGORIES.get(int(i), 39)) for i in np.unique(ids) if i}
        return Scene(scene_id, np.concatenate(self.vertices), np.concatenate(self.faces), ids, objects,
                     vertex_colors=np.concatenate(self.colors))


def plane_scene(distance: float, object_id: int = 5, half_size: float = 50.0) -> Scene:
    """One square facing the origin at z = `distance` (world), much wider than any test view."""
    builder = _Builder()
    s = half_size
    builder.quad(np.array([[-s, -s, distance], [s, -s, distance], [s, s, distance], [-s, s, distance]]),
                 object_id, (200, 200, 200))
    return builder.scene("plane")


def room_scene() -> Scene:
    """A closed 4 x 2.5 x 4 m room (floor y = 0) with a table, a chair and a cabinet; all labelled."""
    builder = _Builder()
    builder.box(np.array([-2.0, -0.1, -2.0]), np.array([2.0, 0.0, 2.0]), FLOOR, (120, 90, 60))
    builder.box(np.array([-2.0, 2.5, -2.0]), np.array([2.0, 2.6, 2.0]), CEILING, (240, 240, 240))
    builder.box(np.array([-2.1, 0.0, -2.0]), np.array([-2.0, 2.5, 2.0]), WALL, (200, 180, 160))
    builder.box(np.array([2.0, 0.0, -2.0]), np.array([2.1, 2.5, 2.0]), WALL + 100, (180, 200, 160))
    builder.box(np.array([-2.0, 0.0, 2.0]), np.array([2.0, 2.5, 2.1]), WALL + 200, (160, 180, 200))
    builder.box(np.array([-2.0, 0.0, -2.1]), np.array([2.0, 2.5, -2.0]), WALL + 300, (190, 190, 190))
    builder.box(np.array([-0.6, 0.0, 0.8]), np.array([0.4, 0.45, 1.4]), TABLE, (150, 40, 40))
    builder.box(np.array([0.7, 0.0, 0.5]), np.array([1.1, 0.4, 0.9]), CHAIR, (40, 150, 40))
    builder.box(np.array([-1.6, 0.0, 1.3]), np.array([-1.0, 1.2, 1.9]), 31, (40, 40, 150))
    return builder.scene("room")


def embodiment(width: int = 64, height: int = 48, hfov: float = 69.0, model: str = "ideal",
               light: Illumination | None = None, name: str = "robot",
               placements: tuple[float, ...] = (1.0, 0.1)) -> Embodiment:
    """A small test embodiment (64 x 48 by default)."""
    return Embodiment(name=name, sensor=Sensor(width=width, height=height, hfov=hfov, model=model),  # type: ignore[arg-type]
                      illumination=light or Illumination(), placements=list(placements))
