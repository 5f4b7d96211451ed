"""Prediction readers: per-frame COCO RLE files (JSON, or the published `.pt` containers), or a Zarr
array of instance ids per video.

Layouts under the prediction folder `<pred>`:
    panomasksRLE/<video>/<frame_stem>.json   {"coco_rle": [{"size": [H, W], "counts": "..."}, ...]}
                                             (masks may overlap, in any order; [] = no masks; an
                                             optional "ids": [...] makes them tracked, one id per mask)
    panomasksRLE/<video>/<frame_stem>.pt     the same dict saved with torch.save (needs PyTorch)
    <video>.zarr                             (T, H, W) integer ids of a tracker, 0 = nothing; the
                                             array at the store root or named "ids" / "panoptic"
Readers check every mask's size against the ground truth and validate the RLE; errors name the file.
A frame holds at most MAX_MASKS_PER_FRAME masks (ids): its arrays grow with pixels x masks, so that bounds
the memory one frame can take (about 600 MB at 640x480 in the worst case, 1 MB for a typical frame).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import error_text
from pipeline.evaluate.errors import MissingPredictionError, PredictionError
from pipeline.evaluate.frames import (PredictionFrame, TooManyMasksError, prediction_frame_from_ids,
                                      prediction_frame_from_runs, subsampled_shape)
from pipeline.evaluate.rle import Runs, decode_counts, decode_joined_counts, runs_from_lengths, subsample_runs

RLE_FOLDER = "panomasksRLE"
# Far above any segmenter's output (MVPd's frames show ~70 objects; SAM's automatic mask generator keeps a
# few hundred at most).
MAX_MASKS_PER_FRAME = 1024


class PredictionSource:
    """The predictions of one video, read frame by frame.

    Args:
        root: the prediction folder `<pred>`.
        video_name: the video's folder / store name.
        stems: per frame, the file name without extension.
        allow_missing: a missing frame file counts as a frame without masks (and is recorded in
            `missing`) instead of raising `MissingPredictionError`.
    """

    def __init__(self, root: str | Path, video_name: str, stems: list[str], allow_missing: bool = False):
        self.root = Path(root)
        self.video_name = video_name
        self.stems = stems
        self.allow_missing = allow_missing
        self.missing: list[int] = []
        self.folder = self.root / RLE_FOLDER / video_name
        self.store = self.root / f"{video_name}.zarr"
        self._ids = None
        if not self.folder.is_dir():
            if not self.store.is_dir():
                raise MissingPredictionError(f"{self.folder}: no predictions for video {video_name} "
                                             f"(nor {self.store.name}); predict this video or leave it out of the split")
            self._ids = _open_id_array(self.store)

    def frame(self, index: int, shape: tuple[int, int], stride: int) -> PredictionFrame:
        """Frame `index` as a PredictionFrame, checked against the ground truth's full-resolution shape."""
        if self._ids is not None:
            return self._id_frame(index, shape, stride)
        stem = self.stems[index]
        path = self.folder / f"{stem}.json"
        if not path.is_file() and (self.folder / f"{stem}.pt").is_file():
            path = self.folder / f"{stem}.pt"
        if not path.is_file():
            if not self.allow_missing:
                raise MissingPredictionError(f"{path}: prediction frame missing; write it (an empty 'coco_rle' list "
                                             "is allowed) or pass --allow-missing to count it as empty")
            self.missing.append(index)
            rows, columns = subsampled_shape(*shape, stride)
            return prediction_frame_from_runs(_no_runs(), 0, rows * columns)
        return rle_frame(read_rle_file(path), shape, stride, str(path))

    def _id_frame(self, index: int, shape: tuple[int, int], stride: int) -> PredictionFrame:
        array = self._ids
        assert array is not None
        if tuple(array.shape[1:]) != tuple(shape) or array.shape[0] != len(self.stems):
            raise PredictionError(f"{self.store}: id array has shape {tuple(array.shape)}, expected "
                                  f"({len(self.stems)}, {shape[0]}, {shape[1]}); predict every frame at the ground truth's size")
        frame = _read_id_frame(self.store, array, index)
        if not np.issubdtype(frame.dtype, np.integer):
            raise PredictionError(f"{self.store}: id array of {frame.dtype}, not integers; store the tracker's ids as integers")
        try:
            return prediction_frame_from_ids(frame, stride, MAX_MASKS_PER_FRAME)
        except TooManyMasksError as error:
            raise PredictionError(f"{self.store}: frame {index} holds {error.args[0]} ids, more than "
                                  f"{MAX_MASKS_PER_FRAME}; is this an id array (0 = nothing, one id per tracked "
                                  "object)?") from None


def _read_id_frame(store: Path, array: Any, index: int) -> np.ndarray:
    """Frame `index` of a Zarr id array; a chunk that cannot be read or decoded is one line naming the store."""
    try:
        return np.asarray(array[index])
    except Exception as error:  # noqa: BLE001 - zarr and its codecs raise many types for a damaged chunk
        raise PredictionError(f"{store}: frame {index} cannot be read ({type(error).__name__}: "
                              f"{error_text(error, 120)}); rewrite the id array") from None


def _open_id_array(store: Path) -> Any:
    import zarr

    try:
        node = zarr.open(str(store), mode="r")
    except Exception as error:  # noqa: BLE001 - zarr raises many types for damaged metadata (JSON, keys, types)
        raise PredictionError(f"{store}: unreadable Zarr store ({type(error).__name__}: {error_text(error, 120)}); "
                              "rewrite it") from None
    if isinstance(node, zarr.Group):
        for name in ("ids", "panoptic"):
            if name in node:
                return node[name]
        raise PredictionError(f"{store}: Zarr group without an 'ids' or 'panoptic' array; store the (T, H, W) ids as 'ids'")
    return node


