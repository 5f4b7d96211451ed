"""The z-buffer's resolve (raster.Rasterizer.resolve_band): what it writes with and without the surface buffers."""

from __future__ import annotations

import numpy as np

from pipeline.render.raster import ClusteredMesh, Rasterizer
from pipeline.render.raycaster import Camera
from pipeline.scenes.scene import Scene
from tests.render.tiny_scenes import look_at, room_scene


CAMERA = Camera(64, 48, 40.0, 40.0, 31.5, 23.5)


def resolved(surfaces: bool, pose: np.ndarray, scene: Scene | None = None) -> tuple[np.ndarray, ...]:
    """The hit buffers (depth, face, barycentric, normal, direction) of CAMERA at `pose` in `scene` (the room), first
    filled with -1 (7 for the normals and directions), after one resolve of every row with `surfaces`."""
    scene, camera = scene or room_scene(), CAMERA
    rasterizer = Rasterizer(ClusteredMesh(scene.vertices, scene.faces), *camera.pixel_axes(), camera.fx, camera.fy)
    rasterizer.visible_clusters(pose)
    rows = slice(0, camera.height)
    rasterizer.draw_band(rows, pose)
    shape = (camera.height, camera.width)
    out = (np.full(shape, -1.0, np.float32), np.full(shape, -1, np.intp), np.full((*shape, 2), -1.0, np.float32),
           np.full((*shape, 3), 7.0, np.float32), np.full((*shape, 3), 7.0, np.float32))
    rasterizer.resolve_band(rows, pose, len(scene.faces), out, surfaces=surfaces)
    return out


def test_without_surfaces_the_resolve_writes_the_same_hits_and_leaves_normals_and_directions() -> None:
    """Ambient light with an ideal sensor reads neither normals nor directions: the resolve may skip their
    stores, but depth, faces and barycentrics must be the bits it writes with them (misses included)."""
    pose = look_at(np.array([0.3, 4.0, -9.0]), np.array([0.5, 0.7, 1.0]))  # outside: the room and the void
    full, bare = resolved(True, pose), resolved(False, pose)
    assert np.isinf(full[0]).any() and np.isfinite(full[0]).any()  # hits and misses both
    for name, kept, skipped in zip(("depth", "face", "barycentric"), full[:3], bare[:3]):
        assert np.array_equal(kept, skipped), name
    assert (np.abs(full[3]) <= 1.0).all() and (full[4][..., 2] != 7.0).all()  # written with surfaces
    assert (bare[3] == 7.0).all() and (bare[4] == 7.0).all()  # untouched without
