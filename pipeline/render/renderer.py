"""One frame from a pose: ray cast, then every buffer (RGB, depth, panoptic) and its per-frame statistics.

`VideoRenderer` holds what is fixed for a video (scene BVH, camera, light, sensor) so that a frame costs
one ray cast plus vectorised numpy; `frame_segments` turns a panoptic frame into the rows of the
`segments` table (area and bounding box per object) in O(pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.config import Embodiment
from pipeline.render.lighting import Shader, SurfaceColors
from pipeline.render.raycaster import Camera, RayHits, SceneRaycaster
from pipeline.render.sensors import StructuredLightModel, depth_to_millimetres, sensor_model
from pipeline.scenes.scene import Scene


@dataclass
class RenderedFrame:
    """The buffers of one frame: rgb (H, W, 3) uint8, depth (H, W) uint16 mm, panoptic (H, W) uint32.

    `depth_clean` is the ideal depth when a sensor model made `depth` noisy, else None. `dense` is the
    panoptic frame as int32 indices into `SceneLabels.dense_ids` (for per-frame statistics; not stored).
    """

    rgb: np.ndarray
    depth: np.ndarray
    panoptic: np.ndarray
    depth_clean: np.ndarray | None = None
    dense: np.ndarray | None = None


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
    """

    def __init__(self, scene: Scene, embodiment: Embodiment, exposure: float, raycaster: SceneRaycaster | None = None,
                 colors: SurfaceColors | None = None, labels: SceneLabels | None = None):
        self.scene = scene
        self.embodiment = embodiment
        self.camera = camera_of(embodiment)
        self.raycaster = raycaster or SceneRaycaster(scene)
        self.colors = colors or SurfaceColors(scene)
        self.labels = labels or SceneLabels(scene)
        self.ray_lengths = np.linalg.norm(self.camera.directions(), axis=-1).astype(np.float32)
        self.shader = Shader(embodiment.illumination, exposure, self.ray_lengths)
        self.sensor: StructuredLightModel | None = sensor_model(embodiment.sensor.model)

    def trace(self, camera_to_world: np.ndarray) -> RayHits:
        """Ray cast one pose; hits outside the clip range [near, far] become misses (void, black, 0 mm)."""
        hits = self.raycaster.cast(self.camera, camera_to_world)
        sensor = self.embodiment.sensor
        clipped = hits.hit & ((hits.depth < sensor.near) | (hits.depth > sensor.far))
        if clipped.any():
            hits.hit &= ~clipped
            hits.face[clipped] = self.raycaster.miss_index
            hits.depth[clipped] = np.inf
        return hits

    def render(self, camera_to_world: np.ndarray, rng: np.random.Generator | None = None) -> RenderedFrame:
        """All buffers of one frame. `rng` feeds the sensor model (required unless the sensor is ideal)."""
        return self.buffers(self.trace(camera_to_world), rng)

    def buffers(self, hits: RayHits, rng: np.random.Generator | None = None) -> RenderedFrame:
        """RGB, depth (mm) and panoptic ids of traced hits (split from `render` so benchmarks can time it)."""
        sensor = self.embodiment.sensor
        panoptic = self.labels.object_ids[hits.face]  # a miss (face F) picks the trailing 0 (void)
        dense = self.labels.dense_of_face[hits.face]
        rgb = self.shader.shade(self.colors.albedo(hits), hits)
        clean = depth_to_millimetres(hits.depth, sensor.near, sensor.far)
        if self.sensor is None:
            return RenderedFrame(rgb=rgb, depth=clean, panoptic=panoptic, dense=dense)
        if rng is None:
            raise ValueError(f"sensor.model {sensor.model!r} draws noise: pass a seeded rng (context.rng)")
        noisy = self.sensor.apply(hits.depth, hits, self.ray_lengths, rng)
        return RenderedFrame(rgb=rgb, depth=depth_to_millimetres(noisy, sensor.near, sensor.far),
                             panoptic=panoptic, depth_clean=clean, dense=dense)


@dataclass
class FrameSegments:
    """Per-object statistics of one frame (arrays of length K, one entry per visible object, by id)."""

    object_ids: np.ndarray
    categories: np.ndarray
    areas: np.ndarray
    boxes: np.ndarray  # (K, 4) int32 x0, y0, x1, y1 (inclusive-exclusive)
    void_pixels: int


def frame_segments(panoptic: np.ndarray, labels: SceneLabels, dense: np.ndarray | None = None) -> FrameSegments:
    """Area and bounding box of every object visible in a panoptic frame, in O(pixels) (no sort).

    Args:
        panoptic: (H, W) uint32 ids of a frame of the scene `labels` describes.
        dense: the same frame as dense label indices (RenderedFrame.dense), when the renderer has it.
    """
    height, width = panoptic.shape
    if dense is None:
        dense = np.searchsorted(labels.dense_ids, panoptic).astype(np.int32)
    count = len(labels.dense_ids)
    areas = np.bincount(dense.ravel(), minlength=count)
    visible = np.flatnonzero(areas[1:]) + 1
    # Occupancy of (row, label) and (column, label) pairs by two bincounts over offset labels.
    rows = np.bincount((dense + (np.arange(height, dtype=np.int32) * count)[:, None]).ravel(),
                       minlength=height * count).reshape(height, count)[:, visible] > 0
    columns = np.bincount((dense + (np.arange(width, dtype=np.int32) * count)[None, :]).ravel(),
                          minlength=width * count).reshape(width, count)[:, visible] > 0
    boxes = np.stack([
        columns.argmax(axis=0), rows.argmax(axis=0),
        width - columns[::-1].argmax(axis=0), height - rows[::-1].argmax(axis=0),
    ], axis=1).astype(np.int32)
    return FrameSegments(labels.dense_ids[visible], labels.dense_categories[visible], areas[visible].astype(np.int64),
                         boxes, int(areas[0]))
