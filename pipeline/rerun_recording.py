"""A video of a run as a Rerun recording (`mvpd view`): what a robotics researcher opens to check a dataset.

The recording holds, in the world frame (+Y up, metres):
    world/scene               the scene mesh, each object one colour (static)
    world/trajectory          the camera path (static)
    world/camera              the camera pose per frame (timeline `frame`)
    world/camera/image        its pinhole (OpenCV axes: x right, y down, z forward), the objects' names
    world/camera/image/rgb    the RGB frame
    world/camera/image/depth  the depth frame (millimetres)
    world/camera/image/panoptic  the panoptic masks as class ids, named "<raw name> #<object id>"
    world/points              the depth frame back-projected into the world, coloured by the RGB frame

Panoptic object ids (HM3DSem: 24-bit colours) are renumbered 1..K per video, because Rerun's class
ids are 16-bit; the names carry the real object ids. The mesh and the masks share each object's colour.
Needs the `view` extra (rerun-sdk).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from pipeline.io.reader import LoadedVideo, VideoNotFoundError, load_video
from pipeline.scenes.categories import categories
from pipeline.scenes.scans import palette_color
from pipeline.scenes.scene import Scene
from pipeline.store.names import replaced
from pipeline.store.run_folder import RunFolder

LOG = logging.getLogger(__name__)
VOID_COLOR = (0, 0, 0)


class RecordingError(ValueError):
    """A recording that cannot be written; the message names the run, video or file and the fix."""


@dataclass(frozen=True)
class WrittenRecording:
    """What `write_recording` wrote."""

    path: Path
    embodiment: str
    video_name: str
    frames: int
    objects: int


def find_video(run: RunFolder, name: str, embodiment: str | None) -> dict[str, Any]:
    """The `videos` row of a video name (and embodiment); the name is looked up, never used as a path."""
    rows = [r for r in run.read("videos").select(["embodiment", "video_name", "scene_id"]).to_pylist()
            if r["video_name"] == name and (embodiment is None or r["embodiment"] == embodiment)]
    if not rows:
        raise VideoNotFoundError(f"{run.location}: no rendered video {name!r}"
                                 f"{f' of embodiment {embodiment!r}' if embodiment else ''}; "
                                 f"`mvpd query {run.location} \"select embodiment, video_name from videos\"` lists them")
    if len(rows) > 1:
        raise VideoNotFoundError(f"{run.location}: video {name!r} exists for embodiments "
                                 f"{', '.join(sorted(r['embodiment'] for r in rows))}; pass --embodiment")
    return rows[0]


def _scene_of(run: RunFolder, scene_id: str) -> Scene:
    from pipeline.scenes.sources import load_scene_row

    rows = [r for r in run.read("scenes").to_pylist() if r["scene_id"] == scene_id]
    if not rows:
        raise RecordingError(f"{run.location}: scene {scene_id!r} of the video is not in the scenes table; rerun `shard`")
    return load_scene_row(rows[0])


def object_mesh(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, triangles and colours of the scene with each object one flat colour (corners unshared)."""
    corners = scene.vertices[scene.faces].reshape(-1, 3).astype(np.float32)
    ids = scene.face_object_ids
    unique, inverse = np.unique(ids, return_inverse=True)
    palette = np.array([palette_color(int(i)) if i else VOID_COLOR for i in unique], np.uint8)
    colors = np.repeat(palette[inverse.reshape(-1)], 3, axis=0)
    return corners, np.arange(len(corners), dtype=np.uint32).reshape(-1, 3), colors


