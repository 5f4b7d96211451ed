"""COCO training export: loads with pycocotools, decodes to the run's panoptic masks exactly, bad input."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import typer
from PIL import Image
from pycocotools.coco import COCO
from typer.testing import CliRunner

from pipeline.cli import mvpd_io
from pipeline.io.coco import CocoExporter, annotation_file
from pipeline.io.reader import list_videos, load_video
from pipeline.io.training_export import (
    ExportOptions,
    TrainingExportError,
    export_training_data,
    frame_objects,
    run_splits,
    unsplit,
)
from pipeline.store.run_folder import RunFolder
from tests.render.tiny_run import FRAMES, render_tiny_run
from tests.render.tiny_scenes import CHAIR, FLOOR, TABLE, WALL


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    """The rendered room: embodiments `ambient` and `spot`, heights 1.0 m and 0.1 m, 6 frames of 64 x 48."""
    return render_tiny_run(tmp_path_factory.mktemp("coco") / "run")


def cli(*arguments: str) -> object:
    app = typer.Typer()
    mvpd_io.register(app)
    return CliRunner().invoke(app, ["export", *arguments])


@pytest.fixture(scope="module")
def exported(tiny_run: RunFolder, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Split `train` = the ambient videos, `val` = one spot video; mpcat40 categories; every 2nd frame."""
    videos = list_videos(tiny_run)
    splits = {"train": [v for v in videos if v[0] == "ambient"], "val": [("spot", "room.0000000000.0000001000")]}
    out = tmp_path_factory.mktemp("out") / "coco"
    summary = export_training_data(tiny_run, out, splits, CocoExporter,
                                   ExportOptions(every=2, categories="mpcat40"))
    assert summary.frames == {"train": 2 * 3, "val": 3}  # frames 0, 2, 4 of 6 per video
    return out


def test_export_loads_with_pycocotools_and_names_its_images(exported: Path) -> None:
    coco = COCO(str(annotation_file(exported, "train")))
    images = coco.loadImgs(coco.getImgIds())
    assert [(i["video_name"], i["frame"]) for i in images] == [
        (f"room.0000000000.{height:010d}", t) for height in (100, 1000) for t in (0, 2, 4)]
    assert images[0]["file_name"] == "ambient.room.0000000000.0000000100.0000000000.jpg"
    for image in images:
        picture = Image.open(exported / "images" / "train" / image["file_name"])
        assert (picture.format, picture.size) == ("JPEG", (image["width"], image["height"])) == ("JPEG", (64, 48))
    assert {c["id"]: c["name"] for c in coco.loadCats(coco.getCatIds())}[5] == "table"
    assert len(coco.getCatIds()) == 41  # mpcat40 1..40 and 41 `unlabeled`, as the MVPd release lists them


def test_masks_decode_to_the_runs_panoptic_masks_exactly(exported: Path, tiny_run: RunFolder) -> None:
    coco = COCO(str(annotation_file(exported, "train")))
    checked = 0
    for image in coco.loadImgs(coco.getImgIds()):
        video = load_video(tiny_run, image["video_name"], image["embodiment"])
        panoptic = np.asarray(video.panoptic[image["frame"]])
        annotations = coco.loadAnns(coco.getAnnIds(imgIds=image["id"]))
        # Every object of the frame (the room's categories are all mapped, none void) is one annotation.
        assert sorted(a["object_id"] for a in annotations) == sorted(set(np.unique(panoptic).tolist()) - {0})
        for annotation in annotations:
            expected = panoptic == annotation["object_id"]
            np.testing.assert_array_equal(coco.annToMask(annotation).astype(bool), expected)
            assert annotation["area"] == int(expected.sum()) and annotation["iscrowd"] == 0
            assert annotation["category_id"] == video.categories[annotation["object_id"]]
            assert annotation["isthing"] == (0 if annotation["category_id"] in (1, 2, 17) else 1)
            x, y, w, h = annotation["bbox"]
            rows, columns = np.nonzero(expected)
            assert (x, y, x + w, y + h) == (columns.min(), rows.min(), columns.max() + 1, rows.max() + 1)
            checked += 1
    assert checked > 6 * 4  # several objects per frame, not a vacuous loop


