"""Zarr video store: layout (one frame per chunk, shards, zstd), round trip, refusals."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.io.zarr_video import VideoWriteError, VideoWriter, open_video


def _frames(count: int, seed: int = 0) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [{"rgb": rng.integers(0, 256, (6, 8, 3), dtype=np.uint8),
             "depth": rng.integers(0, 65536, (6, 8), dtype=np.uint16),
             "panoptic": rng.integers(0, 2**32, (6, 8), dtype=np.uint32)} for _ in range(count)]


def _write(path: Path, frames: list[dict[str, np.ndarray]], shard: int = 4, background: bool = False) -> None:
    poses = np.tile(np.eye(4), (len(frames), 1, 1)).tolist()
    writer = VideoWriter(path, len(frames), 8, 6, {"video_name": "v", "poses": poses,
                                                  "intrinsics": {"fx": 1.0, "fy": 1.0, "cx": 4.0, "cy": 3.0}},
                         frames_per_shard=shard, background=background)
    for frame in frames:
        writer.append(**frame)
    assert writer.close() == len(frames)


@pytest.mark.parametrize("count", [3, 4, 10])  # fewer than a shard, exactly one, a partial last shard
def test_round_trip_and_layout(tmp_path: Path, count: int) -> None:
    frames = _frames(count)
    _write(tmp_path / "v.zarr", frames)
    video = open_video(tmp_path / "v.zarr")
    assert video.frames == count
    for name in ("rgb", "depth", "panoptic"):
        assert np.array_equal(getattr(video, name)[:], np.stack([f[name] for f in frames]))
    assert video.rgb.chunks == (1, 6, 8, 3) and video.depth.shards == (4, 6, 8)
    metadata = json.loads((tmp_path / "v.zarr" / "depth" / "zarr.json").read_text())
    codecs = metadata["codecs"][0]["configuration"]["codecs"]  # inside the sharding codec
    assert [c["name"] for c in codecs] == ["bytes", "zstd"]
    assert video.attrs["schema_version"] == 1 and video.poses().shape == (count, 4, 4)
    # One file per shard on disk: ceil(count / 4) shard files per array.
    shard_files = [p for p in (tmp_path / "v.zarr" / "rgb" / "c").rglob("*") if p.is_file()]
    assert len(shard_files) == -(-count // 4)


@pytest.mark.parametrize("background", [False, True])
def test_same_frames_give_identical_bytes(tmp_path: Path, background: bool) -> None:
    # Shards written on the writer's thread while frames arrive are the bytes of shards written inline.
    _write(tmp_path / "a.zarr", _frames(11))
    _write(tmp_path / "b.zarr", _frames(11), background=background)
    files = sorted(p.relative_to(tmp_path / "a.zarr") for p in (tmp_path / "a.zarr").rglob("*") if p.is_file())
    assert files and all((tmp_path / "a.zarr" / f).read_bytes() == (tmp_path / "b.zarr" / f).read_bytes() for f in files)


def test_a_failed_video_leaves_no_shard_write_running(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real_write = VideoWriter._write

    def slow_write(self, start, blocks):  # a shard that takes a while to encode
        time.sleep(0.3)
        real_write(self, start, blocks)

    monkeypatch.setattr(VideoWriter, "_write", slow_write)
    frames = _frames(5)
    with pytest.raises(RuntimeError, match="rendering failed"):
        with VideoWriter(tmp_path / "v.zarr", 8, 8, 6, {}, frames_per_shard=4, background=True) as writer:
            for frame in frames:
                writer.append(**frame)  # the fourth frame starts the first shard's write on the writer's thread
            raise RuntimeError("rendering failed")
    # Left: the first shard whole, written before the block ended (its staging folder is removed next).
    assert np.array_equal(open_video(tmp_path / "v.zarr").rgb[:4], np.stack([f["rgb"] for f in frames[:4]]))


def test_wrong_dtype_or_shape_or_count_is_refused(tmp_path: Path) -> None:
    writer = VideoWriter(tmp_path / "v.zarr", 2, 8, 6, {})
    frame = _frames(1)[0]
    with pytest.raises(VideoWriteError, match="depth frame is float64"):
        writer.append(**{**frame, "depth": frame["depth"].astype(np.float64)})
    with pytest.raises(VideoWriteError, match=r"rgb frame is uint8\[6, 7, 3\]"):
        writer.append(**{**frame, "rgb": frame["rgb"][:, :7]})
    writer.append(**frame)
    with pytest.raises(VideoWriteError, match="1 of 2 frames written"):
        writer.close()
    writer.append(**frame)
    with pytest.raises(VideoWriteError, match="more than the 2 frames"):
        writer.append(**frame)


def test_open_video_names_a_missing_store(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="not a Zarr video store"):
        open_video(tmp_path / "missing.zarr")


def test_whole_shards_are_written_byte_for_byte_as_zarr_writes_them(tmp_path: Path) -> None:
    """The writer encodes whole shards itself (zarr's codec pipeline costs more than zstd): every file of
    the store must equal what Zarr writes through `array[...] = block`, all-zero frames and a partial last
    shard included, and read back the same."""
    frames = _frames(10, seed=3)
    frames[1] = {name: np.zeros_like(value) for name, value in frames[1].items()}  # an all-zero chunk is stored too
    _write(tmp_path / "ours.zarr", frames)
    writer = VideoWriter(tmp_path / "zarr.zarr", 10, 8, 6, {"video_name": "v", "poses": np.tile(np.eye(4), (10, 1, 1)).tolist(),
                                                          "intrinsics": {"fx": 1.0, "fy": 1.0, "cx": 4.0, "cy": 3.0}},
                         frames_per_shard=4)
    for name, array in writer.arrays.items():
        array[:] = np.stack([frame[name] for frame in frames])  # Zarr's own sharding codec
    ours = sorted(p.relative_to(tmp_path / "ours.zarr") for p in (tmp_path / "ours.zarr").rglob("*") if p.is_file())
    theirs = sorted(p.relative_to(tmp_path / "zarr.zarr") for p in (tmp_path / "zarr.zarr").rglob("*") if p.is_file())
    assert ours == theirs and len(ours) == 1 + 3 * (1 + 3)  # the group's zarr.json; per array its own and 3 shards
    for relative in ours:
        assert (tmp_path / "ours.zarr" / relative).read_bytes() == (tmp_path / "zarr.zarr" / relative).read_bytes(), relative
    video = open_video(tmp_path / "ours.zarr")
    assert np.array_equal(video.rgb[:], np.stack([f["rgb"] for f in frames]))
