"""The camera rays' hits in a labelled scene: found by a z-buffer (raster.py), or cast into one Embree BVH
per scene in 8-ray packets (embree.py), which also serves every other ray (the bounces of indirect light).

Why per-ray hits: each pixel gets the exact triangle, so labels never blend across objects and depth is
exact (no depth-buffer quantisation, no anti-aliasing between ids). The z-buffer finds the same triangle
as the ray (99.999 % of pixels; the rest are ties on shared edges) and intersects the pixel's ray with it,
for half the CPU and wall time of the packet cast on the 1 M-triangle benchmark house with 2 threads
(benchmarks/bench_render.py `primary_visibility`, results/render_primary.json).

Rays go through pixel centres (u + 0.5, v + 0.5) (schemas/README.md). Camera-frame ray directions are
(x, y, 1) with x = (u + 0.5 - cx) / fx and y = (v + 0.5 - cy) / fy, i.e. NOT normalised: Embree's hit
distance along such a ray is then the planar depth z itself (z = t * (d . optical axis) with d . axis = 1).
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pipeline.render.camera import pixel_rays
from pipeline.render.embree import EmbreeMesh
from pipeline.render.raster import ClusteredMesh, Rasterizer
from pipeline.scenes.scene import Scene

if TYPE_CHECKING:
    from pipeline.render.fused import FramePass


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
        return pixel_rays(np.arange(self.width), np.arange(self.height), self.intrinsics)

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels, as `pipeline.render.camera` takes them."""
        return (self.fx, self.fy, self.cx, self.cy)

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
    """Casts camera rays into one scene. Build once per scene (the BVH costs ~0.4 s per 1 M triangles).

    Args:
        scene: the labelled mesh (world frame).
        threads: threads per cast (each traces a band of rows); 0 = `available_cpus()` (the task's CPUs
            under Ray), never the host's core count, which oversubscribes a container.
        rasterize: find the camera rays' hits with the z-buffer (raster.py) instead of Embree packets.
    """

    def __init__(self, scene: Scene, threads: int = 0, rasterize: bool = True):
        self.scene = scene
        self.threads = threads or available_cpus()
        self.miss_index = len(scene.faces)
        self.rasterize = rasterize
        self._bvh = EmbreeMesh(scene.vertices, scene.faces)
        self._clusters: ClusteredMesh | None = None  # built on the first cast (~1 s per 1 M triangles)
        # Per camera (fixed for a video): the pixel axes, the output buffers reused from frame to frame
        # (fresh multi-megabyte arrays cost page faults every frame) and the rasterizer with its z-buffer, whose
        # winners are the first triangles the next frame draws (a video's frames are 5 cm apart).
        self._setup: tuple[Camera, np.ndarray, np.ndarray, RayHits, Rasterizer | None] | None = None

    @property
    def mesh(self) -> EmbreeMesh:
        """The scene's BVH, for rays other than the camera's (indirect light)."""
        return self._bvh

    def cast(self, camera: Camera, camera_to_world: np.ndarray, surfaces: bool = True,
             into: FramePass | None = None) -> RayHits:
        """Trace one frame from `camera_to_world` (4x4, OpenCV camera axes). Without `surfaces`, the z-buffer
        leaves the normal and direction buffers as they were, for a frame that reads neither (ambient light,
        ideal sensor; the Embree cast fills them anyway). With `into` (a z-buffer cast only), each band's winners
        are resolved straight into that frame's buffers, and the hits returned are left stale.

        The arrays of the result are reused by the next cast of this caster: copy what must outlive it.
        """
        if self._setup is None or self._setup[0] != camera:
            shape = (camera.height, camera.width)
            buffers = RayHits(np.empty(shape, np.float32), np.empty(shape, np.intp), np.empty((*shape, 2), np.float32),
                              np.empty((*shape, 3), np.float32), np.empty((*shape, 3), np.float32), np.empty(shape, bool))
            if self.rasterize and self._clusters is None:
                self._clusters = ClusteredMesh(self.scene.vertices, self.scene.faces)
            pixel_x, pixel_y = camera.pixel_axes()
            rasterizer = Rasterizer(self._clusters, pixel_x, pixel_y, camera.fx, camera.fy) if self.rasterize else None
            self._setup = (camera, pixel_x, pixel_y, buffers, rasterizer)
        _, pixel_x, pixel_y, hits, rasterizer = self._setup
        if into is not None and rasterizer is None:
            raise ValueError("a FramePass resolves a z-buffer's winners: cast it with rasterize=True")
        out = (hits.depth, hits.face, hits.barycentric, hits.normal, hits.direction)

        def trace(rows: slice) -> None:
            if rasterizer is None:
                self._bvh.cast_rows(rows, pixel_x, pixel_y, camera_to_world, self.miss_index, out)
                return
            rasterizer.draw_band(rows, camera_to_world)
            if into is not None:
                into.resolve_band(rasterizer, rows, camera_to_world)
            else:
                rasterizer.resolve_band(rows, camera_to_world, self.miss_index, out, surfaces)

        if rasterizer is not None:
            rasterizer.visible_clusters(camera_to_world)
        first, *others = _cached_bands(camera.height, self.threads)
        # The calling thread traces the first band itself while the pool traces the others: one hand-off less a frame.
        pending = [thread_pool(self.threads).submit(trace, rows) for rows in others]
        try:
            trace(first)
        finally:  # (no band is left running into the next frame's buffers)
            wait(pending)
        for band in pending:
            band.result()
        if into is None:
            np.isfinite(hits.depth, out=hits.hit)
        return hits


def row_bands(height: int, count: int) -> list[slice]:
    """`count` contiguous row ranges covering `height` rows (at least one row each)."""
    edges = np.linspace(0, height, max(1, min(count, height)) + 1).round().astype(int)
    return [slice(int(start), int(stop)) for start, stop in zip(edges[:-1], edges[1:])]


@functools.cache
def _cached_bands(height: int, count: int) -> tuple[slice, ...]:
    """`row_bands`, taken once per frame height and thread count (its linspace cost ~0.1 ms a frame)."""
    return tuple(row_bands(height, count))


@functools.cache
def thread_pool(workers: int) -> ThreadPoolExecutor:
    """One pool per process and size for work split in row bands (threads live as long as the process)."""
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="render-band")
