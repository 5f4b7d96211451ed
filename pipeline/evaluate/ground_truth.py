"""Ground-truth readers: an MVPd-layout split folder, or the rendered videos of one of our runs.

A reader lists `VideoSpec`s (small, JSON-able: they travel in unit params to Ray workers) and loads
one frame's full-resolution id image on demand. Zero-shot ids come from the split's `zero_shot.json`
matched to `instance_id_map` entries by (scene_name, colour), as the published MVPDataset does; in
our runs every object is non-zero-shot until a split stage exists.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.evaluate.errors import GroundTruthError

if TYPE_CHECKING:
    from pipeline.store.run_folder import RunFolder


@dataclass(frozen=True)
class VideoSpec:
    """What a worker needs to evaluate one video.

    Attributes:
        key: unique name in outputs (MVPd: the video name; runs: "<embodiment>/<video_name>").
        video_name: the folder name of its predictions (`<pred>/panomasksRLE/<video_name>/`).
        labels: per frame, the ground-truth file (MVPd: PNG path) or "" (runs: Zarr frame index).
        stems: per frame, the prediction file name without extension.
        zero_shot: ids of zero-shot objects.
        store: Zarr store of the video (runs only).
        embodiment: embodiment name (runs only).
    """

    key: str
    video_name: str
    labels: list[str]
    stems: list[str]
    zero_shot: list[int] = field(default_factory=list)
    store: str = ""
    embodiment: str = ""

    @property
    def frames(self) -> int:
        return len(self.stems)

    def to_params(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> "VideoSpec":
        return cls(**params)


def rgb_to_id(rgb: np.ndarray) -> np.ndarray:
    """COCO panoptic colour (H, W, 3) RGB -> id: R + 256 G + 256^2 B (uint32)."""
    height, width = rgb.shape[:2]
    pixels = height * width
    flat = np.ascontiguousarray(rgb[..., :3]).reshape(-1)
    ids = np.empty(pixels, dtype=np.uint32)
    if pixels == 0:
        return ids.reshape(height, width)
    # Read each pixel's 3 bytes (and the next pixel's first byte) as one little-endian uint32 through
    # a byte stride of 3, and mask the 4th byte off: one pass, where per-channel casts and shifts
    # (or a strided copy into RGBA) take 10-15 times longer.
    words = np.ndarray((pixels - 1,), dtype="<u4", buffer=flat, strides=(3,))
    np.bitwise_and(words, np.uint32(0xFFFFFF), out=ids[:-1])
    red, green, blue = (int(value) for value in flat[-3:])
    ids[-1] = red | (green << 8) | (blue << 16)
    return ids.reshape(height, width)


def _decode_rgb(data: np.ndarray) -> np.ndarray | None:
    """PNG bytes -> (H, W, 3) uint8 RGB, or None when undecodable.

    imagecodecs' libpng binding decodes about 40 % faster than OpenCV and is used when installed;
    anything it returns that is not 8-bit RGB(A) (grey, palette, 16-bit) goes through OpenCV, whose
    IMREAD_COLOR turns every PNG flavour into 8-bit colour (alpha dropped, as the published rgb2id does).
    """
    import cv2

    try:
        import imagecodecs
    except ModuleNotFoundError:
        imagecodecs = None
    if imagecodecs is not None:
        try:
            rgb = imagecodecs.png_decode(data)
        except imagecodecs.PngError:
            return None
        if rgb.dtype == np.uint8 and rgb.ndim == 3 and rgb.shape[2] in (3, 4):
            return rgb[..., :3]
    bgr = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    return None if bgr is None else bgr[..., ::-1]


def read_panoptic_png(path: Path) -> np.ndarray:
    """Full-resolution id image of an MVPd `panomasksRGB` PNG."""
    try:
        data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
    except FileNotFoundError:
        raise GroundTruthError(f"{path}: ground-truth frame missing; restore the MVPd split or drop the video "
                               "from empty_videos.json") from None
    rgb = _decode_rgb(data)
    if rgb is None:
        raise GroundTruthError(f"{path}: unreadable PNG; restore the file from the MVPd release")
    return rgb_to_id(rgb)


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise GroundTruthError(f"{path}: missing; {what}") from None
    except (ValueError, UnicodeDecodeError) as error:
        raise GroundTruthError(f"{path}: not valid JSON ({error}); restore the file from the MVPd release") from None


def _hex(color: list[int]) -> str:
    return "%02X%02X%02X" % tuple(int(c) for c in color[:3])


class MvpdSplit:
    """`<root>/<split>/` in the MVPd release layout (panoptic_<split>.json, panomasksRGB/, ...)."""

    def __init__(self, root: str | Path, split: str):
        self.root = Path(root)
        self.split = split
        self.folder = self.root / split
        self.annotation_file = self.folder / f"panoptic_{split}.json"
        if not self.annotation_file.is_file():
            raise GroundTruthError(f"{self.annotation_file}: missing; give --gt-mvpd the folder holding "
                                   f"{split}/panoptic_{split}.json (or the right --split)")

    def videos(self) -> list[VideoSpec]:
        """Every evaluated video (only `empty_videos.json` "accepted" ones when that file exists), by name."""
        data = _read_json(self.annotation_file, "give the MVPd split folder")
        try:
            videos = {v["video_name"]: v for v in data["videos"]}
            annotations = {a["video_name"]: a for a in data["annotations"]}
        except (KeyError, TypeError):
            raise GroundTruthError(f"{self.annotation_file}: needs 'videos' and 'annotations' lists with 'video_name'; "
                                   "restore the file from the MVPd release") from None
        accepted = self._accepted()
        zero_shot = self._zero_shot_colors()
        specs = []
        for name in sorted(videos):
            if accepted is not None and name not in accepted:
                continue
            if name not in annotations:
                raise GroundTruthError(f"{self.annotation_file}: video {name} has no entry in 'annotations'; restore the file")
            specs.append(self._spec(name, videos[name], annotations[name], zero_shot))
        return specs

    def _spec(self, name: str, video: dict, annotation: dict, zero_shot: dict[str, set[str]]) -> VideoSpec:
        try:
            images = [image["file_name"] for image in video["images"]]
            labels = [frame["file_name"] for frame in annotation["annotations"]]
            id_map = annotation.get("instance_id_map", {})
        except (KeyError, TypeError):
            raise GroundTruthError(f"{self.annotation_file}: video {name}: 'images' / 'annotations' entries need "
                                   "'file_name'; restore the file") from None
        if len(labels) < len(images):
            raise GroundTruthError(f"{self.annotation_file}: video {name} lists {len(images)} images but "
                                   f"{len(labels)} annotations; restore the file")
        folder = self.folder / "panomasksRGB" / name
        zero_shot_ids = sorted(int(key) for key, value in id_map.items()
                               if _hex(value.get("color", [0, 0, 0])) in zero_shot.get(str(value.get("scene_name")), set()))
        return VideoSpec(key=name, video_name=name, labels=[str(folder / f) for f in labels[: len(images)]],
                         stems=[Path(f).stem for f in images], zero_shot=zero_shot_ids)

    def _accepted(self) -> set[str] | None:
        path = self.folder / "empty_videos.json"
        if not path.is_file():
            return None
        data = _read_json(path, "")
        if not isinstance(data, dict) or not isinstance(data.get("accepted"), list):
            raise GroundTruthError(f"{path}: needs an 'accepted' list of video names; restore the file")
        return set(data["accepted"])

    def _zero_shot_colors(self) -> dict[str, set[str]]:
        path = self.folder / "zero_shot.json"
        if not path.is_file():
            return {}
        data = _read_json(path, "")
        by_scene: dict[str, set[str]] = {}
        for entry in data.get("zero-shot", []) if isinstance(data, dict) else []:
            by_scene.setdefault(str(entry["scene_name"]), set()).add(_hex(entry["color"]))
        return by_scene


def run_videos(run: RunFolder, embodiment: str | None = None) -> list[VideoSpec]:
    """The rendered videos of a run (`videos` table) as specs; every object non-zero-shot.

    Args:
        run: the run folder.
        embodiment: keep only this embodiment's videos; required when the run has several.
    """
    table = run.read("videos").to_pylist()
    if not table:
        raise GroundTruthError(f"{run.location}/videos: no rendered videos; run the render stage first (mvpd rerun RUN --stage render)")
    embodiments = sorted({row["embodiment"] for row in table})
    if embodiment is None and len(embodiments) > 1:
        raise GroundTruthError(f"{run.location}: the run has embodiments {', '.join(embodiments)}; choose one with --embodiment")
    if embodiment is not None and embodiment not in embodiments:
        raise GroundTruthError(f"{run.location}: no videos of embodiment {embodiment!r}; the run has {', '.join(embodiments)}")
    chosen = embodiment or embodiments[0]
    from pipeline.io.reader import video_locations

    locations = video_locations(run)  # local paths, or URLs on the run's object store
    specs = []
    for row in sorted((r for r in table if r["embodiment"] == chosen), key=lambda r: r["video_name"]):
        frames = int(row["frames"])
        specs.append(VideoSpec(key=f"{chosen}/{row['video_name']}", video_name=row["video_name"], labels=[""] * frames,
                               stems=[f"{t:010d}" for t in range(frames)], store=locations.get((chosen, row["video_name"]), str(run.root / row["store_path"])),
                               embodiment=chosen))
    return specs


class GroundTruthLoader:
    """Loads one video's full-resolution id frames, from PNGs (MVPd) or its Zarr store (runs)."""

    def __init__(self, spec: VideoSpec):
        self.spec = spec
        self._panoptic = None
        if spec.store:
            from pipeline.io.zarr_video import open_video

            try:
                self._panoptic = open_video(spec.store).panoptic
            except FileNotFoundError as error:
                raise GroundTruthError(str(error)) from None

    def __call__(self, frame: int) -> np.ndarray:
        if self._panoptic is not None:
            return np.asarray(self._panoptic[frame])
        return read_panoptic_png(Path(self.spec.labels[frame]))
