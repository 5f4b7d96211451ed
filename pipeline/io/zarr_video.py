"""One video as a Zarr v3 store: `rgb`, `depth`, `panoptic` (+ `depth_clean` with a noisy sensor).

Layout (schemas/zarr_video.md): one frame per chunk, shards of `frames_per_shard` frames, zstd.
Attributes: schema_version, video_name, scene_id, embodiment (resolved), height_m, intrinsics
{fx, fy, cx, cy, width, height}, poses (T x 4 x 4 camera-to-world, OpenCV camera axes), and anything
else the writer passes. Stores are written in a staging folder and committed whole by the runtime.
"""

from __future__ import annotations

import functools
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.lazy_import import lazy_module
from pipeline.store.remote import remote_url

zarr = lazy_module("zarr")  # loaded on first use: commands that never open a video start faster
google_crc32c = lazy_module("google_crc32c")  # Zarr's checksum of a shard's index (a dependency of zarr)
zstd_codec = lazy_module("numcodecs.zstd")  # the compressor of Zarr's ZstdCodec, for `_write_whole_shard`

ZARR_SCHEMA_VERSION = 1
ARRAYS: dict[str, tuple[str, int]] = {
    # name: (dtype, channels; 0 = none)
    "rgb": ("uint8", 3),
    "depth": ("uint16", 0),
    "depth_clean": ("uint16", 0),
    "panoptic": ("uint32", 0),
}


class VideoWriteError(ValueError):
    """A frame that does not fit the store (shape, dtype, count); the message names the array and the fix."""


class VideoWriter:
    """Creates a video store and appends frames in blocks of whole shards.

    Frames are buffered up to one shard and written shard by shard, so every shard is encoded once
    (a partial shard write would re-read and re-encode it). With `background`, a full shard is encoded
    and written on a thread of its own while the caller renders the next frames (one shard at a time, in
    order: the same bytes as inline); for a renderer with several threads, whose single-threaded steps
    leave a core idle, not for a 1-CPU worker, which must not use a second core. `close` waits for the
    writes, raises what failed, and refuses a store with missing frames.
    """

    def __init__(self, path: Path, frames: int, width: int, height: int, attributes: dict[str, Any],
                 arrays: tuple[str, ...] = ("rgb", "depth", "panoptic"), frames_per_shard: int = 16, level: int = 3,
                 background: bool = False):
        self.group = zarr.open_group(str(path), mode="w", zarr_format=3)
        self.group.attrs.update({"schema_version": ZARR_SCHEMA_VERSION, **attributes})
        self.shard = frames_per_shard
        self.arrays = {}
        for name in arrays:
            dtype, channels = ARRAYS[name]
            tail = (height, width, channels) if channels else (height, width)
            self.arrays[name] = self.group.create_array(
                name, shape=(frames, *tail), chunks=(1, *tail), shards=(frames_per_shard, *tail),
                dtype=dtype, compressors=zarr.codecs.ZstdCodec(level=level), fill_value=0,
                # Store all-zero chunks too: zarr's default compares every chunk with the fill value before
                # writing it (a full extra pass, ~3 ms per 640x480 frame); readers see the same zeros.
                config={"write_empty_chunks": True},
            )
        self._zstd = zstd_codec.Zstd(level=level, checksum=False)  # what ZstdCodec(level) encodes each chunk with
        self._buffer: dict[str, list[np.ndarray]] = {name: [] for name in arrays}
        self._written = 0
        self._background = background
        self._writing: Future | None = None  # the shard being written in the background
        self.frames = frames
        self.path = Path(path)

    def append(self, **frame: np.ndarray) -> None:
        """Add one frame: one keyword per array (rgb=..., depth=..., panoptic=...), exact shape and dtype.

        The arrays are kept, not copied, until their shard is written (after `close` at the latest): do not
        modify them once appended."""
        if set(frame) != set(self.arrays):
            raise VideoWriteError(f"{self.path}: append got arrays {sorted(frame)}, the store has {sorted(self.arrays)}")
        buffered = len(self._buffer[next(iter(self.arrays))])
        if self._written + buffered >= self.frames:
            raise VideoWriteError(f"{self.path}: more than the {self.frames} frames the store was created for")
        for name, array in self.arrays.items():
            value = frame[name]
            # No silent casts: a float depth or an int64 id image would be truncated without a word.
            if value.shape != array.shape[1:] or value.dtype != array.dtype:
                raise VideoWriteError(f"{self.path}: {name} frame is {value.dtype}{list(value.shape)}, the store "
                                      f"holds {array.dtype}{list(array.shape[1:])}; convert it before appending")
        for name in self.arrays:
            self._buffer[name].append(frame[name])
        if len(self._buffer[next(iter(self.arrays))]) == self.shard:
            self._flush()

    def _flush(self) -> None:
        """Write the buffered frames (in the background: after the shard before them is written)."""
        count = len(self._buffer[next(iter(self.arrays))])
        if count == 0:
            return
        # A whole shard is encoded frame by frame (`_write_whole_shard`): no copy of its frames into one block.
        whole = count == self.shard and self._written % self.shard == 0 and remote_url(str(self.path)) is None
        blocks = {name: list(self._buffer[name]) if whole else np.stack(self._buffer[name]) for name in self.arrays}
        for frames in self._buffer.values():
            frames.clear()
        self._wait()
        if self._background:
            self._writing = _shard_writer().submit(self._write, self._written, blocks)
        else:
            self._write(self._written, blocks)
        self._written += count

    def _write(self, start: int, blocks: dict[str, np.ndarray | list[np.ndarray]]) -> None:
        for name, block in blocks.items():
            if isinstance(block, list):
                _write_whole_shard(self.path / name, start // self.shard, block, self._zstd)
            else:  # the last, partial shard of a video: Zarr leaves its missing chunks out of the index
                self.arrays[name][start:start + len(block)] = block

    def _wait(self) -> None:
        """Wait for the shard being written; raise what its write raised."""
        if self._writing is not None:
            writing, self._writing = self._writing, None
            writing.result()

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, *failure: object) -> None:
        """Let no shard write run on past the block: when rendering failed, the attempt's staging folder is
        removed next (and a retry in this process would write into the same folder)."""
        if self._writing is not None:
            wait([self._writing])  # the block's own error is the one to raise
            self._writing = None

    def close(self) -> int:
        """Write what is buffered; returns the number of frames written (all of them, or it raises)."""
        self._flush()
        self._wait()
        if self._written != self.frames:
            raise VideoWriteError(f"{self.path}: {self._written} of {self.frames} frames written; "
                                  "the video is incomplete (render every pose before closing)")
        return self._written


