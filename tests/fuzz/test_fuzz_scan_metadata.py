"""Fuzz tests of the scan datasets' metadata readers: Replica's info_semantic.json, ScanNet's aggregation
and segs JSON and its label TSV, Matterport3D's .house and HM3DSem's .semantic.txt.

Each builds a valid file, then breaks it (truncate, repeat, overflow a number, nest, change a type, insert
NUL or invalid UTF-8) and asserts the one property: a result, or SceneError in one line naming the file.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline.scenes.hm3dsem import read_semantic_table
from pipeline.scenes.matterport3d import house_objects, read_house
from pipeline.scenes.replica import read_info
from pipeline.scenes.ply import write_ply
from pipeline.scenes.scannet import _segment_list, read_labels_tsv, read_scannet
from pipeline.scenes.scene import SceneError
from tests.fuzz.breaking import broken_bytes
from tests.fuzz.outcome import result_or_one_line_error

NAMES = st.sampled_from(["chair", "wall", "floor", "undefined", "non-plane", "anonymize_text", "kitchen cabinet",
                         "table, dining", 'say "hi"', "é", ""])
IDS = st.integers(0, 40)
ODD_NUMBERS = st.sampled_from([2**32 - 2, 2**32 - 1, 2**32, 2**63, 10**30, -1, -2**63 - 1, 1.5, 1e300, True, None])
WIDE = st.sampled_from([2**31, 2**32, 10**30, -2])  # integers past what a field may hold
ODD_VALUES = st.one_of(ODD_NUMBERS, st.sampled_from(["7", "", [], {}, [[1]], {"a": 1}]))


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder per module; each example overwrites its file (Hypothesis reruns the test body)."""
    return tmp_path_factory.mktemp("fuzz_scan_metadata")


# ------------------------------------------------------------------------------------------- breaking


def _break_json(draw: st.DrawFn, document: Any) -> Any:
    """The document with one value somewhere inside replaced by an odd one (overflow, wrong type, nesting)."""
    containers = [document]
    found: list[tuple[Any, Any]] = []
    while containers:
        container = containers.pop()
        keys = range(len(container)) if isinstance(container, list) else list(container)
        for key in keys:
            found.append((container, key))
            if isinstance(container[key], (list, dict)):
                containers.append(container[key])
    if not found:
        return document
    container, key = draw(st.sampled_from(found))
    container[key] = draw(st.one_of(st.just(NEST), ODD_VALUES))
    return document


NEST = "<nest>"  # replaced in the text by arrays nested deeper than json.dumps (or json.loads) can recurse


# Tokens the metadata readers' parsers may stumble on, beside breaking.broken_bytes' own ways.
JUNK = (b"99999999999999999999999", b"-", b"\n", b",", b"\t", b"[" * 3000, b"1e400", b"NaN", b'"', b"\xff\xfe")


def _maybe_broken_json(draw: st.DrawFn, document: Any) -> bytes:
    way = draw(st.sampled_from(["value", "bytes", "both", "valid"]))
    if way in ("value", "both"):
        document = _break_json(draw, document)
    depth = draw(st.sampled_from([100000, 2]))
    data = json.dumps(document).replace(json.dumps(NEST), "[" * depth + "0" + "]" * depth).encode("utf-8")
    return draw(broken_bytes(data, JUNK)) if way in ("bytes", "both") else data


def _maybe_broken_text(draw: st.DrawFn, lines: list[str]) -> bytes:
    """Lines joined; perhaps a line repeated, a field replaced by an odd token, and the bytes broken."""
    lines = list(lines)
    if lines and draw(st.booleans()):
        k = draw(st.integers(0, len(lines) - 1))
        lines.insert(k, lines[k])
    if lines and draw(st.integers(0, 3)) > 0:  # most examples: one field made odd
        k = draw(st.integers(0, len(lines) - 1))
        separator = "\t" if "\t" in lines[k] else ("," if "," in lines[k] else " ")
        fields = lines[k].split(separator)
        f = draw(st.integers(0, len(fields) - 1))
        fields[f] = str(draw(st.one_of(ODD_NUMBERS, st.sampled_from(["x", "", "0x1F", "-0", "١٢", "nan"]))))
        lines[k] = separator.join(fields)
    data = ("\n".join(lines) + "\n").encode("utf-8")
    return draw(broken_bytes(data, JUNK)) if draw(st.booleans()) else data


