"""Fuzzing the prediction readers `mvpd evaluate` uses (`pipeline.evaluate.predictions`, schemas/predictions.md):
per-frame COCO RLE JSON files and a tracker's Zarr id array. Valid files are written by the project's own
writer (`rle_payload`, pycocotools' encoder) and by zarr, then broken: a JSON value swapped for one of the
wrong type, huge, negative, deeply nested or not finite; bytes cut, NUL, not UTF-8; a Zarr's metadata or a
chunk broken or gone. Every example ends in a prediction frame or a one-line PredictionError naming the
file, within 30 s and 256 MB."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr
from hypothesis import given
from hypothesis import strategies as st

from pipeline.evaluate.errors import PredictionError
from pipeline.evaluate.predictions import RLE_FOLDER, PredictionSource
from pipeline.models.predict import rle_payload
from tests.fuzz.bounds import within
from tests.fuzz.breaking import broken_bytes
from tests.fuzz.outcome import result_or_one_line_error

SECONDS, MEGABYTES = 30, 256
VIDEO = "s.0000000000.0000001000"


@st.composite
def frames(draw: st.DrawFn) -> tuple[tuple[int, int], dict[str, Any]]:
    """A frame's shape and a valid prediction file's content: a few random masks, maybe tracked."""
    height, width = draw(st.integers(2, 16)), draw(st.integers(2, 16))
    count = draw(st.integers(0, 5))
    seed = draw(st.integers(0, 2**32 - 1))
    masks = np.random.default_rng(seed).random((count, height, width)) < draw(st.floats(0.0, 1.0))
    ids = draw(st.none() | st.lists(st.integers(1, 9), min_size=count, max_size=count).map(np.array))
    return (height, width), rle_payload(masks, ids)


BAD_JSON_VALUES = st.one_of(
    st.sampled_from([None, True, False, 0, -1, 1.5, "", "0", "PPX1", "\x00", "é", [], {}, [[]], [-5, 3], [2**70],
                     [1.5, 2], 10**400, float("inf"), float("nan"), -(10**30)]),
    st.integers(), st.floats(), st.text(max_size=12),
    st.lists(st.integers(-(2**65), 2**65), max_size=6),
    st.lists(st.integers(0, 50), max_size=40),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=3),
)


def _paths(value: Any, path: tuple = ()) -> list[tuple]:
    """Every place in a JSON value (the value itself included), as a path of keys and indices."""
    found = [path]
    if isinstance(value, dict):
        for key, item in value.items():
            found += _paths(item, (*path, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            found += _paths(item, (*path, index))
    return found


def _replaced(value: Any, path: tuple, new: Any) -> Any:
    if not path:
        return new
    copy = dict(value) if isinstance(value, dict) else list(value)
    copy[path[0]] = _replaced(value[path[0]], path[1:], new)
    return copy


@st.composite
def broken_frame_files(draw: st.DrawFn) -> tuple[tuple[int, int], bytes]:
    """A frame's shape and its prediction file, broken in its JSON structure or in its bytes."""
    shape, payload = draw(frames())
    how = draw(st.sampled_from(("value", "value", "nest", "bytes", "none")))
    if how == "value":
        payload = _replaced(payload, draw(st.sampled_from(_paths(payload))), draw(BAD_JSON_VALUES))
    text = json.dumps(payload).encode()
    if how == "nest":  # deeper than json's recursion allows, at the top or as a mask's counts
        depth = draw(st.integers(2, 100_000))
        nested = b"[" * depth + b"]" * depth
        text = nested if draw(st.booleans()) else b'{"coco_rle": [{"size": [2, 2], "counts": ' + nested + b"}]}"
    elif how == "bytes":
        text = draw(broken_bytes(text))
    return shape, text


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz-predictions")


def _read_frame(root: Path, shape: tuple[int, int], stride: int) -> int:
    frame = PredictionSource(root, VIDEO, ["0000000000"]).frame(0, shape, stride)
    return frame.masks


@given(case=broken_frame_files(), stride=st.integers(1, 3))
def test_a_broken_rle_file_is_a_frame_or_one_line(folder, case, stride):
    shape, text = case
    path = folder / RLE_FOLDER / VIDEO / "0000000000.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(text)
    result_or_one_line_error(lambda: within(lambda: _read_frame(folder, shape, stride), SECONDS, MEGABYTES),
                             PredictionError, str(path))


@st.composite
def broken_id_stores(draw: st.DrawFn) -> tuple[tuple[int, int], int, str, bytes | None]:
    """A tracker's id array (frames, shape) and how to break it: which file of the store, and its new bytes
    (None: the file is deleted)."""
    frames_, height, width = draw(st.integers(1, 3)), draw(st.integers(2, 12)), draw(st.integers(2, 12))
    return (height, width), frames_, draw(st.sampled_from(("metadata", "chunk"))), draw(st.none() | st.binary(max_size=64))


def _write_ids(store: Path, frames_: int, shape: tuple[int, int], seed: int) -> None:
    shutil.rmtree(store, ignore_errors=True)
    array = zarr.open_array(str(store), mode="w", shape=(frames_, *shape), chunks=(1, *shape), dtype="uint32")
    array[:] = np.random.default_rng(seed).integers(0, 4, (frames_, *shape))


@given(case=broken_id_stores(), seed=st.integers(0, 2**16), data=st.data())
def test_a_broken_id_array_is_frames_or_one_line(folder, case, seed, data):
    shape, frames_, part, new = case
    store = folder / f"{VIDEO}.zarr"
    shutil.rmtree(folder / RLE_FOLDER, ignore_errors=True)  # the id array is read only when there is no RLE folder
    _write_ids(store, frames_, shape, seed)
    target = store / "zarr.json" if part == "metadata" else store / "c" / "0" / "0" / "0"
    if new is None:
        target.unlink()
    else:
        target.write_bytes(data.draw(broken_bytes(target.read_bytes())) if new == b"" else new)

    def read_every_frame() -> list[int]:
        source = PredictionSource(folder, VIDEO, [f"{i:010d}" for i in range(frames_)])
        return [source.frame(i, shape, 2).masks for i in range(frames_)]

    result_or_one_line_error(lambda: within(read_every_frame, SECONDS, MEGABYTES), PredictionError, str(store))
