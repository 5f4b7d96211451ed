"""A tampered marker, marker index or dataset index is never followed outside the run (issue 20, point 1).

Every path read from a marker is checked as a plain relative path inside the run (and every store key as
one under the unit's own attempt prefix) before anything is read, written or deleted; a marker that fails
is not followed: its unit is simply not done and runs again.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import time
from pathlib import Path

import pytest

from pipeline.runtime.executor import plan_stage, run_stage
from pipeline.store.lock import STALE_SECONDS, RunLock, RunLockedError
from pipeline.store.marker_index import LocalMarkerFolder, _encode
from pipeline.store.markers import OutputFile, marker_text, parse_marker
from pipeline.store.run_folder import RunFolder, RunFolderError
from tests.runtime.test_executor import make_job
from tests.runtime.tiny_stage import TinyStage


@pytest.fixture
def tiny(tmp_path) -> RunFolder:
    run = RunFolder.create(tmp_path / "run", make_job({"a": [1.0], "b": [0.5]}))
    run_stage(TinyStage(run.job()), run, executor="local")
    return run


def victims(tmp_path: Path) -> list[Path]:
    """A folder beside the run (reached by `../`) and one named by an absolute path, each holding a file."""
    found = []
    for name in ("victim", "absolute-victim"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "precious.txt").write_text("keep me")
        found.append(tmp_path / name)
    return found


def test_a_marker_naming_paths_outside_the_run_is_never_followed(tiny, tmp_path):
    beside, absolute = victims(tmp_path)
    path = (tiny.root / "_state" / "tiny" / "a.json")
    data = json.loads(path.read_text())
    data["outputs"] += ["../victim", str(absolute)]
    data["files"] += [{"path": "../victim/precious.txt", "size": 7, "crc32c": "0"}]
    path.write_text(json.dumps(data))
    assert tiny.marker("tiny", "a") is None and "a" not in tiny.markers("tiny")
    assert [u.id for u in plan_stage(TinyStage(tiny.job()), tiny).to_run] == ["a"]  # not done: it runs again
    report = run_stage(TinyStage(tiny.job()), tiny, force=True, executor="local")
    assert not report.failed and (beside / "precious.txt").is_file() and (absolute / "precious.txt").is_file()
    assert tiny.marker("tiny", "a").outputs == ["tiny/part-a.parquet", "tiny_files/a.txt"]


@pytest.mark.parametrize("bad", ["job.yaml", "_state/lock.json", "tiny/../../x", "tiny//x", "/tiny/x", "tiny/.x",
                                 "tiny/a\ntiny/b", 7])
def test_outputs_must_be_plain_paths_of_run_data(tiny, bad):
    data = json.loads((tiny.root / "_state" / "tiny" / "a.json").read_text())
    data["outputs"].append(bad)
    assert parse_marker(json.dumps(data), "a.json") is None
    assert parse_marker((tiny.root / "_state" / "tiny" / "a.json").read_text(), "a.json") is not None
    assert parse_marker((tiny.root / "_state" / "tiny" / "a.json").read_text(), "b.json") is None  # not its own file


def test_a_tampered_marker_index_row_is_never_followed(tiny, tmp_path):
    beside, _ = victims(tmp_path)
    folder = LocalMarkerFolder(tiny.root, "tiny")
    listing = folder.listing()
    marker = tiny.marker("tiny", "a")
    tampered = dataclasses.replace(marker, outputs=[*marker.outputs, "../victim"],
                                   files=[*marker.files, OutputFile("../victim/precious.txt", 7, "0")])
    # The row claims the identity of the real marker file, as a forged index would.
    folder.write_index(_encode({"a.json": (listing["a.json"], tampered)}))
    assert tiny.markers("tiny")["a"].outputs == marker.outputs  # the marker file, read instead
    run_stage(TinyStage(tiny.job()), tiny, force=True, executor="local")
    assert (beside / "precious.txt").is_file()


def test_store_keys_must_lie_under_the_units_own_attempt_prefix(tiny):
    marker = tiny.marker("tiny", "a")
    good = {p: f"_attempts/tiny/a/host.1.2/{p}" for p in marker.outputs}
    assert parse_marker(marker_text(dataclasses.replace(marker, keys=good)), "a.json") is not None
    for key in ("job.yaml", "_attempts/tiny/b/host.1.2/tiny/part-a.parquet", "_attempts/tiny/a/../../job.yaml",
                "_attempts/tiny/a/host.1.2/tiny/part-b.parquet"):
        keys = {**good, "tiny/part-a.parquet": key}
        assert parse_marker(marker_text(dataclasses.replace(marker, keys=keys)), "a.json") is None, key


def test_commit_refuses_to_delete_through_a_link_out_of_the_run(tiny, tmp_path):
    beside, _ = victims(tmp_path)
    (tiny.root / "linked").symlink_to(beside)
    with pytest.raises(RunFolderError, match="linked is a symbolic link inside the run folder"):
        tiny.files.retire(dataclasses.replace(tiny.marker("tiny", "a"), outputs=["linked/precious.txt"]))
    assert (beside / "precious.txt").is_file()


@pytest.mark.parametrize("host", ["this", "elsewhere"])
def test_a_tampered_lock_file_is_judged_by_its_age_never_by_what_it_says(tmp_path, host):
    lock = tmp_path / "_state" / "lock.json"
    lock.parent.mkdir(parents=True)
    lock.write_text(json.dumps({"host": socket.gethostname() if host == "this" else host, "pid": "../../victim",
                                "heartbeat": "/etc/passwd"}))
    with pytest.raises(RunLockedError, match="held but unreadable"):  # fields of the wrong type: unreadable
        with RunLock(tmp_path):
            pass
    old = time.time() - STALE_SECONDS - 5
    os.utime(lock, (old, old))
    with RunLock(tmp_path):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
