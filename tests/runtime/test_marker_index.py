"""The consolidated marker index: a cache of a stage's markers that never changes what readers see."""

from __future__ import annotations

import json
import os
import pickle
from dataclasses import replace
from pathlib import Path

import fsspec
import pytest

from pipeline.store import marker_index
from pipeline.runtime.executor import run_stage
from pipeline.store.marker_index import INDEX_NAME, FsspecMarkerFolder, LocalMarkerFolder, load_markers, write_index
from pipeline.store.markers import Damage, Marker, OutputFile, marker_text, parse_marker
from pipeline.store.run_folder import RunFolder
from pipeline.store.run_folder import as_run
from tests.runtime.test_executor import make_job
from tests.runtime.tiny_stage import TinyStage

STAGE = "render"


def a_marker(unit: str, files: int = 3, seconds: float = 1.5) -> Marker:
    manifest = [OutputFile(f"videos/{unit}/{index}.bin", 4 + index, f"{index:08x}") for index in range(files)]
    return Marker(STAGE, unit, "hash", "0.1+abc", [f"videos/{unit}"], {"videos": 1}, seconds, 1, "host", 1000.0 + seconds,
                  {"frames": 3}, manifest)


def every_json(root: Path, stage: str) -> dict[str, Marker]:
    """The reference: every marker file read and parsed, as `stage_markers` did before the index."""
    found = {}
    for path in sorted((root / "_state" / stage).glob("*.json")):
        marker = parse_marker(path.read_text(encoding="utf-8"))
        if marker is not None:
            found[marker.unit] = marker
    return found


@pytest.fixture
def root(tmp_path) -> Path:
    for index in range(6):
        as_run(tmp_path).write_marker(a_marker(f"u{index}", files=index + 1))
    return tmp_path


class CountingFolder(LocalMarkerFolder):
    """The local folder, counting the marker files it reads."""

    read: list[str] = []

    def read_texts(self, names: list[str]) -> dict[str, str]:
        CountingFolder.read = list(names)
        return super().read_texts(names)


def test_markers_come_from_the_index_and_only_changed_ones_are_read(root):
    folder = CountingFolder(root, STAGE)
    assert write_index(folder) == 6 and (root / "_state" / STAGE / INDEX_NAME).is_file()
    assert load_markers(folder) == every_json(root, STAGE) and CountingFolder.read == []
    as_run(root).write_marker(a_marker("u2", files=9, seconds=7.0))  # rewritten after the index
    (root / "_state" / STAGE / "u4.json").unlink()  # deleted after the index
    as_run(root).write_marker(a_marker("u9"))  # new
    found = load_markers(folder)
    assert CountingFolder.read == ["u2.json", "u9.json"]
    assert found == every_json(root, STAGE) and list(found) == list(every_json(root, STAGE))
    assert found["u2"].seconds == 7.0 and len(found["u2"].files) == 9 and "u4" not in found


def test_a_rewrite_of_the_same_size_and_mtime_is_still_seen(root):
    write_index(LocalMarkerFolder(root, STAGE))
    path = (root / "_state" / STAGE / "u3.json")
    before = path.stat()
    changed = replace(a_marker("u3", files=4), host="hozt")  # same size, other content
    assert len(marker_text(changed)) == before.st_size
    as_run(root).write_marker(changed)
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert as_run(root).markers(STAGE)["u3"].host == "hozt"


def test_version_1_and_unreadable_markers_count_as_absent_from_the_index_too(root):
    folder = (root / "_state" / STAGE / "x.json").parent
    (folder / "old.json").write_text(json.dumps({"stage": STAGE, "unit": "old", "version": 1}), encoding="utf-8")
    (folder / "bad.json").write_text("{not json", encoding="utf-8")
    write_index(LocalMarkerFolder(root, STAGE))
    assert set(as_run(root).markers(STAGE)) == {f"u{i}" for i in range(6)} == set(every_json(root, STAGE))


@pytest.mark.parametrize("damage", [b"", b"PAR1 not parquet", b"\x00" * 64])
def test_a_damaged_index_is_ignored_and_rebuilt(root, monkeypatch, damage):
    monkeypatch.setattr(marker_index, "REFRESH_AFTER", 1)
    index = root / "_state" / STAGE / INDEX_NAME
    index.write_bytes(damage)
    assert as_run(root).markers(STAGE) == every_json(root, STAGE)
    assert index.read_bytes() != damage  # rewritten by the reader (the folder is writable)
    CountingFolder.read = ["sentinel"]
    assert load_markers(CountingFolder(root, STAGE)) == every_json(root, STAGE) and CountingFolder.read == []


def test_an_index_of_another_schema_is_not_trusted(root):
    import pyarrow as pa
    import pyarrow.parquet as pq

    lying = pa.table({"name": ["u0.json"], "identity": ["x"], "header": ["{}"]})
    pq.write_table(lying, root / "_state" / STAGE / INDEX_NAME)
    assert as_run(root).markers(STAGE) == every_json(root, STAGE)