def _check(path: Path, data: bytes, read: Callable[[], Any]) -> Any:
    path.write_bytes(data)
    return result_or_one_line_error(read, SceneError, path.name)


# ------------------------------------------------------------------------------------------- readers


@st.composite
def replica_info(draw: st.DrawFn) -> bytes:
    classes = [{"id": c, "name": draw(NAMES)} for c in draw(st.lists(IDS, unique=True, max_size=5))]
    class_ids = [c["id"] for c in classes] + [-1]
    objects = [{"id": i, "class_id": draw(st.sampled_from(class_ids)), "class_name": draw(NAMES),
                "oriented_bbox": {"abb": {"center": [0, 0, 0], "sizes": [1, 1, 1]}}, "node_id": i}
               for i in draw(st.lists(IDS, unique=True, max_size=6))]
    document = {"classes": classes, "objects": objects, "id_to_label": [-2] + [o["class_id"] for o in objects],
                "gravity_dir": [0, 0, -1]}
    return _maybe_broken_json(draw, document)


@given(data=replica_info())
def test_replica_info(folder: Path, data: bytes) -> None:
    path = folder / "info_semantic.json"
    objects = _check(path, data, lambda: read_info(path))
    if objects is not None:
        assert all(0 < i <= 2**32 - 1 and o.object_id == i for i, o in objects.items())


SEGMENTS = np.array([11, 11, 18, 25, 25, 32, 39, 39], np.int64)  # segIndices of the 8-vertex mesh below


