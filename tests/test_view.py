"""`mvpd view`: a Rerun recording of a demo-shaped video, read back with the Rerun SDK."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from tests.demo_run import DEMO_VIDEO, demo_shaped_run

rr = pytest.importorskip("rerun")  # in the `test` extra, so CI has it; skipped only in a bare install


@pytest.fixture(scope="module")
def run(ray_session, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return demo_shaped_run(tmp_path_factory)


def _chunks(path: Path) -> dict[str, dict]:
    """Per entity path: rows on the `frame` timeline, static rows, and component names."""
    entities: dict[str, dict] = defaultdict(lambda: {"frames": set(), "static": 0, "components": set()})
    for chunk in rr.chunk.RrdReader(path).stream():
        entry = entities[chunk.entity_path]
        batch = chunk.to_record_batch()
        entry["components"].update(batch.schema.names)
        if chunk.is_static:
            entry["static"] += chunk.num_rows
        elif "frame" in batch.schema.names:
            entry["frames"].update(batch.column("frame").to_pylist())
    return entities


def test_view_writes_a_recording_with_the_scene_path_frames_and_named_masks(run: Path, tmp_path: Path) -> None:
    from pipeline.io.reader import load_video

    out = tmp_path / "video.rrd"
    result = CliRunner().invoke(app, ["view", str(run), DEMO_VIDEO, "--embodiment", "ambient", "--out", str(out)])
    assert result.exit_code == 0, result.output
    video = load_video(run, DEMO_VIDEO, "ambient")
    entities = _chunks(out)
    frames = set(range(video.frames))
    for entity in ("/world/camera", "/world/camera/image/rgb", "/world/camera/image/depth",
                   "/world/camera/image/panoptic", "/world/points"):
        assert entities[entity]["frames"] == frames, entity
    assert entities["/world/scene"]["static"] == 1 and "Mesh3D:vertex_colors" in entities["/world/scene"]["components"]
    assert entities["/world/trajectory"]["static"] == 1
    assert "AnnotationContext:context" in entities["/world/camera/image"]["components"]
    assert "Pinhole:image_from_camera" in entities["/world/camera/image"]["components"]
    assert not list(tmp_path.glob(".*.tmp"))  # written beside, then renamed


def test_view_masks_use_the_videos_object_names(run: Path) -> None:
    from pipeline.io.reader import load_video
    from pipeline.rerun_recording import _class_table, class_ids

    video = load_video(run, DEMO_VIDEO, "ambient")
    ids, classes = _class_table(video)
    panoptic = np.asarray(video.panoptic[0])
    dense = class_ids(panoptic, ids)
    seen = panoptic[panoptic > 0]
    assert seen.size and np.array_equal(ids[dense[panoptic > 0].astype(int) - 1], seen)  # class k is the k-th object
    label = dict((k, name) for k, name, _ in classes)[int(dense[panoptic > 0][0])]
    assert label.endswith(f"#{int(seen[0])}") and video.raw_names[int(seen[0])] in label


def test_view_looks_names_up_and_never_joins_them_into_paths(run: Path, tmp_path: Path) -> None:
    for name in ("../../etc", f"../demo/videos/ambient/{DEMO_VIDEO}", "nope"):
        result = CliRunner().invoke(app, ["view", str(run), name, "--out", str(tmp_path / "x.rrd")])
        assert result.exit_code == 2 and "no rendered video" in result.output, result.output
    both = CliRunner().invoke(app, ["view", str(run), DEMO_VIDEO, "--out", str(tmp_path / "x.rrd")])
    assert both.exit_code == 2 and "ambient, spot20w" in both.output
    assert not (tmp_path / "x.rrd").exists()