def _no_runs() -> Runs:
    empty = np.zeros(0, dtype=np.int64)
    return Runs(empty, empty, empty)


def read_rle_file(path: Path) -> dict[str, Any]:
    """The dict stored in a prediction file (`.json`, or `.pt` through torch)."""
    if path.suffix == ".pt":
        try:
            import torch
        except ModuleNotFoundError:
            raise PredictionError(f"{path}: .pt predictions need PyTorch; `pip install torch` or convert them to "
                                  ".json files with the same {'coco_rle': [...]} content") from None
        try:
            data = torch.load(path, map_location="cpu")
        except (RuntimeError, OSError, ValueError) as error:
            raise PredictionError(f"{path}: unreadable .pt file ({error}); rewrite it") from None
    else:
        try:
            data = json.loads(path.read_bytes())
        except (ValueError, RecursionError) as error:  # UnicodeDecodeError is a ValueError; nesting too deep for json
            raise PredictionError(f"{path}: not valid JSON ({error_text(error, 120)}); rewrite it as "
                                  "{\"coco_rle\": [...]}") from None
    if not isinstance(data, dict) or not isinstance(data.get("coco_rle"), list):
        raise PredictionError(f"{path}: needs a 'coco_rle' list (possibly empty); rewrite it as {{\"coco_rle\": [...]}}")
    if len(data["coco_rle"]) > MAX_MASKS_PER_FRAME:
        raise PredictionError(f"{path}: {len(data['coco_rle'])} masks, more than {MAX_MASKS_PER_FRAME} in one frame; "
                              "keep the model's best masks")
    return data


def rle_frame(data: dict[str, Any], shape: tuple[int, int], stride: int, source: str) -> PredictionFrame:
    """{"coco_rle": [...], optional "ids"} -> PredictionFrame, validating sizes and RLE."""
    rles = data["coco_rle"]
    height, width = shape
    lengths, offsets = _fast_lengths(rles, [height, width], source)
    if lengths is None:
        lengths, offsets = _lengths(_checked_counts(rles, height, width, source), source)
    runs = subsample_runs(runs_from_lengths(lengths, offsets, height * width, source), height, width, stride)
    rows, columns = subsampled_shape(height, width, stride)
    ids = _tracker_ids(data, len(rles), source)
    return prediction_frame_from_runs(runs, len(rles), rows * columns, ids)


def _fast_lengths(rles: list[Any], size: list[int], source: str) -> tuple[Any, Any]:
    """The common case in one pass: every mask a dict of the right size with a compressed string.

    Returns (None, None) when any mask is not, so `_checked_counts` can name the faulty one.
    """
    try:
        if not all(rle["size"] == size for rle in rles):
            return None, None
        strings = [rle["counts"] for rle in rles]
    except (KeyError, TypeError):
        return None, None
    if not all(type(value) is str for value in strings):
        return None, None
    try:
        joined = "".join(strings).encode("ascii")
    except UnicodeEncodeError:
        raise PredictionError(f"{source}: corrupt RLE (non-ASCII character in 'counts'); re-encode the masks with pycocotools") from None
    return decode_joined_counts(joined, [len(value) for value in strings], source)


def _checked_counts(rles: list[Any], height: int, width: int, source: str) -> list[Any]:
    """Per-mask validation with an error naming the mask; counts as bytes (compressed) or lists."""
    counts: list[Any] = []
    for index, rle in enumerate(rles):
        size = rle.get("size") if isinstance(rle, dict) else None
        if not isinstance(size, (list, tuple)) or list(size) != [height, width]:
            raise PredictionError(f"{source}: mask {index} has size {size}, the ground truth is {height}x{width}; "
                                  "predict at the ground truth's full resolution")
        value = rle.get("counts")
        if isinstance(value, str):
            try:
                value = value.encode("ascii")
            except UnicodeEncodeError:
                raise PredictionError(f"{source}: corrupt RLE (mask {index}: non-ASCII character in 'counts'); "
                                      "re-encode the mask with pycocotools") from None
        if not isinstance(value, (bytes, list)):
            raise PredictionError(f"{source}: mask {index} has no 'counts' string; re-encode it with pycocotools")
        counts.append(value)
    return counts


def _lengths(counts: list[bytes | list], source: str) -> tuple[np.ndarray, np.ndarray]:
    """Run lengths of compressed (bytes) and uncompressed (list of ints) counts, in mask order."""
    if all(isinstance(c, bytes) for c in counts):
        return decode_counts(counts, source)  # type: ignore[arg-type]
    pieces = []
    for value in counts:
        if isinstance(value, bytes):
            pieces.append(decode_counts([value], source)[0])
        elif all(type(count) is int and 0 <= count < 2**62 for count in value):
            pieces.append(np.asarray(value, dtype=np.int64))
        else:  # a float would be truncated, a bool taken for 0/1, a huge number overflow int64
            raise PredictionError(f"{source}: corrupt RLE (uncompressed counts are not all integers from 0 to 2^62); "
                                  "re-encode the mask")
    offsets = np.concatenate([[0], np.cumsum([p.size for p in pieces])]).astype(np.int64)
    return (np.concatenate(pieces) if pieces else np.zeros(0, dtype=np.int64)), offsets


def _tracker_ids(data: dict[str, Any], masks: int, source: str) -> np.ndarray | None:
    ids = data.get("ids")
    if ids is None:
        return None
    if not isinstance(ids, list) or len(ids) != masks or not all(type(i) is int and 0 < i < 2**63 for i in ids):
        raise PredictionError(f"{source}: 'ids' must list one positive integer per mask of 'coco_rle'; fix or drop it")
    return np.asarray(ids, dtype=np.int64)
