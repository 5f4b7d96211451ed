"""One frame from a pose: ray cast, then every buffer (RGB, depth, panoptic) and its per-frame statistics.

`VideoRenderer` holds what is fixed for a video (scene BVH, camera, light, sensor) so that a frame costs
one ray cast plus vectorised numpy. The per-frame `segments` rows come from `pipeline.io.segments`.
"""

from __future__ import annotations

import functools
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from pipeline.config import Embodiment
from pipeline.io.segments import FrameSegments, frame_segments
from pipeline.lazy_import import lazy_module
from pipeline.render.fused import FramePass
from pipeline.render.indirect import IndirectGather, VirtualLights
from pipeline.render.lighting import Shader, SurfaceColors
from pipeline.render.raycaster import Camera, RayHits, SceneRaycaster, row_bands, thread_pool
from pipeline.render.sensors import StructuredLightModel, depth_to_millimetres, millimetres_of, sensor_model
from pipeline.scenes.scene import Scene

zarr = lazy_module("zarr")  # loaded on first use: only a rendering worker sizes its pool


# Fewest row bands a frame is shaded in (see VideoRenderer.__init__).
MIN_BANDS = 4


@dataclass
class RenderedFrame:
    """The buffers of one frame: rgb (H, W, 3) uint8, depth (H, W) uint16 mm, panoptic (H, W) uint32.

    `depth_clean` is the ideal depth when a sensor model made `depth` noisy, else None. `dense` is the
    panoptic frame as int32 indices into `SceneLabels.dense_ids` (for per-frame statistics; not stored), or
    None when the frame came with its `segments` (a fused frame counts them while it writes its ids).
    """

    rgb: np.ndarray
    depth: np.ndarray
    panoptic: np.ndarray
    depth_clean: np.ndarray | None = None
    dense: np.ndarray | None = None
    segments: FrameSegments | None = None

    def segment_statistics(self, labels: SceneLabels) -> FrameSegments:
        """The frame's `segments` rows: counted with the frame, or now from its dense labels."""
        return self.segments if self.segments is not None else frame_segments(self.panoptic, labels, self.dense)


def new_frame(height: int, width: int, dense: bool = True) -> RenderedFrame:
    """Unset buffers of one frame (its own: the Zarr writer keeps them until their shard is written)."""
    shape = (height, width)
    return RenderedFrame(rgb=np.empty((*shape, 3), np.uint8), depth=np.empty(shape, np.uint16),
                         panoptic=np.empty(shape, np.uint32), dense=np.empty(shape, np.int32) if dense else None)


def camera_of(embodiment: Embodiment) -> Camera:
    """The pinhole camera of an embodiment's sensor."""
    fx, fy, cx, cy = embodiment.sensor.intrinsics()
    return Camera(embodiment.sensor.width, embodiment.sensor.height, fx, fy, cx, cy)


class SceneLabels:
    """Per-face lookups of one scene, with a trailing entry for misses (face index F)."""

    def __init__(self, scene: Scene):
        object_ids = np.asarray(scene.face_object_ids, np.uint32)
        self.object_ids = np.append(object_ids, np.uint32(0))
        # Dense label k in 0..K (0 = void) per face, so per-frame statistics are bincounts, not sorts.
        self.dense_ids = np.unique(np.append(object_ids, np.uint32(0)))  # sorted, starts with 0
        self.dense_of_face = np.searchsorted(self.dense_ids, self.object_ids).astype(np.int32)
        self.dense_categories = np.array(
            [scene.objects[int(i)].category if int(i) in scene.objects else 0 for i in self.dense_ids], np.int16)


