"""The MVPd release layout: paths, id <-> colour encodings, pose convention and JSON reading.

Everything both directions (export and import) must agree on lives here, so the two cannot drift.
The mapping to our run layout is documented in schemas/mvpd.md.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.scenes.categories import STUFF_CATEGORIES, categories
from pipeline.store.names import atomic_write_text

# MVPd's camera (DESIGN.md): 640 x 480, 69 degrees horizontal field of view; imports keep the files' size.
MVPD_HFOV_DEGREES = 69.0
MVPD_FX = 465.6029  # the focal length the authors' loader hard-codes (fx = fy; cx = 320, cy = 240)
# The MVPd rule for empty videos: any frame with more than this fraction of void pixels.
EMPTY_VOID_FRACTION = 0.5
# Fixed JPEG settings so that two exports of the same run are byte-identical.
JPEG_QUALITY = 95
MAX_MVPD_ID = (1 << 24) - 1  # ids and colours are 24-bit RGB triplets

PANOMASKS = "panomasksRGB"
IMAGES_RGB = "imagesRGB"
IMAGES_DEPTH = "imagesDEPTH"
EMPTY_VIDEOS = "empty_videos.json"
ZERO_SHOT = "zero_shot.json"
_VIDEO_NAME = re.compile(r"^(?P<scene>.+)\.(?P<trajectory>\d{10})\.(?P<height_mm>\d{10})$")

# Both MVPd's world and its camera differ from ours by a 180 degree rotation about X, i.e. by
# F = diag(1, -1, -1) (schemas/mvpd.md derives it). F is its own inverse, so the same map converts
# in both directions: R' = F R F, t' = F t, which for quaternions is (w, x, -y, -z).
_FLIP = np.diag([1.0, -1.0, -1.0])


class MvpdFormatError(ValueError):
    """An MVPd release folder or file that cannot be read; the message names the file and the fix."""


@dataclass(frozen=True)
class SplitPaths:
    """The files of one split of an MVPd release: `<root>/<split>/...`."""

    root: Path
    split: str

    @property
    def folder(self) -> Path:
        return self.root / self.split

    @property
    def annotations(self) -> Path:
        return self.folder / f"panoptic_{self.split}.json"

    @property
    def empty_videos(self) -> Path:
        return self.folder / EMPTY_VIDEOS

    @property
    def zero_shot(self) -> Path:
        return self.folder / ZERO_SHOT

    def panomask(self, video: str, file_name: str) -> Path:
        return self.folder / PANOMASKS / video / file_name

    def rgb_folder(self, video: str) -> Path:
        return self.folder / IMAGES_RGB / video

    def depth_folder(self, video: str) -> Path:
        return self.folder / IMAGES_DEPTH / video


def frame_stem(frame: int) -> str:
    """MVPd frame file stem: the frame index, 10 digits."""
    return f"{frame:010d}"


@dataclass(frozen=True)
class VideoName:
    """The parts of `<scene_id>.<trajectory:010d>.<sensor_height_mm:010d>`."""

    scene_id: str
    trajectory: int
    height_mm: int

    @property
    def height_m(self) -> float:
        return self.height_mm / 1000.0


def parse_video_name(name: str, source: Path) -> VideoName:
    """Split a video name into scene, trajectory and height; `source` names the file for errors."""
    match = _VIDEO_NAME.match(name)
    if match is None:
        raise MvpdFormatError(
            f"{source}: video name {name!r} is not <scene_id>.<trajectory:010d>.<height_mm:010d>; fix the name"
        )
    return VideoName(match["scene"], int(match["trajectory"]), int(match["height_mm"]))


# ------------------------------------------------------------------------------------ ids, colours


def png_to_ids(rgb: np.ndarray) -> np.ndarray:
    """COCO panoptic PNG (H, W, 3) uint8 -> (H, W) uint32 ids, id = R + 256 G + 256^2 B."""
    rgb = rgb.astype(np.uint32)
    return rgb[..., 0] + (rgb[..., 1] << 8) + (rgb[..., 2] << 16)


def ids_to_png(ids: np.ndarray) -> np.ndarray:
    """(H, W) ids < 2^24 -> COCO panoptic PNG pixels (H, W, 3) uint8 (inverse of `png_to_ids`)."""
    ids = ids.astype(np.uint32)
    return np.stack([ids & 0xFF, (ids >> 8) & 0xFF, (ids >> 16) & 0xFF], axis=-1).astype(np.uint8)


def color_to_object_id(color: list[int] | tuple[int, int, int]) -> int:
    """HM3DSem colour [R, G, B] -> our object id 0xRRGGBB (the object's identity within its scene)."""
    red, green, blue = (int(c) for c in color)
    return (red << 16) | (green << 8) | blue


def object_id_to_color(object_id: int) -> list[int]:
    """Our object id 0xRRGGBB -> the HM3DSem colour [R, G, B] that `zero_shot.json` names."""
    return [(object_id >> 16) & 0xFF, (object_id >> 8) & 0xFF, object_id & 0xFF]


def mvpd_categories() -> list[dict[str, Any]]:
    """The `categories` list of a panoptic JSON: mpcat40 1..40 (41 `unlabeled` is left out, as the authors'
    builder stops at 40); wall, floor and ceiling are stuff."""
    return [
        {"id": c.index, "name": c.name, "isthing": 0 if c.index in STUFF_CATEGORIES else 1, "color": list(c.rgb)}
        for index, c in sorted(categories().items())
        if 0 < index <= 40
    ]


# ------------------------------------------------------------------------------------------ poses


def quaternion_to_matrix(quaternion: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> 3x3 rotation matrix (normalised first)."""
    w, x, y, z = np.asarray(quaternion, dtype=np.float64) / np.linalg.norm(quaternion)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix -> unit quaternion (w, x, y, z) with w >= 0 (Shepperd's stable branch choice)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    # Pick the largest of 4w^2, 4x^2, 4y^2, 4z^2 as the divisor: no cancellation near 180 degrees.
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    largest = int(np.argmax(candidates))
    if largest == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif largest == 1:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif largest == 2:
        s = 2.0 * np.sqrt(1.0 - m[0, 0] + m[1, 1] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 - m[0, 0] - m[1, 1] + m[2, 2])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    quaternion = np.asarray(q) / np.linalg.norm(q)
    return -quaternion if quaternion[0] < 0 else quaternion


def pose_to_mvpd(pose: np.ndarray) -> tuple[list[float], list[float]]:
    """Our 4x4 camera-to-world (OpenCV camera, +Y-up world) -> MVPd (camera_position, camera_rotation).

    MVPd's camera is OpenGL-like and its world is ours turned 180 degrees about X: T' = F T F.
    """
    rotation = _FLIP @ pose[:3, :3] @ _FLIP
    position = _FLIP @ pose[:3, 3]
    return [float(v) for v in position], [float(v) for v in matrix_to_quaternion(rotation)]


def pose_from_mvpd(position: list[float], rotation: list[float]) -> np.ndarray:
    """MVPd (camera_position [x, y, z], camera_rotation [w, x, y, z]) -> our 4x4 camera-to-world."""
    pose = np.eye(4)
    pose[:3, :3] = _FLIP @ quaternion_to_matrix(np.asarray(rotation)) @ _FLIP
    pose[:3, 3] = _FLIP @ np.asarray(position, dtype=np.float64)
    return pose


# ------------------------------------------------------------------------------------------- JSON


def read_json(path: Path, what: str) -> Any:
    """Parse a JSON file of the release; a missing or broken file is a one-line MvpdFormatError."""
    if not path.is_file():
        raise MvpdFormatError(f"{path}: no such file; give the MVPd root that holds {what}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise MvpdFormatError(f"{path}: not valid JSON ({error}); re-download or re-export the file") from None


def require(mapping: Any, key: str, kind: type, source: Path, where: str) -> Any:
    """`mapping[key]` checked to be a `kind`; otherwise a one-line error naming file and key path."""
    if not isinstance(mapping, dict) or key not in mapping:
        raise MvpdFormatError(f"{source}: {where}.{key}: required key is missing; is this an MVPd panoptic file?")
    value = mapping[key]
    if not isinstance(value, kind):
        raise MvpdFormatError(f"{source}: {where}.{key}: expected {kind.__name__}, got {type(value).__name__}")
    return value


def write_json(path: Path, data: Any) -> None:
    """Deterministic JSON (fixed key order as built, compact separators like MVPd's files)."""
    atomic_write_text(path, json.dumps(data, separators=(", ", ": ")))
