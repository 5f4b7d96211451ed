"""The scene object every stage uses: one triangle mesh with per-face instance labels.

Frame: world, metres, +Y up (gravity -Y). Readers of scans stored with another up axis rotate into
this frame and keep the rotation in `Scene.to_world` so that exports can undo it.

Memory (documented bound): per triangle 12 B vertices (shared, ~6 B/face amortised) + 12 B faces +
4 B object id + 1-2 B material, plus vertex colours (3 B/vertex) or UVs (24 B/face) and textures.
A 1 M-triangle scene is about 60 MB of arrays plus its textures; the `Scene` is only built when a
`SceneRef.load()` is called, so listing scenes (sharding) costs nothing until a unit needs one.
Measured (benchmarks/bench_scenes.py): generating a 1 M-triangle house peaks at about 0.15 GiB of
process memory, reading a 1 M-triangle HM3DSem trio at about 0.3 GiB (both far under 2 GiB).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pipeline.scenes.categories import STUFF_CATEGORIES, categories

VOID_ID = 0


@dataclass(frozen=True)
class SceneObject:
    """One labelled instance of a scene.

    Attributes:
        object_id: id > 0, unique in the scene; 0 is void. For HM3DSem it is the object's hex colour
            as an integer (0xRRGGBB), so that (scene id, object id) identifies an object across videos.
        raw_name: the annotator's raw name ("kitchen cabinet").
        category: mpcat40 index (0 = void, when the raw name is not mapped).
        region: room / region index, -1 when unknown.
    """

    object_id: int
    raw_name: str
    category: int
    region: int = -1

    @property
    def category_name(self) -> str:
        return categories()[self.category].name if self.category in categories() else "void"

    @property
    def is_stuff(self) -> bool:
        return self.category in STUFF_CATEGORIES


@dataclass
class Scene:
    """A labelled triangle mesh in the world frame (+Y up, metres).

    Attributes:
        scene_id: the scene's id (HM3DSem style, e.g. "00808-y9hTuugGdiq", or "proc-000003").
        vertices: (V, 3) float32 positions.
        faces: (F, 3) int32 vertex indices, counter-clockwise seen from outside.
        face_object_ids: (F,) uint32 object id per face, 0 = void.
        objects: every object that labels at least one face (void excluded), by object id.
        vertex_colors: (V, 3) uint8 albedo per vertex, or None when textured.
        face_uvs: (F, 3, 2) float32 texture coordinates per face corner (u right, v up, glTF flips
            on read), or None.
        textures: list of (H, W, 3) uint8 images; `face_material` picks one per face.
        face_material: (F,) uint16 index into `textures`, or None.
        to_world: 4x4 float64 transform from the source file's frame into the world frame.
        source: where it came from ("procedural", "hm3dsem", "mesh").
        path: the file it was read from (empty for in-memory scenes).
        unknown_colors: semantic colours of the source that had no row in its table (they are void).
        degenerate_faces: faces of the source dropped on reading (fewer than 3 corners or zero area).
    """

    scene_id: str
    vertices: np.ndarray
    faces: np.ndarray
    face_object_ids: np.ndarray
    objects: dict[int, SceneObject]
    vertex_colors: np.ndarray | None = None
    face_uvs: np.ndarray | None = None
    textures: list[np.ndarray] = field(default_factory=list)
    face_material: np.ndarray | None = None
    to_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    source: str = "procedural"
    path: str = ""
    unknown_colors: int = 0
    degenerate_faces: int = 0

    @property
    def triangle_count(self) -> int:
        return int(len(self.faces))

    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner of the mesh."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)]).astype(np.float64)

    def _face_cross(self) -> np.ndarray:
        """(F, 3) float64 (b - a) x (c - a) of every triangle; the edges are made in place, so a scene of
        millions of faces holds three (F, 3) arrays at a time instead of six."""
        v = self.vertices.astype(np.float64)
        a = v[self.faces[:, 0]]
        ab, ac = v[self.faces[:, 1]], v[self.faces[:, 2]]
        ab -= a
        ac -= a
        del a, v
        return np.cross(ab, ac)

    def face_areas(self) -> np.ndarray:
        """(F,) float64 area of each triangle in square metres."""
        return 0.5 * np.linalg.norm(self._face_cross(), axis=1)

    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit normals (zero for degenerate faces)."""
        n = self._face_cross()
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def face_colors(self) -> np.ndarray:
        """(F, 3) uint8 mean albedo per face (for previews; the renderer samples textures itself)."""
        if self.vertex_colors is not None:
            return self.vertex_colors[self.faces].mean(axis=1).astype(np.uint8)
        colors = np.full((len(self.faces), 3), 160, np.uint8)
        if self.face_uvs is None or self.face_material is None:
            return colors
        centre_uv = self.face_uvs.mean(axis=1)
        for material, texture in enumerate(self.textures):
            mask = self.face_material == material
            h, w = texture.shape[:2]
            u = np.clip((centre_uv[mask, 0] % 1.0) * (w - 1), 0, w - 1).astype(int)
            v = np.clip((1.0 - centre_uv[mask, 1] % 1.0) * (h - 1), 0, h - 1).astype(int)
            colors[mask] = texture[v, u, :3]
        return colors

    def validate(self) -> None:
        """Raise SceneError naming the problem if the arrays are unusable (empty, NaN, bad indices)."""
        where = self.path or self.scene_id
        if len(self.faces) == 0 or len(self.vertices) == 0:
            raise SceneError(f"{where}: the mesh is empty (0 triangles); check the file was exported with geometry")
        if not np.isfinite(self.vertices).all():
            bad = int((~np.isfinite(self.vertices)).any(axis=1).sum())
            raise SceneError(f"{where}: {bad} vertices are NaN or infinite; repair the mesh before using it")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise SceneError(f"{where}: face indices outside 0..{len(self.vertices) - 1}; the file is corrupt")
        if len(self.face_object_ids) != len(self.faces):
            raise SceneError(f"{where}: {len(self.face_object_ids)} face labels for {len(self.faces)} faces")


class SceneError(ValueError):
    """A scene that cannot be read or used; the message names the file and what to fix."""


@dataclass(frozen=True)
class SceneRef:
    """A scene that has been listed but not loaded: cheap to pass to a Ray task.

    `loader` is a module-level function `(ref) -> Scene` (picklable by reference).
    """

    scene_id: str
    source: str
    path: str
    loader: Callable[["SceneRef"], Scene]
    options: tuple[tuple[str, object], ...] = ()

    def load(self) -> Scene:
        scene = self.loader(self)
        scene.validate()
        return scene

    def option(self, key: str, default: object = None) -> object:
        return dict(self.options).get(key, default)