@pytest.fixture(scope="module")
def scannet_meshes(folder: Path) -> dict[str, Path]:
    """A ScanNet v2 and a ScanNet++ scene of one 8-vertex mesh (two quads, four triangles) with its segs file:
    only the aggregation changes between examples."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [3, 1, 0], [2, 1, 0]], np.float32)
    columns = {"x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2], "red": np.full(8, 200, np.uint8),
               "green": np.full(8, 100, np.uint8), "blue": np.full(8, 50, np.uint8)}
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    scannet = folder / "scans" / "scene0000_00"
    scannetpp = folder / "data" / "0a1b2c3d4e" / "scans"
    for mesh, segs in ((scannet / "scene0000_00_vh_clean_2.ply", scannet / "scene0000_00_vh_clean_2.0.010000.segs.json"),
                       (scannetpp / "mesh_aligned_0.05.ply", scannetpp / "segments.json")):
        mesh.parent.mkdir(parents=True)
        write_ply(mesh, columns, faces)
        segs.write_text(json.dumps({"segIndices": SEGMENTS.tolist()}), encoding="utf-8")
    return {"scannet": scannet / "scene0000_00_vh_clean_2.ply", "scannetpp": scannetpp / "mesh_aligned_0.05.ply"}


@st.composite
def aggregation(draw: st.DrawFn) -> bytes:
    pool = sorted(set(SEGMENTS.tolist()))
    groups = [{"id": k, "objectId": draw(IDS), "label": draw(NAMES),
               "segments": draw(st.lists(st.sampled_from(pool), max_size=3))} for k in range(draw(st.integers(0, 4)))]
    return _maybe_broken_json(draw, {"sceneId": "scannet.scene0000_00", "segGroups": groups})


@given(data=aggregation(), layout=st.sampled_from(["scannet", "scannetpp"]))
def test_scannet_aggregation(scannet_meshes: dict[str, Path], data: bytes, layout: str) -> None:
    mesh = scannet_meshes[layout]
    path = mesh.with_name("segments_anno.json" if layout == "scannetpp" else "scene0000_00.aggregation.json")
    scene = _check(path, data, lambda: read_scannet(mesh))
    if scene is not None:
        assert len(scene.face_object_ids) == 4 and set(scene.face_object_ids.tolist()) - {0} <= set(scene.objects)
        assert all(0 < i <= 2**32 - 1 for i in scene.objects)


@st.composite
def segs(draw: st.DrawFn) -> bytes:
    values = draw(st.lists(st.integers(0, 2**40), max_size=20))
    document = {"params": {"kThresh": "0.0001"}, "sceneId": "scene0000_00", "segIndices": values}
    if draw(st.booleans()):  # the fast path's shape: plain digits straight from the text
        document = {"sceneId": "scene0000_00", "segIndices": values}
    return _maybe_broken_json(draw, document)


@given(data=segs())
def test_scannet_segs(folder: Path, data: bytes) -> None:
    path = folder / "scene0000_00_vh_clean_2.0.010000.segs.json"
    values = _check(path, data, lambda: _segment_list(path))
    if values is not None:
        assert values.ndim == 1 and values.dtype == np.int64


@st.composite
def labels_tsv(draw: st.DrawFn) -> bytes:
    header = "id\traw_category\tcategory\tcount\tnyu40id\tmpcat40\tmpcat40index"
    rows = [f"{k}\t{draw(NAMES)}\tx\t1\t40\tmisc\t{draw(st.one_of(st.integers(0, 41), st.just(''), WIDE))}"
            for k in range(draw(st.integers(0, 5)))]
    return _maybe_broken_text(draw, [header, *rows])


@given(data=labels_tsv())
def test_scannet_labels_tsv(folder: Path, data: bytes) -> None:
    path = folder / "scannetv2-labels.combined.tsv"
    read_labels_tsv.cache_clear()  # the reader caches by path; each example rewrites the file
    table = _check(path, data, lambda: read_labels_tsv(path))
    if table is not None:
        assert all(0 <= index <= 41 for index in table.values())


@st.composite
def house_file(draw: st.DrawFn) -> bytes:
    categories = draw(st.lists(IDS, unique=True, min_size=1, max_size=4))
    objects = draw(st.lists(IDS, unique=True, min_size=1, max_size=4))
    lines = ["ASCII 1.1", "H  scan -  0 0 0 0 2 1 1 1 0 1  0 0 0 0 0  0 0 0 1 1 1  0 0 0 0 0",
             "R  0 0 0 0 b  0 0 0  0 0 0 1 1 1  2.5  0 0 0 0"]
    lines += [f"C  {c}  {c + 1} {draw(NAMES).replace(' ', '#') or '-'}  {draw(st.integers(0, 41))} chair  0 0 0 0 0"
              for c in categories]
    lines += [f"O  {o} {draw(st.one_of(st.sampled_from([-1, 0]), WIDE))} {draw(st.sampled_from([-1, *categories]))}  "
              "0 0 0  1 0 0  0 1 0  "
              "0.5 0.5 0.5  0 0 0 0 0 0 0 0" for o in objects]
    lines += [f"E  {k} {draw(st.sampled_from([-1, *objects]))} {1000000 * k + 7}  1  0 0 0  0 0 0 1 1 1  0 0 0 0 0"
              for k in range(draw(st.integers(1, 4)))]
    if draw(st.booleans()):
        lines.insert(draw(st.integers(1, len(lines))), "")  # blank lines, as habitat-sim skips
    return _maybe_broken_text(draw, lines)


@given(data=house_file())
def test_matterport_house(folder: Path, data: bytes) -> None:
    path = folder / "scan0000000.house"
    house = _check(path, data, lambda: read_house(path))
    if house is not None:  # what the tables can hold: uint32 object ids, int32 regions, mpcat40 0..41
        assert all(0 < i <= 2**32 - 1 and -1 <= o.region < 2**31 and 0 <= o.category <= 41
                   for i, o in house_objects(house).items())


@st.composite
def semantic_txt(draw: st.DrawFn) -> bytes:
    colors = draw(st.lists(st.integers(0, 0xFFFFFF), unique=True, max_size=5))
    lines = ["HM3D Semantic Annotations"] + [
        f'{k + 1},{color:06X},"{draw(NAMES).replace(chr(34), chr(34) * 2)}",{draw(st.one_of(st.integers(-1, 9), WIDE))}'
        for k, color in enumerate(colors)]
    return _maybe_broken_text(draw, lines)


@given(data=semantic_txt())
def test_hm3dsem_semantic_txt(folder: Path, data: bytes) -> None:
    path = folder / "00800-abc.semantic.txt"
    table = _check(path, data, lambda: read_semantic_table(path))
    if table is not None:
        assert all(0 <= color <= 0xFFFFFF and -1 <= region < 2**31 for color, (_, region) in table.items())