def test_a_read_only_folder_is_read_without_an_index(root, monkeypatch):
    def refuse(self, data: bytes) -> None:
        raise PermissionError("read-only file system")

    monkeypatch.setattr(marker_index, "REFRESH_AFTER", 1)
    monkeypatch.setattr(LocalMarkerFolder, "write_index", refuse)
    assert as_run(root).markers(STAGE) == every_json(root, STAGE)
    assert not (root / "_state" / STAGE / INDEX_NAME).exists()


def test_a_stage_run_leaves_an_index_equal_to_its_markers(tmp_path):
    run = RunFolder.create(tmp_path / "run", make_job({"a": [1.0], "b": [0.5]}))
    run_stage(TinyStage(run.job()), run, executor="local")
    rows = marker_index._read_rows(LocalMarkerFolder(run.root, "tiny"))
    assert {marker.unit: marker for _, marker in rows.values()} == every_json(run.root, "tiny") != {}


def test_the_fsspec_folder_on_a_memory_store(root):
    fs = fsspec.filesystem("memory")
    base = "/index-test/_state/render"
    for path in (root / "_state" / STAGE).glob("*.json"):
        fs.pipe_file(f"{base}/{path.name}", path.read_bytes())
    folder = FsspecMarkerFolder(fs, base)
    assert write_index(folder) == 6 and fs.exists(f"{base}/{INDEX_NAME}")
    fs.pipe_file(f"{base}/u1.json", marker_text(a_marker("u1", files=5, seconds=3.0)).encode())
    fs.rm(f"{base}/u5.json")
    expected = {unit: m for unit, m in every_json(root, STAGE).items() if unit != "u5"}
    expected["u1"] = a_marker("u1", files=5, seconds=3.0)
    assert load_markers(folder) == expected
    fs.pipe_file(f"{base}/{INDEX_NAME}", b"garbage")
    assert load_markers(folder) == expected
    fs.rm(base, recursive=True)


def test_check_files_finds_missing_resized_misplaced_and_recorded_damage(tmp_path):
    marker = a_marker("u0", files=4)
    for entry in marker.files:
        (tmp_path / entry.path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / entry.path).write_bytes(b"x" * entry.size)
    as_run(tmp_path).write_marker(marker)
    assert as_run(tmp_path).check_files(marker) == []
    (tmp_path / marker.files[0].path).unlink()
    (tmp_path / marker.files[1].path).write_bytes(b"xx")
    misplaced = OutputFile(f"{marker.files[2].path}/inner.bin", 1, "0")  # its "folder" is a file
    marker.files.append(misplaced)
    as_run(tmp_path).record_damage(STAGE, [(marker, [Damage(STAGE, "u0", marker.files[3].path, "is unreadable Parquet")])])
    assert [(d.path, d.problem) for d in as_run(tmp_path).check_files(marker)] == [
        (marker.files[0].path, "is missing"), (marker.files[1].path, "has 2 bytes, the marker says 5"),
        (misplaced.path, "is missing"), (marker.files[3].path, "is unreadable Parquet")]


def test_unit_damage_names_exactly_the_units_with_a_missing_or_resized_file(tmp_path):
    found = {}
    for index in range(40):
        marker = a_marker(f"u{index:02d}", files=3)
        for entry in marker.files[: index % 4]:  # only units 3 mod 4 have all their files
            (tmp_path / entry.path).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / entry.path).write_bytes(b"x" * (entry.size if index % 3 else 1))  # 0 mod 3: resized
        found[marker.unit] = marker
    damaged = as_run(tmp_path).damage(found)
    assert sorted(set(found) - set(damaged)) == ["u07", "u11", "u19", "u23", "u31", "u35"]
    assert damaged["u05"][0].problem == "is missing" and "has 1 bytes" in damaged["u03"][0].problem


def test_a_marker_from_the_index_checks_pickles_and_compares_like_one_from_its_file(tmp_path):
    marker = a_marker("u0", files=5)
    for entry in marker.files[1:]:
        (tmp_path / entry.path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / entry.path).write_bytes(b"x" * (entry.size if entry.size != 6 else 2))
    as_run(tmp_path).write_marker(marker)
    write_index(LocalMarkerFolder(tmp_path, STAGE))
    indexed = as_run(tmp_path).markers(STAGE)["u0"]
    assert "_manifest" in indexed.__dict__  # still columnar: the check below must not need `files`
    assert as_run(tmp_path).check_files(indexed) == as_run(tmp_path).check_files(marker) != []
    assert "_manifest" in indexed.__dict__
    copy = pickle.loads(pickle.dumps(indexed))
    assert copy == marker and copy.files == marker.files and marker_text(indexed) == marker_text(marker)


def test_an_index_rewritten_from_an_index_keeps_every_marker(root, monkeypatch):
    monkeypatch.setattr(marker_index, "REFRESH_AFTER", 1)
    write_index(LocalMarkerFolder(root, STAGE))
    as_run(root).write_marker(a_marker("u7", files=2))  # one stale row: the reader rewrites from the columnar rows
    before = (root / "_state" / STAGE / INDEX_NAME).read_bytes()
    assert as_run(root).markers(STAGE) == every_json(root, STAGE)
    assert (root / "_state" / STAGE / INDEX_NAME).read_bytes() != before
    CountingFolder.read = ["sentinel"]
    assert load_markers(CountingFolder(root, STAGE)) == every_json(root, STAGE) and CountingFolder.read == []