def test_each_split_has_its_own_file_and_images(exported: Path) -> None:
    annotation_files = sorted(p.name for p in (exported / "annotations").iterdir())
    assert annotation_files == ["instances_train.json", "instances_val.json"]
    val = json.loads(annotation_file(exported, "val").read_text())
    assert {(i["embodiment"], i["frame"]) for i in val["images"]} == {("spot", 0), ("spot", 2), ("spot", 4)}
    assert len(list((exported / "images" / "val").iterdir())) == 3
    assert [a["id"] for a in val["annotations"]] == list(range(1, len(val["annotations"]) + 1))


def test_class_agnostic_export_drops_stuff_on_request_and_is_deterministic(tiny_run: RunFolder,
                                                                            tmp_path: Path) -> None:
    splits = unsplit(tiny_run)
    options = ExportOptions(embodiment="ambient", drop_stuff=True)
    first, second = tmp_path / "a", tmp_path / "b"
    for out in (first, second):
        export_training_data(tiny_run, out, splits, CocoExporter, options)
    data = json.loads(annotation_file(first, "all").read_text())
    assert data["categories"] == [{"id": 1, "name": "object", "supercategory": "object", "isthing": 1}]
    assert len(data["images"]) == 2 * FRAMES and {i["embodiment"] for i in data["images"]} == {"ambient"}
    assert {a["category_id"] for a in data["annotations"]} == {1}
    objects = {a["object_id"] for a in data["annotations"]}
    assert WALL not in objects and FLOOR not in objects and {TABLE, CHAIR} <= objects
    files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file())
    assert [p.name for p in files if p.name.startswith(".")] == []  # no temporary part left behind
    assert all((first / f).read_bytes() == (second / f).read_bytes() for f in files)


def test_void_and_unmapped_objects_are_not_annotated() -> None:
    panoptic = np.array([[0, 5, 5], [7, 7, 9]], dtype=np.uint32)
    video = SimpleNamespace(categories={5: 3, 7: 0, 9: 1}, path=Path("v.zarr"))  # 7: unmapped, 9: wall
    kept = frame_objects(panoptic, video, drop_stuff=False)  # type: ignore[arg-type]
    assert [(o.object_id, o.category, o.is_stuff, int(o.mask.sum())) for o in kept] == [
        (5, 3, False, 2), (9, 1, True, 1)]
    assert [o.object_id for o in frame_objects(panoptic, video, drop_stuff=True)] == [5]  # type: ignore[arg-type]
    with pytest.raises(TrainingExportError, match="object 8 has no category"):
        frame_objects(np.array([[8]], dtype=np.uint32), video, drop_stuff=False)  # type: ignore[arg-type]


def test_split_stage_answers_become_the_splits() -> None:
    answers = {"train": [("a", "v1")], "val": [], "test": None}
    assert run_splits(answers.get) == {"train": [("a", "v1")], "val": []}
    assert run_splits(lambda split: None) is None  # a run without a split
    assert run_splits(None) is None  # an install without the split stage


# ------------------------------------------------------------------------------------ the CLI