class VideoRenderer:
    """Renders the frames of one video: one scene, one embodiment, one exposure.

    Args:
        scene: the labelled mesh; `raycaster` may be passed to share one BVH between videos of a scene.
        embodiment: camera, clip range, depth sensor model and light.
        exposure: the job's exposure (lighting.job_exposure); unused for ambient light.
        seed: the job's seed; fixes the pattern of indirect light (the same for every frame and video).
    """

    def __init__(self, scene: Scene, embodiment: Embodiment, exposure: float, raycaster: SceneRaycaster | None = None,
                 colors: SurfaceColors | None = None, labels: SceneLabels | None = None, seed: int = 0):
        self.scene = scene
        self.embodiment = embodiment
        self.camera = camera_of(embodiment)
        self.raycaster = raycaster or SceneRaycaster(scene)
        self.colors = colors or SurfaceColors(scene)
        self.labels = labels or SceneLabels(scene)
        self.ray_lengths = np.linalg.norm(self.camera.directions(), axis=-1).astype(np.float32)
        self.shader = Shader(embodiment.illumination, exposure, self.ray_lengths)
        self.sensor: StructuredLightModel | None = sensor_model(embodiment.sensor.model)
        light = embodiment.illumination
        self.indirect = (IndirectGather(self.raycaster.mesh, self.colors, light, seed, self.raycaster.threads)
                         if light.kind == "spot" and light.indirect.bounces > 0 else None)
        self._lights: tuple[np.ndarray, Future] | None = None  # (pose, its virtual lights being traced)
        # Whether the general path (`trace`, then `buffers`) needs the hits' normals and directions: the spot's
        # shading and a depth sensor model read them; ambient light with an ideal sensor reads neither, and the
        # resolve skips ~7 MB of stores a frame.
        self.needs_surfaces = light.kind == "spot" or self.sensor is not None
        # A frame with an ideal sensor on a z-buffer cast and a vertex-coloured scene skips the hits altogether under
        # ambient light or a spot alone on diffuse surfaces: the resolve writes its buffers, lit by each hit's normal,
        # ray and depth under the spot, and counts its segments itself (fused.FramePass; an ambient bench frame,
        # paired in one process, 1 / 2 threads: 28.8 -> 26.8 / 28.5 -> 27.0 ms CPU from the pose to the segments).
        self.fused = (self.sensor is None and self.raycaster.rasterize and self.colors.records is not None
                      and self.indirect is None and (light.kind == "ambient" or light.material == "diffuse"))
        # Frames are shaded in row bands: a band's temporaries stay in the core's cache (4 bands of a 640x480
        # frame: 12 % faster than whole frames), and with several cast threads the bands run in parallel
        # (numpy releases the GIL: 2 threads take ~60 % of the time). A 1-CPU worker runs them inline.
        self._bands = [(rows, Shader(embodiment.illumination, exposure, self.ray_lengths[rows], rows.start))
                       for rows in row_bands(self.camera.height, max(MIN_BANDS, self.raycaster.threads))]

    def trace(self, camera_to_world: np.ndarray, surfaces: bool = True) -> RayHits:
        """Ray cast one pose; hits outside the clip range [near, far] become misses (void, black, 0 mm). Without
        `surfaces` the hits' normals and directions are not filled (`needs_surfaces` says when `render` skips them).

        With indirect light and several threads, the spot's virtual lights of the pose (which need no camera
        hit) are traced on a thread of their own meanwhile: their single-threaded numpy would leave a core idle."""
        if self.indirect is not None and self.raycaster.threads > 1:  # (a 1-CPU worker keeps to its core)
            pose = np.array(camera_to_world, np.float64)
            self._lights = (pose, _light_tracer().submit(self.indirect.virtual_lights, pose))
        hits = self.raycaster.cast(self.camera, camera_to_world, surfaces)
        sensor = self.embodiment.sensor
        # One compiled pass tells whether any hit is clipped; the masks are built only then (rarely).
        if _any_clipped(hits.depth, np.float32(sensor.near), np.float32(sensor.far)):
            inside = hits.depth >= sensor.near  # a miss (inf) fails the far test below
            inside &= hits.depth <= sensor.far
            clipped = hits.hit & ~inside
            hits.face[clipped] = self.raycaster.miss_index
            hits.depth[clipped] = np.inf
            hits.hit = inside
        return hits

    def render(self, camera_to_world: np.ndarray, rng: np.random.Generator | None = None) -> RenderedFrame:
        """All buffers of one frame. `rng` feeds the sensor model (required unless the sensor is ideal)."""
        if self.fused:
            return self.resolve_frame(camera_to_world)
        return self.buffers(self.trace(camera_to_world, self.needs_surfaces), rng, camera_to_world)

    def resolve_frame(self, camera_to_world: np.ndarray, colour: bool = True) -> RenderedFrame:
        """The frame `render` gives when `fused`, cast straight into its buffers, with its segment statistics
        (the caster's hits are left stale); without `colour`, its depth and ids alone (rgb left unset)."""
        sensor = self.embodiment.sensor
        frame = new_frame(self.camera.height, self.camera.width, dense=False)
        spot = self.shader if colour and self.embodiment.illumination.kind == "spot" else None
        into = FramePass(frame, self.labels, self.colors if colour else None, sensor.near, sensor.far, spot)
        self.raycaster.cast(self.camera, camera_to_world, into=into)
        frame.segments = into.segments()
        return frame

    def buffers(self, hits: RayHits, rng: np.random.Generator | None = None,
                camera_to_world: np.ndarray | None = None) -> RenderedFrame:
        """RGB, depth (mm) and panoptic ids of traced hits (split from `render` so benchmarks can time it).
        `camera_to_world` (the pose of `hits`) is needed when the light has indirect bounces."""
        sensor = self.embodiment.sensor
        frame = new_frame(*hits.depth.shape)
        indirect = None
        if self.indirect is not None:
            if camera_to_world is None:
                raise ValueError("indirect light traces from the spot: pass the pose of the hits (camera_to_world)")
            indirect = self.indirect.irradiance(hits, camera_to_world, lights=self._traced_lights(camera_to_world))
        bands = range(len(self._bands))
        if self.raycaster.threads == 1:
            for band in bands:
                self._fill_band(hits, band, frame, indirect)
        else:
            list(thread_pool(self.raycaster.threads).map(lambda band: self._fill_band(hits, band, frame, indirect), bands))
        if self.sensor is None:
            return frame
        if rng is None:
            raise ValueError(f"sensor.model {sensor.model!r} draws noise: pass a seeded rng (context.rng)")
        # Whole frame, never by band: the noise draws follow the row-major order of the valid pixels.
        noisy = self.sensor.apply(hits.depth, hits, self.ray_lengths, rng)
        frame.depth_clean, frame.depth = frame.depth, depth_to_millimetres(noisy, sensor.near, sensor.far)
        return frame

    def _traced_lights(self, camera_to_world: np.ndarray) -> VirtualLights | None:
        """The virtual lights `trace` started for this pose (None when it traced another pose)."""
        pose, lights = self._lights if self._lights is not None else (None, None)
        self._lights = None
        return lights.result() if pose is not None and np.array_equal(pose, camera_to_world) else None

    def _fill_band(self, hits: RayHits, band: int, frame: RenderedFrame, indirect: np.ndarray | None = None) -> None:
        """Write the RGB, clean depth (mm), panoptic ids and dense labels of the rows of one band into `frame`."""
        rows, shader = self._bands[band]
        hits = hits.rows(rows)
        sensor = self.embodiment.sensor
        shader.shade_surfaces(self.colors, hits, out=frame.rgb[rows], indirect=indirect)
        _depth_and_labels(hits.depth, hits.face, np.float32(sensor.near), np.float32(sensor.far), self.labels.object_ids,
                          self.labels.dense_of_face, frame.depth[rows], frame.panoptic[rows], frame.dense[rows])


