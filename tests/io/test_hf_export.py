"""Hugging Face export (`mvpd export --hf`): the real `datasets` loads it plainly and streaming, offline;
pixels round-trip bit for bit; the card matches the shards; overwrite, refusals and failures leave DIR whole."""

from __future__ import annotations

import filecmp
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import typer
import yaml
from typer.testing import CliRunner

from pipeline.cli import mvpd_io
from pipeline.io.huggingface import HfExportError, export_hf_dataset
from pipeline.io.huggingface import export as hf_export
from pipeline.io.huggingface.features import dataset_features
from pipeline.io.reader import list_videos, load_video
from pipeline.io.tables import to_table
from pipeline.store.run_folder import RunFolder
from tests.render.tiny_run import FRAMES, render_tiny_run
from tests.render.tiny_scenes import CHAIR

datasets = pytest.importorskip("datasets")  # the `test` extra installs it; a bare install skips

AMBIENT = ("ambient", "room.0000000000.0000000100"), ("ambient", "room.0000000000.0000001000")
SPOT = ("spot", "room.0000000000.0000000100"), ("spot", "room.0000000000.0000001000")


@pytest.fixture(scope="module")
def offline(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """`datasets` and the Hub client offline, with a cache of their own (restored afterwards)."""
    import huggingface_hub.constants

    cache = tmp_path_factory.mktemp("hf-home")
    with pytest.MonkeyPatch.context() as patch:
        for name in ("HF_DATASETS_OFFLINE", "HF_HUB_OFFLINE"):
            patch.setenv(name, "1")
        patch.setenv("HF_HOME", str(cache))
        patch.setattr(datasets.config, "HF_HUB_OFFLINE", True)
        patch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
        yield cache / "datasets"


def load(folder: Path, cache: Path, **options: Any) -> Any:
    return datasets.load_dataset(str(folder), cache_dir=str(cache), **options)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    """The rendered room (ambient and spot, 0.1 m and 1.0 m, 6 frames of 64 x 48) with a split by hand:
    train = the ambient videos (the tall one shows the chair, an unseen object, and is rejected), val = the
    spot videos (the short one is empty)."""
    run = render_tiny_run(tmp_path_factory.mktemp("hf") / "run")
    rows = []
    for (embodiment, name), split, empty, zero_shot in [(AMBIENT[0], "train", False, False),
                                                        (AMBIENT[1], "train", False, True),
                                                        (SPOT[0], "val", True, False), (SPOT[1], "val", False, False)]:
        rows.append({"embodiment": embodiment, "video_name": name, "scene_id": "room", "split": split, "empty": empty,
                     "zero_shot_rejected": zero_shot, "accepted": not (empty or zero_shot)})
    instances = [{"scene_id": "room", "object_id": CHAIR, "color": [0, 0, CHAIR], "raw_name": "chair", "cluster": 0,
                  "unseen": True}]
    run.commit_tables("split", "room", {"splits": to_table("splits", rows),
                                        "zero_shot_instances": to_table("zero_shot_instances", instances)})
    return run


@pytest.fixture(scope="module")
def exported(tiny_run: RunFolder, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("out") / "hf"
    summary = export_hf_dataset(tiny_run, out, rows_per_group=4)
    assert summary.frames == {"train": 2 * FRAMES, "val": 2 * FRAMES} and summary.videos == 4
    return out


def cli(*arguments: str) -> Any:
    app = typer.Typer()
    mvpd_io.register(app)
    return CliRunner().invoke(app, ["export", *arguments])


# ------------------------------------------------------------------------------------ loading


def test_load_dataset_gives_one_row_per_frame_of_each_split_in_video_order(exported: Path, offline: Path) -> None:
    loaded = load(exported, offline)
    assert sorted(loaded) == ["train", "val"]
    keys = [(r["embodiment"], r["video_name"], r["frame"]) for r in loaded["train"].select_columns(
        ["embodiment", "video_name", "frame"])]
    assert keys == [(e, n, t) for e, n in AMBIENT for t in range(FRAMES)]
    assert loaded["val"].num_rows == 2 * FRAMES
    features = loaded["train"].features
    assert isinstance(features["rgb"], datasets.Image) and isinstance(features["depth"], datasets.Image)
    assert features["panoptic"] == datasets.Array2D((48, 64), "uint32")


def test_pixels_pose_and_intrinsics_equal_the_runs_arrays(exported: Path, offline: Path, tiny_run: RunFolder) -> None:
    loaded = load(exported, offline)
    for split in ("train", "val"):
        rows = loaded[split]
        panoptic = rows.with_format("arrow")["panoptic"].combine_chunks().to_numpy(zero_copy_only=False)  # uint32
        for index, row in enumerate(rows):
            video = load_video(tiny_run, row["video_name"], row["embodiment"])
            t = row["frame"]
            rgb, depth = np.asarray(row["rgb"]), np.asarray(row["depth"])
            assert (row["rgb"].mode, row["depth"].mode) == ("RGB", "I;16")
            assert rgb.dtype == np.uint8 and np.array_equal(rgb, video.rgb[t])
            assert depth.dtype == np.uint16 and np.array_equal(depth, video.depth[t])
            assert panoptic.dtype == np.uint32 and np.array_equal(panoptic[index], video.panoptic[t])
            assert np.array_equal(np.asarray(row["pose"]), video.poses[t])  # float64, exactly
            assert row["intrinsics"] == {k: video.intrinsics[k] for k in ("fx", "fy", "cx", "cy", "width", "height")}


def test_numpy_format_decodes_every_pixel_column_to_an_array(exported: Path, offline: Path,
                                                             tiny_run: RunFolder) -> None:
    row = load(exported, offline, split="val").with_format("numpy")[7]
    video = load_video(tiny_run, str(row["video_name"]), str(row["embodiment"]))
    assert row["rgb"].shape == (48, 64, 3) and row["depth"].dtype == np.uint16
    assert np.array_equal(row["panoptic"], video.panoptic[int(row["frame"])])  # int64 there: same values


def test_streaming_gives_the_same_rows(exported: Path, offline: Path) -> None:
    plain = load(exported, offline, split="train")
    streamed = list(load(exported, offline, split="train", streaming=True))
    assert len(streamed) == plain.num_rows
    for row, again in zip(plain, streamed):
        assert (again["video_name"], again["frame"]) == (row["video_name"], row["frame"])
        assert np.array_equal(np.asarray(again["depth"]), np.asarray(row["depth"]))
        assert np.array_equal(np.asarray(again["rgb"]), np.asarray(row["rgb"]))
        assert again["panoptic"] == row["panoptic"]


def test_flags_and_zero_shot_objects_are_the_split_stages(exported: Path, offline: Path) -> None:
    loaded = load(exported, offline)
    columns = ["video_name", "embodiment", "empty", "zero_shot_rejected", "accepted", "zero_shot_object_ids",
               "object_ids", "object_categories"]
    flags = {(r["embodiment"], r["video_name"]): r for split in ("train", "val")
             for r in loaded[split].select_columns(columns)}
    assert (flags[AMBIENT[1]]["zero_shot_rejected"], flags[AMBIENT[1]]["accepted"]) == (True, False)
    assert (flags[SPOT[0]]["empty"], flags[SPOT[0]]["accepted"]) == (True, False)
    assert flags[SPOT[1]]["accepted"] and not flags[SPOT[1]]["empty"]
    for row in flags.values():
        assert row["zero_shot_object_ids"] == ([CHAIR] if CHAIR in row["object_ids"] else [])
        assert len(row["object_categories"]) == len(row["object_ids"])


# --------------------------------------------------------------------------------- card and shards


def front_matter(folder: Path) -> dict[str, Any]:
    text = (folder / "README.md").read_text()
    assert text.startswith("---\n")
    return yaml.safe_load(text.split("---\n")[1])


def test_card_front_matter_matches_the_shards(exported: Path, tiny_run: RunFolder) -> None:
    card = front_matter(exported)
    assert card["license"] == "other" and (exported / card["license_link"]).is_file()
    [config] = card["configs"]
    for entry in config["data_files"]:
        assert sorted(p.name for p in exported.glob(entry["path"])) == [f"{entry['split']}-00000-of-00001.parquet"]
    info = card["dataset_info"]
    assert {s["name"]: s["num_examples"] for s in info["splits"]} == {
        split: sum(pq.read_metadata(p).num_rows for p in exported.glob(f"data/{split}-*.parquet"))
        for split in ("train", "val")}
    assert info["download_size"] == sum(p.stat().st_size for p in (exported / "data").iterdir())
    assert datasets.Features._from_yaml_list(info["features"]) == dataset_features(48, 64)
    assert (exported / "mvpd_job.yaml").read_bytes() == (tiny_run.root / "job.yaml").read_bytes()
    prose = (exported / "README.md").read_text()
    job_hash = yaml.safe_load((tiny_run.root / "job.yaml").read_text())["job_hash"]
    assert f"job hash `{job_hash}`" in prose and "Opipari" in prose and "0.1 m" in prose


def test_parquet_schema_alone_declares_the_features(exported: Path, offline: Path) -> None:
    """Loading the shards without the card (`data_files=`) still decodes images and arrays."""
    shards = sorted(str(p) for p in (exported / "data").glob("val-*.parquet"))
    loaded = datasets.load_dataset("parquet", data_files={"val": shards}, cache_dir=str(offline), split="val")
    assert loaded.features == dataset_features(48, 64)
    assert np.asarray(loaded[0]["depth"]).dtype == np.uint16


def test_shards_close_at_the_size_bound_with_fixed_row_groups(tiny_run: RunFolder, tmp_path: Path,
                                                              offline: Path) -> None:
    out = tmp_path / "hf"
    export_hf_dataset(tiny_run, out, split="train", rows_per_group=4, shard_bytes=1)  # a shard per row group
    shards = sorted((out / "data").iterdir())
    assert [p.name for p in shards] == [f"train-{i:05d}-of-00003.parquet" for i in range(3)]  # 12 rows / 4
    assert [pq.ParquetFile(p).metadata.row_group(0).num_rows for p in shards] == [4, 4, 4]
    assert load(out, offline, split="train").num_rows == 2 * FRAMES


def test_the_same_run_gives_a_byte_identical_export(tiny_run: RunFolder, exported: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    export_hf_dataset(tiny_run, again, rows_per_group=4)
    files = sorted(p.relative_to(exported) for p in exported.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    match, mismatch, errors = filecmp.cmpfiles(exported, again, [str(f) for f in files], shallow=False)
    assert (mismatch, errors) == ([], [])


def test_a_run_without_split_is_one_train_split_with_null_flags(tmp_path: Path, offline: Path) -> None:
    run = render_tiny_run(tmp_path / "run")
    summary = export_hf_dataset(run, tmp_path / "hf", embodiment="spot")
    assert summary.frames == {"train": 2 * FRAMES} and not summary.has_split
    rows = load(tmp_path / "hf", offline, split="train").select_columns(["embodiment", "empty", "accepted"])
    assert {(r["embodiment"], r["empty"], r["accepted"]) for r in rows} == {("spot", None, None)}


# ------------------------------------------------------------------------------ refusals and failures


def test_cli_writes_refuses_again_and_overwrites(tiny_run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "hf"
    first = cli(str(tiny_run.root), "--hf", str(out), "--split", "val")
    assert first.exit_code == 0, first.output
    assert "export: 12 frames (val 12) of 2 videos in 1 shards" in " ".join(first.output.split())
    card = (out / "README.md").read_bytes()
    again = cli(str(tiny_run.root), "--hf", str(out))
    assert again.exit_code == 2 and "exists and is not empty" in again.output and "--overwrite" in again.output
    assert (out / "README.md").read_bytes() == card  # untouched
    replaced = cli(str(tiny_run.root), "--hf", str(out), "--overwrite")
    assert replaced.exit_code == 0, replaced.output
    assert sorted(p.name for p in (out / "data").iterdir()) == ["train-00000-of-00001.parquet",
                                                               "val-00000-of-00001.parquet"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging or old copy left


@pytest.mark.parametrize("arguments, words", [
    (["--split", "test"], "made train, val"),
    (["--split", "all"], "union of every split"),
    (["--embodiment", "lidar"], "no videos of embodiment 'lidar'"),
    (["--coco", "COCO"], "exactly one of"),
])
def test_cli_refuses_bad_options_in_one_line(tiny_run: RunFolder, tmp_path: Path, arguments: list[str],
                                             words: str) -> None:
    arguments = [a.replace("COCO", str(tmp_path / "coco")) for a in arguments]
    result = cli(str(tiny_run.root), "--hf", str(tmp_path / "hf"), *arguments)
    assert result.exit_code == 2 and words in " ".join(result.output.split())
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
    assert not (tmp_path / "hf").exists()


def test_cli_refuses_a_folder_inside_the_run_and_a_foreign_folder(tiny_run: RunFolder, tmp_path: Path) -> None:
    inside = cli(str(tiny_run.root), "--hf", str(tiny_run.root / "hf"))
    assert inside.exit_code == 2 and "inside the run folder" in inside.output
    assert not (tiny_run.root / "hf").exists()
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("mine")
    refused = cli(str(tiny_run.root), "--hf", str(theirs), "--overwrite")
    assert refused.exit_code == 2 and (theirs / "notes.txt").read_text() == "mine"


def test_overwrite_replaces_only_an_earlier_hf_export(tiny_run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "hf"
    export_hf_dataset(tiny_run, out, split="val")
    (out / "extra.bin").write_bytes(b"x")
    with pytest.raises(HfExportError, match="'extra.bin', which an --hf export does not write"):
        export_hf_dataset(tiny_run, out, overwrite=True)
    assert (out / "extra.bin").is_file()


def test_a_failed_export_leaves_no_folder_and_keeps_the_previous_one(tiny_run: RunFolder, tmp_path: Path) -> None:
    def fail_on_second_video(name: str) -> None:
        seen.append(name)
        if len(seen) == 2:
            raise RuntimeError("disk full")

    seen: list[str] = []
    with pytest.raises(RuntimeError, match="disk full"):
        export_hf_dataset(tiny_run, tmp_path / "new", on_video=fail_on_second_video)
    assert list(tmp_path.iterdir()) == []  # neither DIR nor its staging folder
    kept = tmp_path / "kept"
    export_hf_dataset(tiny_run, kept, split="val")
    before = {p.relative_to(kept): p.read_bytes() for p in kept.rglob("*") if p.is_file()}
    seen.clear()
    with pytest.raises(RuntimeError, match="disk full"):
        export_hf_dataset(tiny_run, kept, overwrite=True, on_video=fail_on_second_video)
    assert {p.relative_to(kept): p.read_bytes() for p in kept.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]


def test_videos_of_several_sizes_are_refused_with_the_fix(tiny_run: RunFolder) -> None:
    videos = {key: {"height": 48, "width": 64} for key in list_videos(tiny_run)}
    videos[SPOT[0]] = {"height": 480, "width": 640}
    splits = hf_export.planned_splits(tiny_run, None, None)
    with pytest.raises(HfExportError, match="several image sizes .* --embodiment"):
        hf_export._frame_size(tiny_run, splits, videos)


def test_without_datasets_the_export_says_what_to_install(tiny_run: RunFolder, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(__import__("sys").modules, "datasets", None)  # `import datasets` raises ImportError
    with pytest.raises(HfExportError, match=r"pip install 'mvpd-pipeline\[hf\]'"):
        export_hf_dataset(tiny_run, tmp_path / "hf")
    assert not (tmp_path / "hf").exists()
