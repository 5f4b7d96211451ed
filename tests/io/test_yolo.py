"""YOLO segmentation export: layout, data.yaml, polygons that rasterise back to the run's masks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from pipeline.io.reader import list_videos, load_video
from pipeline.io.training_export import ExportOptions, TrainingExportError, export_training_data, unsplit
from pipeline.io.yolo import mask_polygon, polygon_line, yolo_names, YoloExporter
from pipeline.store.run_folder import RunFolder
from tests.render.tiny_run import FRAMES, render_tiny_run


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    return render_tiny_run(tmp_path_factory.mktemp("yolo") / "run")


def rasterise(line: str, width: int, height: int) -> tuple[int, np.ndarray]:
    """A label line filled as ultralytics fills it (denormalise, round, cv2.fillPoly)."""
    values = line.split()
    points = np.array(values[1:], dtype=np.float64).reshape(-1, 2) * [width, height]
    mask = np.zeros((height, width), np.uint8)
    cv2.fillPoly(mask, [np.round(points).astype(np.int32)], 1)
    return int(values[0]), mask.astype(bool)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_polygons_rasterise_back_to_the_runs_masks(tiny_run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "yolo"
    videos = list_videos(tiny_run)
    splits = {"train": videos[:3], "test": videos[3:]}
    export_training_data(tiny_run, out, splits, YoloExporter, ExportOptions(categories="mpcat40"))
    checked = 0
    for split, keys in splits.items():
        for embodiment, name in keys:
            video = load_video(tiny_run, name, embodiment)
            for t in range(FRAMES):
                stem = f"{embodiment}.{name}.{t:010d}"
                assert (out / "images" / split / f"{stem}.jpg").is_file()
                lines = (out / "labels" / split / f"{stem}.txt").read_text().splitlines()
                panoptic = np.asarray(video.panoptic[t])
                present = sorted(set(np.unique(panoptic).tolist()) - {0})
                # Objects seen as a pixel or a one-pixel line trace fewer than 3 vertices: no label line.
                objects = [o for o in present if mask_polygon(panoptic == o) is not None]
                assert all((panoptic == o).sum() < 64 for o in set(present) - set(objects))
                assert len(lines) == len(objects)  # one line per object, in id order, whatever its pieces
                for object_id, line in zip(objects, lines):
                    class_index, drawn = rasterise(line, 64, 48)
                    assert class_index == video.categories[object_id] - 1
                    expected = panoptic == object_id
                    if expected.mean() > 0.01:
                        assert iou(drawn, expected) >= 0.9, (stem, object_id, iou(drawn, expected))
                        checked += 1
    assert checked > 4 * FRAMES * 3


def test_data_yaml_names_the_splits_and_classes(tiny_run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "yolo"
    videos = list_videos(tiny_run)
    export_training_data(tiny_run, out, {"train": videos[:2], "val": videos[2:]}, YoloExporter,
                         ExportOptions(every=5))
    data = yaml.safe_load((out / "data.yaml").read_text())
    assert data == {"path": str(out.resolve()), "train": "images/train", "val": "images/val", "names": {0: "object"}}
    assert len(list((out / "labels" / "val").iterdir())) == 2 * 2  # frames 0 and 5 of two videos
    assert {line.split()[0] for p in (out / "labels").rglob("*.txt") for line in p.read_text().splitlines()} == {"0"}


def test_without_split_train_and_val_are_the_one_folder(tiny_run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "yolo"
    export_training_data(tiny_run, out, unsplit(tiny_run), YoloExporter,
                         ExportOptions(every=6, embodiment="ambient", drop_stuff=True))
    text = (out / "data.yaml").read_text()
    data = yaml.safe_load(text)
    assert (data["train"], data["val"], "test" in data) == ("images/all", "images/all", False)
    assert "no split" in text and "stuff dropped" in text
    assert sorted(p.name for p in (out / "labels" / "all").iterdir()) == [
        "ambient.room.0000000000.0000000100.0000000000.txt", "ambient.room.0000000000.0000001000.0000000000.txt"]


def test_pieces_and_holes_make_one_polygon() -> None:
    mask = np.zeros((48, 64), bool)
    mask[5:30, 5:60] = True
    mask[10:20, 20:30] = False  # a hole (an object in front of a wall)
    mask[36:44, 10:30] = True  # a second piece
    polygon = mask_polygon(mask)
    assert polygon is not None
    _, drawn = rasterise(polygon_line(0, polygon, 64, 48), 64, 48)
    assert not drawn[12:18, 22:28].any()  # the hole stays empty
    assert (drawn & ~mask).sum() <= 6 and (mask & ~drawn).sum() == 0  # only the one-pixel bridge is extra
    assert mask_polygon(np.zeros((4, 4), bool)) is None
    single = np.zeros((4, 4), bool)
    single[1, 1] = True
    assert mask_polygon(single) is None  # one vertex: no polygon to write


def test_mpcat40_names_are_zero_based() -> None:
    names = yolo_names("mpcat40")
    assert (names[0], names[4], names[39], len(names)) == ("wall", "table", "misc", 41)


def test_an_existing_export_needs_overwrite_and_overwrite_replaces_it(tiny_run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "yolo"
    options = ExportOptions(every=6, embodiment="spot")
    export_training_data(tiny_run, out, unsplit(tiny_run), YoloExporter, options)
    (out / "labels" / "all" / "stale.txt").write_text("0 0 0 1 0 1 1\n")
    with pytest.raises(TrainingExportError, match="--overwrite"):
        export_training_data(tiny_run, out, unsplit(tiny_run), YoloExporter, options)
    overwrite = ExportOptions(every=6, embodiment="spot", overwrite=True)
    export_training_data(tiny_run, out, unsplit(tiny_run), YoloExporter, overwrite)
    assert not (out / "labels" / "all" / "stale.txt").exists()  # the old export went, not mixed in


def test_a_split_naming_a_video_the_run_lacks_is_refused(tiny_run: RunFolder, tmp_path: Path) -> None:
    with pytest.raises(TrainingExportError, match="'room.9'.*rerun the split stage"):
        export_training_data(tiny_run, tmp_path / "yolo", {"train": [("spot", "room.9")]}, YoloExporter,
                             ExportOptions())
    assert not (tmp_path / "yolo").exists()


def test_cli_writes_the_yolo_layout(tiny_run: RunFolder, tmp_path: Path) -> None:
    import typer
    from typer.testing import CliRunner

    from pipeline.cli import mvpd_io

    app = typer.Typer()
    mvpd_io.register(app)
    out = tmp_path / "yolo"
    result = CliRunner().invoke(app, ["export", str(tiny_run.root), "--yolo", str(out), "--every", "6",
                                      "--categories", "mpcat40"])
    assert result.exit_code == 0, result.output
    assert "4 frames (all 4)" in result.output  # 4 videos, frame 0 of each
    assert sorted(p.name for p in out.iterdir()) == [".mvpd-out", "data.yaml", "images", "labels"]  # tag: export wrote it
    assert len(yaml.safe_load((out / "data.yaml").read_text())["names"]) == 41