def _write_whole_shard(array_folder: Path, index: int, frames: list[np.ndarray], zstd: Any) -> None:
    """Write shard `index` of an array (every one of its chunks: one frame each) as Zarr's sharding codec
    writes it for this layout, byte for byte: the chunks zstd-compressed one after the other in frame order
    (the Morton order of a (frames, 1, 1) grid), then the index (offset, length per chunk, little-endian
    uint64) and the index's CRC32C (little-endian uint32).

    Why not `array[...] = block`: Zarr's asynchronous codec pipeline costs more than the compression itself
    (~4.6 ms per 640x480 frame of rgb + depth + panoptic, zstd alone ~2 ms; benchmarks/bench_render.py).
    tests/io/test_zarr_video.py checks that the files equal Zarr's own."""
    chunks = [zstd.encode(np.ascontiguousarray(frame)) for frame in frames]
    lengths = np.array([len(chunk) for chunk in chunks], np.uint64)
    offsets = np.concatenate([np.zeros(1, np.uint64), np.cumsum(lengths, dtype=np.uint64)[:-1]])
    table = np.stack([offsets, lengths], axis=-1).astype("<u8").tobytes()
    checksum = np.array([google_crc32c.value(table)], "<u4").tobytes()
    path = array_folder.joinpath("c", str(index), *["0"] * frames[0].ndim)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as out:
        out.writelines([*chunks, table, checksum])


@functools.cache
def _shard_writer() -> ThreadPoolExecutor:
    """The process's one thread that encodes and writes shards behind the render loop."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="zarr-shards")


@dataclass
class Video:
    """A stored video opened lazily: arrays are Zarr arrays (index them to read)."""

    path: Path | str  # a local path, or a URL on an object store
    group: zarr.Group

    @property
    def attrs(self) -> dict[str, Any]:
        return dict(self.group.attrs)

    @property
    def rgb(self) -> zarr.Array:
        return self.group["rgb"]  # type: ignore[return-value]

    @property
    def depth(self) -> zarr.Array:
        return self.group["depth"]  # type: ignore[return-value]

    @property
    def panoptic(self) -> zarr.Array:
        return self.group["panoptic"]  # type: ignore[return-value]

    @property
    def frames(self) -> int:
        return int(self.group["panoptic"].shape[0])

    def poses(self) -> np.ndarray:
        """(T, 4, 4) float64 camera-to-world matrices (OpenCV camera axes)."""
        return np.asarray(self.group.attrs["poses"], dtype=np.float64)

    def intrinsics(self) -> dict[str, float]:
        return dict(self.group.attrs["intrinsics"])


def open_video(location: str | Path) -> Video:
    """Open a stored video read-only: a local path, or the URL of a store on an object store (read in place
    through fsspec; what `RunFolder.committed_location` gives for a remote run)."""
    if remote_url(location) is None:
        path = Path(location)
        if not (path / "zarr.json").is_file():
            raise FileNotFoundError(f"{path}: not a Zarr video store (no zarr.json); was the render unit committed?")
        return Video(path, zarr.open_group(str(path), mode="r"))
    try:
        return Video(str(location), zarr.open_group(_read_only_store(str(location)), mode="r"))
    except (FileNotFoundError, zarr.errors.GroupNotFoundError):
        raise FileNotFoundError(f"{location}: not a Zarr video store (no zarr.json); was the render unit committed?") from None


def _read_only_store(url: str) -> "zarr.storage.FsspecStore":
    """A read-only Zarr store on an object-store URL, through the process's own (cached, synchronous) fsspec
    client in a thread wrapper: zarr's `from_url` would open a second client on its own event loop, whose
    HTTP session is never closed (aiohttp warns "Unclosed client session" when it is collected)."""
    import fsspec
    from fsspec.implementations.asyn_wrapper import AsyncFileSystemWrapper

    fs, path = fsspec.core.url_to_fs(url)
    return zarr.storage.FsspecStore(AsyncFileSystemWrapper(fs, asynchronous=True), path=path, read_only=True)
