"""Reading API: lazy videos with metadata, frame and clip iterators, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

import pipeline
from pipeline.io import reader
from pipeline.io.reader import VideoNotFoundError, clip_index, iter_clips, iter_frames, list_videos, load_video
from pipeline.store.run_folder import RunFolder
from tests.render.tiny_run import FRAMES, render_tiny_run

HIGH = "room.0000000000.0000001000"


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    return render_tiny_run(tmp_path_factory.mktemp("reader") / "run")


def test_load_video_is_lazy_and_carries_metadata(run: RunFolder) -> None:
    video = pipeline.load_video(run.root, HIGH, embodiment="spot")
    assert video.frames == FRAMES and video.rgb.shape == (FRAMES, 48, 64, 3)
    assert video.depth_clean is not None and video.poses.shape == (FRAMES, 4, 4)
    assert video.intrinsics["width"] == 64
    frame = video.frame(2)
    assert frame["rgb"].shape == (48, 64, 3) and frame["poses"].shape == (4, 4) and frame["frame"] == 2
    ids = set(np.unique(video.panoptic[:]).tolist()) - {0}
    assert set(video.categories) == ids and video.categories[21] == 5  # the table is a 'table' (mpcat40 5)


def test_ambiguous_or_unknown_names_say_what_exists(run: RunFolder) -> None:
    with pytest.raises(VideoNotFoundError, match="embodiments ambient, spot"):
        load_video(run, HIGH)
    with pytest.raises(VideoNotFoundError, match="no rendered video named 'nope'"):
        load_video(run, "nope")


def test_clips_cover_every_video_without_crossing_them(run: RunFolder) -> None:
    assert len(list_videos(run)) == 4
    index = clip_index(run, clip_len=4, stride=2)
    assert len(index) == 4 * 2  # starts 0 and 2 in each 6-frame video (4 would run past the end)
    clips = list(iter_clips(run, clip_len=4, stride=2))
    first = clips[0]
    assert first["rgb"].shape == (4, 48, 64, 3) and first["panoptic"].dtype == np.uint32
    stored = load_video(run, first["video_name"], first["embodiment"])
    assert np.array_equal(first["depth"], stored.depth[0:4]) and np.allclose(first["poses"], stored.poses[0:4])


def test_iter_frames_yields_every_frame_once(run: RunFolder) -> None:
    frames = list(iter_frames(run, arrays=("panoptic",)))
    assert len(frames) == 4 * FRAMES
    assert frames[0]["panoptic"].shape == (48, 64) and "rgb" not in frames[0]
    assert [f["frame"] for f in frames[:FRAMES]] == list(range(FRAMES))


def test_torch_adapter_only_with_torch() -> None:
    try:
        import torch  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="needs torch"):
            reader.TorchVideoDataset  # noqa: B018
    else:
        assert reader.TorchVideoDataset is not None


def test_torch_dataset_gives_the_clips_as_tensors(run: RunFolder) -> None:
    torch = pytest.importorskip("torch")
    dataset = reader.TorchVideoDataset(run.root, clip_len=4, stride=2)
    assert len(dataset) == len(clip_index(run, clip_len=4, stride=2)) == 8
    item, clip = dataset[0], next(iter_clips(run, clip_len=4, stride=2))
    assert item["rgb"].shape == (4, 3, 48, 64) and item["rgb"].dtype == torch.uint8
    assert np.array_equal(item["rgb"].permute(0, 2, 3, 1).numpy(), clip["rgb"])
    assert item["depth"].dtype == torch.int32 and np.array_equal(item["depth"].numpy(), clip["depth"])
    assert item["panoptic"].dtype == torch.int64 and np.array_equal(item["panoptic"].numpy(), clip["panoptic"])
    batch = next(iter(torch.utils.data.DataLoader(dataset, batch_size=2)))
    assert batch["panoptic"].shape == (2, 4, 48, 64) and len(batch["video_name"]) == 2