def test_cli_exports_a_run_without_split_as_all(tiny_run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "coco"
    result = cli(str(tiny_run.root), "--coco", str(out), "--every", "3", "--embodiment", "spot")
    assert result.exit_code == 0, result.output
    assert "has no split" in result.output and "4 frames" in result.output  # 2 videos x frames 0, 3
    data = json.loads(annotation_file(out, "all").read_text())
    assert sorted((i["video_name"][-4:], i["frame"]) for i in data["images"]) == [
        ("0100", 0), ("0100", 3), ("1000", 0), ("1000", 3)]


@pytest.mark.parametrize("arguments, message", [
    (["--embodiment", "drone"], "no videos of embodiment 'drone'"),
    (["--every", "0"], "--every 0"),
    (["--categories", "nyu40"], "choose agnostic or mpcat40"),
])
def test_cli_bad_input_is_one_line_exit_2_and_writes_nothing(tiny_run: RunFolder, tmp_path: Path,
                                                             arguments: list[str], message: str) -> None:
    out = tmp_path / "coco"
    result = cli(str(tiny_run.root), "--coco", str(out), *arguments)
    assert result.exit_code == 2 and message in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_refuses_a_file_a_foreign_folder_and_its_own_export_without_overwrite(tiny_run: RunFolder,
                                                                                   tmp_path: Path) -> None:
    a_file = tmp_path / "out.json"
    a_file.write_text("{}")
    result = cli(str(tiny_run.root), "--coco", str(a_file))
    assert result.exit_code == 2 and "is a file" in result.output and a_file.read_text() == "{}"
    folder = tmp_path / "taken"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    for extra in ([], ["--overwrite"]):  # a folder export did not write is never written into
        result = cli(str(tiny_run.root), "--coco", str(folder), "--embodiment", "ambient", "--every", "6", *extra)
        assert result.exit_code == 2 and "was not written by `mvpd export`" in result.output, result.output
        assert [p.name for p in folder.iterdir()] == ["notes.txt"]
    ours = tmp_path / "coco"
    assert cli(str(tiny_run.root), "--coco", str(ours), "--embodiment", "ambient", "--every", "6").exit_code == 0
    result = cli(str(tiny_run.root), "--coco", str(ours), "--embodiment", "ambient", "--every", "6")
    assert result.exit_code == 2 and "--overwrite" in result.output  # its own export: replaced only when asked
    result = cli(str(tiny_run.root), "--coco", str(ours), "--embodiment", "ambient", "--every", "6", "--overwrite")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in ours.iterdir()) == [".mvpd-out", "annotations", "images"]


def test_cli_wants_exactly_one_target(tiny_run: RunFolder, tmp_path: Path) -> None:
    result = cli(str(tiny_run.root), "--coco", str(tmp_path / "a"), "--yolo", str(tmp_path / "b"))
    assert result.exit_code == 2 and "exactly one of --mvpd, --coco or --yolo" in result.output
    assert cli(str(tiny_run.root)).exit_code == 2
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_failed_export_leaves_no_temporary_file(tiny_run: RunFolder, tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    from pipeline.io import training_export

    def broken_jpeg(path: Path, rgb: np.ndarray) -> None:
        raise OSError(f"{path}: disk full")

    monkeypatch.setattr(training_export, "write_jpeg", broken_jpeg)
    with pytest.raises(OSError, match="disk full"):
        export_training_data(tiny_run, tmp_path / "out", unsplit(tiny_run), CocoExporter, ExportOptions())
    assert [p for p in (tmp_path / "out").rglob("*") if p.is_file()] == []


def test_cli_exports_the_split_stages_splits(tiny_run: RunFolder, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The CLI exports each split `pipeline.split.selection` answers (a fixed answer here; the split stage has its own tests)."""
    from pipeline.split import selection

    answers = {"train": [("ambient", "room.0000000000.0000001000")], "val": [("ambient", "room.0000000000.0000000100")],
               "test": []}
    monkeypatch.setattr(selection, "accepted_videos", lambda run, split: answers[split])
    out = tmp_path / "coco"
    result = cli(str(tiny_run.root), "--coco", str(out), "--every", "6")
    assert result.exit_code == 0, result.output
    assert "no split" not in result.output and "train 1, val 1, test 0" in result.output
    assert sorted(p.name for p in (out / "annotations").iterdir()) == [
        "instances_test.json", "instances_train.json", "instances_val.json"]
    val = json.loads(annotation_file(out, "val").read_text())
    assert [i["file_name"] for i in val["images"]] == ["ambient.room.0000000000.0000000100.0000000000.jpg"]
    assert json.loads(annotation_file(out, "test").read_text())["images"] == []