def world_points(depth_mm: np.ndarray, rgb: np.ndarray, pose: np.ndarray, intrinsics: dict[str, float],
                 stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Every `stride`-th pixel with depth, back-projected into the world, and its RGB colour."""
    rows, cols = np.mgrid[0:depth_mm.shape[0]:stride, 0:depth_mm.shape[1]:stride]
    z = depth_mm[rows, cols].astype(np.float64) / 1000.0
    valid = z > 0
    rows, cols, z = rows[valid], cols[valid], z[valid]
    camera = np.stack([(cols + 0.5 - intrinsics["cx"]) / intrinsics["fx"] * z,
                       (rows + 0.5 - intrinsics["cy"]) / intrinsics["fy"] * z, z], axis=1)
    return (camera @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32), rgb[rows, cols]


def _class_table(video: LoadedVideo) -> tuple[np.ndarray, list[tuple[int, str, tuple[int, int, int]]]]:
    """Sorted object ids of the video and (class id, label, colour) per object (class 0 = void)."""
    ids = np.array(sorted(video.categories), dtype=np.int64)
    names = categories()
    classes = [(0, "void", VOID_COLOR)]
    for k, object_id in enumerate(ids.tolist(), start=1):
        raw = video.raw_names.get(object_id) or names.get(video.categories[object_id], names[0]).name
        classes.append((k, f"{raw} #{object_id}", tuple(int(v) for v in palette_color(object_id))))
    return ids, classes


def class_ids(panoptic: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(H, W) uint16 class ids: 1..K for the video's objects in id order, 0 for void or unknown ids."""
    position = np.searchsorted(ids, panoptic)
    clipped = np.minimum(position, max(len(ids) - 1, 0))
    known = (len(ids) > 0) & (ids[clipped] == panoptic) if len(ids) else np.zeros(panoptic.shape, bool)
    return np.where(known, position + 1, 0).astype(np.uint16)


def write_recording(run: RunFolder, name: str, out: Path, embodiment: str | None = None, point_stride: int = 2,
                    on_frame: Callable[[int, int], None] | None = None) -> WrittenRecording:
    """Write the Rerun recording of one video (see module doc) to `out` (written beside, then renamed)."""
    try:
        import rerun as rr
    except ImportError:
        raise RecordingError("mvpd view needs rerun-sdk: pip install 'mvpd-pipeline[view]'") from None
    row = find_video(run, name, embodiment)
    video = load_video(run, row["video_name"], row["embodiment"])
    scene = _scene_of(run, row["scene_id"])
    ids, classes = _class_table(video)
    out.parent.mkdir(parents=True, exist_ok=True)
    with replaced(out) as temporary:  # renamed over `out` at the end: a new file, never a shared one
        recording = rr.RecordingStream("mvpd-view", recording_id=f"{row['embodiment']}/{row['video_name']}")
        recording.save(str(temporary))
        _log_static(rr, recording, scene, video, classes)
        intrinsics = video.intrinsics
        image_from_camera = np.array([[intrinsics["fx"], 0, intrinsics["cx"]], [0, intrinsics["fy"], intrinsics["cy"]],
                                      [0, 0, 1]])
        pinhole = rr.Pinhole(image_from_camera=image_from_camera, resolution=[intrinsics["width"], intrinsics["height"]],
                             camera_xyz=rr.ViewCoordinates.RDF)
        recording.log("world/camera/image", pinhole, static=True)
        for index in range(video.frames):
            frame = video.frame(index)
            recording.set_time("frame", sequence=index)
            pose = frame["poses"]
            recording.log("world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
            recording.log("world/camera/image/rgb", rr.Image(frame["rgb"]))
            recording.log("world/camera/image/depth", rr.DepthImage(frame["depth"], meter=1000.0))
            recording.log("world/camera/image/panoptic", rr.SegmentationImage(class_ids(frame["panoptic"], ids)))
            points, colors = world_points(frame["depth"], frame["rgb"], pose, intrinsics, point_stride)
            recording.log("world/points", rr.Points3D(points, colors=colors, radii=0.01))
            if on_frame is not None:
                on_frame(index + 1, video.frames)
        recording.flush()
        recording.disconnect()
    return WrittenRecording(out, row["embodiment"], row["video_name"], video.frames, len(classes) - 1)


def _log_static(rr: Any, recording: Any, scene: Scene, video: LoadedVideo,
                classes: list[tuple[int, str, tuple[int, int, int]]]) -> None:
    """The world axes, the scene mesh coloured by object, the camera path and the objects' names."""
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)
    positions, triangles, colors = object_mesh(scene)
    recording.log("world/scene", rr.Mesh3D(vertex_positions=positions, triangle_indices=triangles,
                                           vertex_colors=colors), static=True)
    recording.log("world/trajectory", rr.LineStrips3D([video.poses[:, :3, 3]], colors=[(20, 90, 230)]), static=True)
    recording.log("world/camera/image", rr.AnnotationContext(
        [rr.AnnotationInfo(id=k, label=label, color=color) for k, label, color in classes]), static=True)
