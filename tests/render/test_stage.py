"""The render stage end to end on a tiny run: stores, tables, paired videos, bit-identical reruns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.io.zarr_video import open_video
from pipeline.render.stage import RenderInputError, read_poses
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.categories import STUFF_CATEGORIES
from tests.render.tiny_run import FRAMES, RoomRenderer, render_tiny_run, tiny_job
from tests.render.tiny_scenes import CATEGORIES

NAMES = ["room.0000000000.0000001000", "room.0000000000.0000000100"]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    return render_tiny_run(tmp_path_factory.mktemp("render") / "run")


def test_units_are_one_per_video_and_embodiment(rendered: RunFolder) -> None:
    ids = [unit.id for unit in RoomRenderer(rendered.job()).units(rendered)]
    assert ids == sorted(f"{body}.{name}" for body in ("ambient", "spot") for name in NAMES)


def test_stores_have_the_documented_layout(rendered: RunFolder) -> None:
    video = open_video(rendered.video_store("spot", NAMES[0]))
    assert video.rgb.shape == (FRAMES, 48, 64, 3) and video.rgb.dtype == np.uint8
    assert video.depth.shape == (FRAMES, 48, 64) and video.depth.dtype == np.uint16
    assert video.panoptic.dtype == np.uint32
    assert video.group["depth_clean"].dtype == np.uint16  # noisy sensor: the clean depth stays available
    assert video.rgb.chunks == (1, 48, 64, 3) and video.rgb.shards == (4, 48, 64, 3)
    attrs = video.attrs
    assert attrs["schema_version"] == 1 and attrs["illumination"] == "spot-20W"
    assert attrs["intrinsics"]["width"] == 64 and attrs["embodiment"]["name"] == "spot"
    row = next(r for r in rendered.read("trajectories").to_pylist() if (r["embodiment"], r["video_name"]) == ("spot", NAMES[0]))
    assert np.allclose(video.poses(), read_poses(rendered, row))
    assert "render_seconds" not in str(attrs)
    ambient = open_video(rendered.video_store("ambient", NAMES[0]))
    assert "depth_clean" not in ambient.group and ambient.attrs["exposure"] is None


def test_tables_agree_with_the_stored_pixels(rendered: RunFolder) -> None:
    videos = rendered.read("videos").to_pylist()
    assert len(videos) == 4 and {v["illumination"] for v in videos} == {"ambient", "spot-20W"}
    for row in videos:
        assert (rendered.root / row["store_path"]).is_dir() and row["bytes"] > 0 and row["frames"] == FRAMES
    segments = rendered.read("segments").to_pylist()
    stats = {(r["embodiment"], r["video_name"], r["frame"]): r for r in rendered.read("frame_stats").to_pylist()}
    assert len(stats) == 4 * FRAMES
    panoptic = open_video(rendered.video_store("ambient", NAMES[1])).panoptic[:]
    for t in range(FRAMES):
        rows = [r for r in segments if r["embodiment"] == "ambient" and r["video_name"] == NAMES[1] and r["frame"] == t]
        ids = [i for i in np.unique(panoptic[t]) if i]
        assert [r["object_id"] for r in rows] == ids
        for r in rows:
            mask = panoptic[t] == r["object_id"]
            assert r["area"] == mask.sum() and r["category"] == CATEGORIES.get(r["object_id"], 39)
        assert stats[("ambient", NAMES[1], t)]["visible_objects"] == len(ids)
        assert stats[("ambient", NAMES[1], t)]["void_fraction"] == pytest.approx((panoptic[t] == 0).mean())


def test_paired_videos_of_one_trajectory_see_the_same_objects(rendered: RunFolder) -> None:
    high, low = (set(np.unique(open_video(rendered.video_store("ambient", n)).panoptic[:]).tolist()) - {0}
                 for n in NAMES)
    things = {i for i in high | low if CATEGORIES.get(i, 39) not in STUFF_CATEGORIES}
    assert things and things <= high and things <= low  # every object is seen from both heights
    # Only stuff may differ (the ceiling leaves the view at 0.1 m).
    assert (high ^ low) <= {i for i in high | low if CATEGORIES.get(i, 39) in STUFF_CATEGORIES}


def test_two_runs_of_one_job_give_bit_identical_stores(rendered: RunFolder, tmp_path: Path) -> None:
    again = render_tiny_run(tmp_path / "again")
    for body in ("ambient", "spot"):
        for name in NAMES:
            first, second = rendered.video_store(body, name), again.video_store(body, name)
            files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file())
            assert files == sorted(p.relative_to(second) for p in second.rglob("*") if p.is_file())
            assert all((first / f).read_bytes() == (second / f).read_bytes() for f in files)
    # A different seed changes the sensor noise (and only that): the noisy depth differs.
    other = render_tiny_run(tmp_path / "other", seed=1)
    first, second = (open_video(r.video_store("spot", NAMES[0])) for r in (rendered, other))
    assert np.array_equal(first.rgb[:], second.rgb[:]) and np.array_equal(first.panoptic[:], second.panoptic[:])
    assert not np.array_equal(first.depth[:], second.depth[:])


def test_missing_frames_are_reported_with_the_fix(tmp_path: Path) -> None:
    run = RunFolder.create(tmp_path / "run", tiny_job())
    with pytest.raises(RenderInputError, match="run `mvpd rerun RUN --stage plan"):
        read_poses(run, {"scene_id": "s", "embodiment": "ambient", "video_name": NAMES[0], "frames": FRAMES})
