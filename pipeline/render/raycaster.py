"""CPU ray casting of a labelled scene: one Embree BVH (open3d's RaycastingScene) per scene.

Why ray casting: on plain CPUs Embree traces a 640x480 frame of a 1 M-triangle house in tens of
milliseconds using every core, and each hit gives the exact triangle, so labels never blend across
objects and depth is exact (no depth-buffer quantisation, no anti-aliasing between ids).

Rays go through pixel centres (u + 0.5, v + 0.5) (schemas/README.md). Camera-frame ray directions are
(x, y, 1) with x = (u + 0.5 - cx) / fx and y = (v + 0.5 - cy) / fy, i.e. NOT normalised: Embree's hit
distance along such a ray is then the planar depth z itself (z = t * (d . optical axis) with d . axis = 1).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from pipeline.scenes.scene import Scene


def available_cpus() -> int:
    """Threads a cast may use: OMP_NUM_THREADS when set (Ray sets it to the CPUs a task asked for), else the
    CPUs in this process's affinity mask (what a container gives it)."""
    requested = os.environ.get("OMP_NUM_THREADS", "")
    if requested.isdigit() and int(requested) > 0:
        return int(requested)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: image size and intrinsics in pixels (OpenCV axes x right, y down, z forward)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def directions(self) -> np.ndarray:
        """(H, W, 3) float64 camera-frame ray directions through pixel centres, with z = 1."""
        u = (np.arange(self.width, dtype=np.float64) + 0.5 - self.cx) / self.fx
        v = (np.arange(self.height, dtype=np.float64) + 0.5 - self.cy) / self.fy
        directions = np.ones((self.height, self.width, 3), np.float64)
        directions[..., 0] = u[None, :]
        directions[..., 1] = v[:, None]
        return directions

    def as_dict(self) -> dict[str, float]:
        """The intrinsics as stored in Zarr attributes and tables."""
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}


@dataclass
class RayHits:
    """What one frame's rays hit, per pixel (all arrays (H, W) or (H, W, k)).

    Attributes:
        depth: float32 planar z in metres (inf where nothing was hit).
        face: int64 index of the hit triangle; F (the scene's triangle count) where nothing was hit, so
            per-face lookup tables with one trailing "miss" entry need no masking.
        barycentric: float32 (H, W, 2) Embree's (u, v): the hit is (1-u-v) a + u b + v c.
        normal: float32 (H, W, 3) unit geometric normal of the hit triangle, world frame.
        direction: float32 (H, W, 3) world-frame ray direction (camera-frame z = 1, not normalised).
        hit: bool mask of pixels that hit a triangle.
    """

    depth: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    normal: np.ndarray
    direction: np.ndarray
    hit: np.ndarray


class SceneRaycaster:
    """Casts camera rays into one scene. Build once per scene (the BVH costs ~1-2 s per 1 M triangles).

    Args:
        scene: the labelled mesh (world frame).
        threads: Embree threads per cast; 0 = `available_cpus()` (the task's CPUs under Ray). Not open3d's
            own default, which counts the host's cores and oversubscribes a container (measured 4x slower).
    """

    def __init__(self, scene: Scene, threads: int = 0):
        self.scene = scene
        self.threads = threads or available_cpus()
        self.miss_index = len(scene.faces)
        self._bvh = o3d.t.geometry.RaycastingScene()
        self._bvh.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(scene.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(scene.faces, dtype=np.uint32)),
        )
        self._directions_cache: tuple[Camera, np.ndarray] | None = None
        self._rays: np.ndarray | None = None

    def _camera_directions(self, camera: Camera) -> np.ndarray:
        # The per-pixel directions only depend on the camera, which is fixed for a whole video.
        if self._directions_cache is None or self._directions_cache[0] != camera:
            self._directions_cache = (camera, camera.directions().reshape(-1, 3).astype(np.float32))
        return self._directions_cache[1]

    def rays(self, camera: Camera, camera_to_world: np.ndarray) -> np.ndarray:
        """(H*W, 6) float32 world-frame rays (origin, direction) of one pose; direction has camera z = 1.

        The array is reused from frame to frame (fresh multi-megabyte buffers cost page faults every
        frame); copy it to keep it beyond the next call.
        """
        rotation = np.asarray(camera_to_world, np.float32)[:3, :3]
        origin = np.asarray(camera_to_world, np.float64)[:3, 3]
        directions = self._camera_directions(camera)
        if self._rays is None or len(self._rays) != len(directions):
            self._rays = np.empty((len(directions), 6), np.float32)
        self._rays[:, :3] = origin
        np.matmul(directions, rotation.T, out=self._rays[:, 3:])
        return self._rays

    def cast(self, camera: Camera, camera_to_world: np.ndarray) -> RayHits:
        """Trace one frame from `camera_to_world` (4x4, OpenCV camera axes)."""
        rays = self.rays(camera, camera_to_world)
        # from_numpy shares the buffer (no copy); the cast is synchronous, so reusing it next frame is safe.
        result = self._bvh.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=self.threads)
        shape = (camera.height, camera.width)
        depth = result["t_hit"].numpy().reshape(shape)
        hit = np.isfinite(depth)
        # open3d marks misses with INVALID_ID (2^32 - 1): clamp them to F, the trailing "miss" entry.
        face = np.minimum(result["primitive_ids"].numpy(), self.miss_index).astype(np.int64).reshape(shape)
        return RayHits(
            depth=depth,
            face=face,
            barycentric=result["primitive_uvs"].numpy().reshape(*shape, 2),
            normal=result["primitive_normals"].numpy().reshape(*shape, 3),
            direction=rays[:, 3:].reshape(*shape, 3).copy(),
            hit=hit,
        )
