"""The columns of a Hugging Face export: `datasets` feature types and one block of frames as Arrow columns.

One row per frame. Pixels are stored losslessly, so decoding gives the run's arrays bit for bit:
`rgb` (PNG, uint8 RGB) and `depth` (16-bit grayscale PNG, uint16 mm) decode as `datasets.Image`
(PIL images; `np.asarray` gives the arrays), `panoptic` is `Array2D(uint32)` (Parquet dictionary
encoding plus zstd keeps its few ids per frame small). Field by field: schemas/hf_dataset.md.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
from PIL import Image as PilImage

if TYPE_CHECKING:
    import datasets

# zlib level of the PNGs: on the test room's 640x480 colour frames level 3 took 12.7 ms and 69 kB a frame,
# Pillow's default 6 30.6 ms and 49 kB (one measurement on the shared machine); zlib decodes both alike.
PNG_LEVEL = 3


def dataset_features(height: int, width: int) -> "datasets.Features":
    """The export's `datasets.Features` for frames of `height` x `width` pixels."""
    from datasets import Array2D, Features, Image, List, Value

    return Features({
        "video_name": Value("string"),
        "frame": Value("int32"),
        "embodiment": Value("string"),
        "scene_id": Value("string"),
        "camera_height_m": Value("float64"),
        "illumination": Value("string"),
        "rgb": Image(),
        "depth": Image(),
        "panoptic": Array2D((height, width), "uint32"),
        "pose": Array2D((4, 4), "float64"),
        "intrinsics": {"fx": Value("float64"), "fy": Value("float64"), "cx": Value("float64"),
                       "cy": Value("float64"), "width": Value("int32"), "height": Value("int32")},
        "object_ids": List(Value("uint32")),
        "object_categories": List(Value("int32")),
        "zero_shot_object_ids": List(Value("uint32")),
        "empty": Value("bool"),
        "zero_shot_rejected": Value("bool"),
        "accepted": Value("bool"),
    })


def parquet_schema(features: "datasets.Features") -> pa.Schema:
    """The shards' schema: `datasets`' own (`Array2D` as its Arrow extension type, the features in the
    `huggingface` schema metadata), so `datasets` decodes the shards even without the card; other Parquet
    readers (DuckDB, pyarrow alone) see the extension's storage, nested lists."""
    return features.arrow_schema


@dataclass(frozen=True)
class VideoFacts:
    """What every row of one video repeats: keys, camera, objects and the split stage's flags."""

    video_name: str
    embodiment: str
    scene_id: str
    camera_height_m: float
    illumination: str
    intrinsics: dict[str, float]
    object_ids: list[int]
    object_categories: list[int]
    zero_shot_object_ids: list[int]
    empty: bool | None
    zero_shot_rejected: bool | None
    accepted: bool | None


def png_bytes(pixels: np.ndarray) -> bytes:
    """One image as PNG: (H, W, 3) uint8 as RGB, (H, W) uint16 as 16-bit grayscale (Pillow mode I;16)."""
    buffer = io.BytesIO()
    PilImage.fromarray(pixels).save(buffer, format="PNG", compress_level=PNG_LEVEL)
    return buffer.getvalue()


def frame_block(schema: pa.Schema, facts: VideoFacts, first_frame: int, rgb: np.ndarray, depth: np.ndarray,
                panoptic: np.ndarray, poses: np.ndarray,
                encode: Callable[[list[np.ndarray]], list[bytes]] | None = None) -> pa.RecordBatch:
    """Rows for frames first_frame, first_frame + 1, ... of one video (arrays with a leading time axis).
    `encode` turns images into PNG bytes in order (default: one after the other, `png_bytes`)."""
    count = int(panoptic.shape[0])
    encoded = (encode or _encode_serially)([*rgb, *depth])
    repeat = lambda value: [value] * count  # noqa: E731
    intrinsics = {key: repeat(facts.intrinsics[key]) for key in ("fx", "fy", "cx", "cy")}
    intrinsics.update(width=repeat(int(facts.intrinsics["width"])), height=repeat(int(facts.intrinsics["height"])))
    columns: dict[str, Any] = {
        "video_name": repeat(facts.video_name),
        "frame": np.arange(first_frame, first_frame + count, dtype=np.int32),
        "embodiment": repeat(facts.embodiment),
        "scene_id": repeat(facts.scene_id),
        "camera_height_m": repeat(facts.camera_height_m),
        "illumination": repeat(facts.illumination),
        "rgb": _images(encoded[:count]),
        "depth": _images(encoded[count:]),
        "panoptic": _nested_lists(np.ascontiguousarray(panoptic, dtype=np.uint32)),
        "pose": _nested_lists(np.ascontiguousarray(poses, dtype=np.float64)),
        "intrinsics": [dict(zip(intrinsics, values)) for values in zip(*intrinsics.values())],
        "object_ids": repeat(facts.object_ids),
        "object_categories": repeat(facts.object_categories),
        "zero_shot_object_ids": repeat(facts.zero_shot_object_ids),
        "empty": repeat(facts.empty),
        "zero_shot_rejected": repeat(facts.zero_shot_rejected),
        "accepted": repeat(facts.accepted),
    }
    arrays = [_column(columns[field.name], field.type) for field in schema]
    return pa.RecordBatch.from_arrays(arrays, schema=schema)


def _encode_serially(images: list[np.ndarray]) -> list[bytes]:
    return [png_bytes(image) for image in images]


def _column(values: Any, kind: pa.DataType) -> pa.Array:
    if isinstance(kind, pa.ExtensionType):  # Array2D: nested lists wrapped in `datasets`' extension type
        return pa.ExtensionArray.from_storage(kind, values)
    return values if isinstance(values, pa.Array) else pa.array(values, type=kind)


def _images(encoded: list[bytes]) -> pa.StructArray:
    """`datasets.Image` storage: struct<bytes, path> with the file bytes and no path."""
    return pa.StructArray.from_arrays([pa.array(encoded, pa.binary()), pa.nulls(len(encoded), pa.string())],
                                      names=["bytes", "path"])


def _nested_lists(values: np.ndarray) -> pa.ListArray:
    """(N, H, W) array -> N rows of list<list<value>> (`Array2D` storage), without going through Python lists."""
    count, rows, columns = values.shape
    inner = pa.ListArray.from_arrays(pa.array(np.arange(0, count * rows * columns + 1, columns, dtype=np.int32)),
                                     pa.array(values.reshape(-1)))
    return pa.ListArray.from_arrays(pa.array(np.arange(0, count * rows + 1, rows, dtype=np.int32)), inner)