@numba.njit(nogil=True, cache=True)
def _any_clipped(depth, near, far):  # pragma: no cover (compiled)
    """Whether a hit (a finite depth) lies outside [near, far], compared in float32 as NumPy compares the float32
    depths with the clip range. Every pixel is tested (no early exit, no branch: vectorised): 0.07 ms a 640x480
    frame, where two whole-array comparisons and two counts took 0.17."""
    clipped = False
    for row in range(depth.shape[0]):
        for column in range(depth.shape[1]):
            z = depth[row, column]
            clipped |= ((z < near) | (z > far)) & (z < np.inf) & (z > -np.inf)  # NaN fails every comparison
    return clipped


@numba.njit(nogil=True, cache=True)
def _depth_and_labels(depth, face, near, far, object_ids, dense_of_face, millimetres, panoptic,
                      dense):  # pragma: no cover (compiled)
    """One pass over a band's rows for what three whole-array passes did: `depth_to_millimetres(depth, near,
    far)` (its float32 arithmetic and comparisons exactly: NumPy compares float32 depths with near and far
    as float32), and each pixel's panoptic id and dense label (`np.take(..., mode="clip")`: a miss, face F,
    picks the trailing 0 (void) of both tables). A row's depths, then its labels: the depth loop, without the
    table look-ups and with its tests combined by `&` (no branches), is vectorised. The whole pass on 24 bench
    frames, 1 thread, in turns with the single loop, median of 7: 0.67 -> 0.63 ms on a quiet machine, 1.24 -> 0.87
    with others' work on it (never slower in five runs)."""
    last = len(object_ids) - 1
    for row in range(depth.shape[0]):
        for column in range(depth.shape[1]):
            millimetres[row, column] = millimetres_of(depth[row, column], near, far)
        for column in range(depth.shape[1]):
            f = min(max(face[row, column], 0), last)
            panoptic[row, column] = object_ids[f]
            dense[row, column] = dense_of_face[f]


@functools.cache
def _light_tracer() -> ThreadPoolExecutor:
    """The thread that traces a frame's virtual lights while its camera rays are cast."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="virtual-lights")


def limit_worker_threads(threads: int) -> None:
    """Size OpenCV's thread pool (albedo planes, colour look-ups) and Zarr's (chunk compression) to a
    worker's CPU budget.

    Both count the host's cores, so 1-CPU Ray workers would each run several threads against each other's
    Embree casts: Zarr compresses a shard's 16 chunks in parallel, and a 1-CPU render worker kept 1.34
    cores busy (measured), which no second worker on the same cores can match. A per-process setting:
    call it once where a worker starts rendering, before it writes its first store, not in libraries.
    """
    cv2.setNumThreads(max(1, threads))
    zarr.config.set({"threading.max_workers": max(1, threads)})
