"""Fuzzing the readers of a run folder's own untrusted bytes: markers, the marker index, the run lock.

Anyone who can write into a shared run folder can put any bytes there. The property (tests/fuzz/outcome.py):
any bytes give a valid result (a marker or none, the markers the folder proves, a lock taken or refused)
or the project's one-line error naming the run; never another exception type, a hang or a crash.
"""

from __future__ import annotations

import io
import json
import os
import random
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline.config import Embodiment, Job, ProceduralSource, SceneSources
from pipeline.store.lock import LOCK_KEY, RunLock, RunLockedError, local_holder
from pipeline.store.marker_index import INDEX_NAME
from pipeline.store.markers import Marker, OutputFile, code_version, marker_text, parse_marker
from pipeline.store.run_folder import RunFolder, RunFolderError
from tests.fuzz.outcome import result_or_one_line_error

STAGE = "fuzz"
UNITS = ("a", "b", "c")

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=20)


def marker_of(unit: str) -> Marker:
    files = [OutputFile(f"frames/part-{unit}.parquet", 10, "0badf00d"), OutputFile(f"videos/e/{unit}.zarr/zarr.json", 5, "00000000")]
    return Marker(STAGE, unit, "hash", code_version(), [f"frames/part-{unit}.parquet", f"videos/e/{unit}.zarr"],
                  {"frames": 1}, 1.0, 1, "host", 1.0, {}, files)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    job = Job(name="fuzz", scenes=SceneSources(procedural=ProceduralSource(count=1)), embodiments=[Embodiment(name="e")])
    folder = RunFolder.create(tmp_path_factory.mktemp("fuzz") / "run", job)
    for unit in UNITS:
        folder.write_marker(marker_of(unit))
    folder.index_markers(STAGE)
    return folder


def valid_markers(found: dict[str, Marker]) -> dict[str, Marker]:
    """`found`, after checking it is what a reader may be handed: markers of this stage named by their unit."""
    assert isinstance(found, dict)
    for unit, marker in found.items():
        assert isinstance(marker, Marker) and marker.unit == unit and marker.stage == STAGE
    return found


def mutated(data: bytes, seed: int) -> bytes:
    """`data` truncated, with bytes flipped, repeated or spliced (what a damaged or forged file looks like)."""
    rng = random.Random(seed)
    data = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        kind = rng.choice(("flip", "truncate", "repeat", "splice"))
        if not data:
            break
        at = rng.randrange(len(data))
        if kind == "flip":
            data[at] ^= 1 << rng.randrange(8)
        elif kind == "truncate":
            del data[at:]
        elif kind == "repeat":
            data[at:at] = data[at:at + rng.randint(1, 64)] * rng.randint(1, 50)
        else:
            data[at:at + 8] = rng.randbytes(8)
    return bytes(data)


# ------------------------------------------------------------------------------------------ markers


@given(st.one_of(
    st.text(max_size=200),
    st.integers(1, 300_000).map(lambda depth: "[" * depth),
    json_values.map(json.dumps),
    st.builds(lambda key, value: json.dumps({**json.loads(marker_text(marker_of("a"))), key: value}),
              st.sampled_from(["stage", "unit", "outputs", "files", "rows", "version", "keys", "info", "attempt"]),
              json_values)))
def test_any_marker_text_gives_a_marker_or_none(text):
    found = result_or_one_line_error(lambda: parse_marker(text, "a.json"), (), "a.json")
    assert found is None or (isinstance(found, Marker) and found.unit == "a")


@given(st.binary(max_size=300) | st.integers(0, 2**31).map(lambda seed: mutated(marker_text(marker_of("b")).encode(), seed)))
def test_any_marker_file_gives_the_markers_it_proves(run, data):
    path = run.root / "_state" / STAGE / "b.json"
    path.write_bytes(data)
    try:
        found = valid_markers(result_or_one_line_error(lambda: run.markers(STAGE), RunFolderError, str(run.root)))
        assert {"a", "c"} <= set(found)  # the other units are untouched by b's bytes
        single = run.marker(STAGE, "b")
        assert single is None or single.unit == "b"
    finally:
        path.write_text(marker_text(marker_of("b")))


# ------------------------------------------------------------------------------------- marker index


@given(st.binary(max_size=2000) | st.integers(0, 2**31))
def test_any_index_bytes_give_the_markers_of_the_files(run, data):
    index = run.root / "_state" / STAGE / INDEX_NAME
    good = index.read_bytes()
    index.write_bytes(mutated(good, data) if isinstance(data, int) else data)
    try:
        found = valid_markers(result_or_one_line_error(lambda: run.markers(STAGE), RunFolderError, str(run.root)))
        assert set(found) == set(UNITS)  # a damaged index is a cache ignored: the marker files say the same
    finally:
        index.write_bytes(good)


def test_a_valid_index_is_read_from_its_bytes(run):
    """The control of the index property: the unmutated bytes are an index of all three markers."""
    table = pq.read_table(io.BytesIO((run.root / "_state" / STAGE / INDEX_NAME).read_bytes()))
    assert sorted(table.column("name").to_pylist()) == [f"{u}.json" for u in UNITS]


# -------------------------------------------------------------------------------------------- lock


lock_records = st.fixed_dictionaries({}, optional={
    "host": st.sampled_from([os.uname().nodename, "elsewhere"]) | json_values,
    "pid": st.sampled_from([os.getpid(), 1, 2**22 + 7, -1, 0, 2**70]) | json_values,
    "process_started": json_values, "started": st.floats() | json_values, "heartbeat": st.floats() | json_values,
    "owner": json_values})


@given(st.binary(max_size=300) | lock_records.map(lambda r: json.dumps(r).encode())
       | st.integers(1, 300_000).map(lambda depth: b"[" * depth))
def test_any_lock_file_is_taken_over_or_refused_in_one_line(run, data):
    path = run.root / LOCK_KEY
    path.write_bytes(data)
    holder = local_holder(path)
    assert holder is None or isinstance(holder, dict)

    def take() -> bool:
        with RunLock(run.root):
            return True

    try:
        result_or_one_line_error(take, RunLockedError, str(run.root))
    finally:
        path.unlink(missing_ok=True)
        Path(str(path) + ".guard").unlink(missing_ok=True)
