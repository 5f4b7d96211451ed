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

    def pixel_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """float64 camera-frame x per image column (W,) and y per image row (H,) of the pixel-centre rays."""
        x = (np.arange(self.width, dtype=np.float64) + 0.5 - self.cx) / self.fx
        y = (np.arange(self.height, dtype=np.float64) + 0.5 - self.cy) / self.fy
        return x, y

    def directions(self) -> np.ndarray:
        """(H, W, 3) float64 camera-frame ray directions through pixel centres, with z = 1."""
        x, y = self.pixel_axes()
        directions = np.ones((self.height, self.width, 3), np.float64)
        directions[..., 0] = x[None, :]
        directions[..., 1] = y[:, None]
        return directions

    def as_dict(self) -> dict[str, float]:
        """The intrinsics as stored in Zarr attributes and tables."""
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}


@dataclass
class RayHits:
    """What one frame's rays hit, per pixel (all arrays (H, W) or (H, W, k)).

    Attributes:
        depth: float32 planar z in metres (inf where nothing was hit).
        face: intp index of the hit triangle; F (the scene's triangle count) where nothing was hit, so
            per-face lookup tables with one trailing "miss" entry need no masking.
        barycentric: float32 (H, W, 2) Embree's (u, v): the hit is (1-u-v) a + u b + v c.
        normal: float32 (H, W, 3) unit geometric normal of the hit triangle, world frame (0 on a miss).
        direction: float32 (H, W, 3) world-frame ray direction (camera-frame z = 1, not normalised). A view
            of the caster's ray buffer: the next cast of the same `SceneRaycaster` overwrites it.
        hit: bool mask of pixels that hit a triangle.
    """

    depth: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    normal: np.ndarray
    direction: np.ndarray
    hit: np.ndarray

    def rows(self, rows: slice) -> RayHits:
        """The hits of a range of image rows (views, no copies)."""
        return RayHits(self.depth[rows], self.face[rows], self.barycentric[rows], self.normal[rows],
                       self.direction[rows], self.hit[rows])


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
        # Per camera (fixed for a video): the pixel axes and the ray buffer reused from frame to frame.
        self._ray_setup: tuple[Camera, np.ndarray, np.ndarray, np.ndarray] | None = None

    def rays(self, camera: Camera, camera_to_world: np.ndarray) -> np.ndarray:
        """(H*W, 6) float32 world-frame rays (origin, direction) of one pose; direction has camera z = 1.

        The array is reused from frame to frame (fresh multi-megabyte buffers cost page faults every
        frame); copy it to keep it beyond the next call.
        """
        if self._ray_setup is None or self._ray_setup[0] != camera:
            buffer = np.empty((camera.height * camera.width, 6), np.float32)
            self._ray_setup = (camera, *camera.pixel_axes(), buffer)
        _, x, y, rays = self._ray_setup
        pose = np.asarray(camera_to_world, np.float64)
        image = rays.reshape(camera.height, camera.width, 6)
        for k in range(3):
            # World direction = R (x, y, 1): per component a row term plus a column term, written as one
            # broadcast add per component. It loops over W-long rows; a (H*W, 3) @ (3, 3) matmul or a
            # broadcast over the 3-long last axis measured 5x slower, and BLAS threads spin against Embree's.
            np.add((y * pose[k, 1] + pose[k, 2]).astype(np.float32)[:, None],
                   (x * pose[k, 0]).astype(np.float32)[None, :], out=image[..., 3 + k])
            rays[:, k] = pose[k, 3]
        return rays

    def cast(self, camera: Camera, camera_to_world: np.ndarray) -> RayHits:
        """Trace one frame from `camera_to_world` (4x4, OpenCV camera axes)."""
        rays = self.rays(camera, camera_to_world)
        # from_numpy shares the buffer (no copy); the cast is synchronous, so reusing it next frame is safe.
        result = self._bvh.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=self.threads)
        shape = (camera.height, camera.width)
        # .numpy() shares the tensors' memory: every output below is a view, not a copy.
        depth = result["t_hit"].numpy().reshape(shape)
        primitive = result["primitive_ids"].numpy()
        # open3d marks misses with INVALID_ID (2^32 - 1): clamp them to F, the trailing "miss" entry, in place
        # (uint32), then widen once to intp, the index type numpy's gathers use without converting again.
        np.minimum(primitive, np.uint32(self.miss_index), out=primitive)
        return RayHits(
            depth=depth,
            face=primitive.astype(np.intp).reshape(shape),
            barycentric=result["primitive_uvs"].numpy().reshape(*shape, 2),
            normal=result["primitive_normals"].numpy().reshape(*shape, 3),
            direction=rays[:, 3:].reshape(*shape, 3),
            hit=np.isfinite(depth),
        )
