"""ScanNet v2 and ScanNet++ scenes as downloaded: a vertex-coloured mesh, its over-segmentation and the
aggregation of segments into named objects.

The formats this reader trusts (ScanNet/ScanNet README and BenchmarkScripts/util_3d.py;
scannetpp/scannetpp common/scene_release.py and common/utils/anno.py):

    ScanNet v2   <scene>/<scene>_vh_clean_2.ply             binary PLY, Z up, metres; vertex x y z red green
                                                            blue alpha; face vertex_indices (triangles)
                 <scene>/<scene>_vh_clean_2.0.010000.segs.json  {"segIndices": [segment id of each vertex]}
                 <scene>/<scene>.aggregation.json (or <scene>_vh_clean.aggregation.json)
                                                            {"segGroups": [{"id", "objectId", "segments": [...],
                                                            "label": raw name}]}
                 scannetv2-labels.combined.tsv (task data)  tab-separated; raw_category -> mpcat40index
    ScanNet++    <scene>/scans/mesh_aligned_0.05.ply        binary PLY, Z up, metres, vertex colours
                 <scene>/scans/segments.json                {"segIndices": [...]} as above
                 <scene>/scans/segments_anno.json           {"segGroups": [...]} as above

A vertex belongs to the object whose segGroup lists its segment; a face takes the object two of its
corners share (else its first corner's). Object id = objectId + 1 (vertices of no group are void),
name = label, category = the TSV's mpcat40index for the raw name when the download holds the TSV, else
(and for names the TSV lacks) our raw-name table. A segGroup naming a segment the segs file lacks, or a
segs file whose length is not the mesh's vertex count, fails the scene with one line naming both.

An aggregation whose `segmentsFile` names another segs file (the hi-res `_vh_clean.aggregation.json`)
fails; segment ids written as decimal strings are read, null ones skipped (as ScanNet's Aggregation.h).
Repeats (schemas/scan_sources.md): objectIds must be 0 .. 2^32 - 2 and unique (a repeat fails naming
both groups); a group repeating an earlier group's label and segments is dropped with one warning
(scene0217_00); a segment in two groups fails (ScanNet v2) or goes to the smallest group (ScanNet++,
whose annotations are multi-label), with one warning.
"""

from __future__ import annotations

import csv
import logging
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from pipeline.scenes.categories import category_of
from pipeline.scenes.ply import read_ply
from pipeline.scenes.scans import (faces_from_vertex_labels, first_repeat, instance_id, integer_field, lookup,
                                   palette_vertex_colors, read_json, scan_scene)
from pipeline.scenes.scene import Scene, SceneError, SceneObject

SCANNET_MESH = "_vh_clean_2.ply"
SCANNET_SEGS = "_vh_clean_2.0.010000.segs.json"
SCANNETPP_MESH = "mesh_aligned_0.05.ply"
LABELS_TSV = "scannetv2-labels.combined.tsv"
MPCAT40_LAST = 41  # mpcat40.tsv's indices run 0 (void) .. 41 (unlabeled)
INT64_MIN, INT64_MAX = -2**63, 2**63 - 1
LOG = logging.getLogger(__name__)


def scene_files(mesh: Path) -> tuple[str, Path, list[Path]]:
    """(scene id, segs file, aggregation candidates in order of preference) of a ScanNet or ScanNet++ mesh."""
    if mesh.name == SCANNETPP_MESH:
        return mesh.parent.parent.name, mesh.with_name("segments.json"), [mesh.with_name("segments_anno.json")]
    scene_id = mesh.name[: -len(SCANNET_MESH)]
    return scene_id, mesh.with_name(scene_id + SCANNET_SEGS), [mesh.with_name(f"{scene_id}.aggregation.json"),
                                                               mesh.with_name(f"{scene_id}_vh_clean.aggregation.json")]


@lru_cache(maxsize=4)
def read_labels_tsv(path: Path) -> dict[str, int]:
    """raw_category -> mpcat40index from ScanNet's scannetv2-labels.combined.tsv (rows without an index skipped)."""
    try:
        text = path.read_bytes().decode("utf-8-sig")
        rows = list(csv.DictReader(text.splitlines(), delimiter="\t"))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise SceneError(f"{path}: cannot read the label table ({type(error).__name__}); re-download it or drop "
                         "scenes.scannet.labels_tsv") from None
    if rows and not {"raw_category", "mpcat40index"} <= set(rows[0]):
        raise SceneError(f"{path}: no raw_category / mpcat40index columns; give ScanNet's {LABELS_TSV}")
    table = {}
    for number, row in enumerate(rows, start=2):  # line 1 is the header
        index, name = (row.get("mpcat40index") or "").strip(), row.get("raw_category")
        if not index or name is None:  # a row without an mpcat40 index (or cut short) maps nothing
            continue
        if not (index.isascii() and index.isdigit()) or int(index) > MPCAT40_LAST:
            raise SceneError(f"{path}:{number}: mpcat40index {index[:20]!r} is not an mpcat40 index 0..{MPCAT40_LAST}; "
                             f"re-download {LABELS_TSV}")
        table[name.strip().lower()] = int(index)
    return table


def _vertex_segments(segs_path: Path, vertex_count: int) -> np.ndarray:
    segments = _segment_list(segs_path)
    if len(segments) != vertex_count:
        raise SceneError(f"{segs_path}: segIndices has {segments.size} entries but the mesh has {vertex_count} "
                         "vertices (one per vertex); use the segs file of this mesh")
    return segments


def _segment_list(segs_path: Path) -> np.ndarray:
    """The `segIndices` list of a segs file. Its digits are parsed by numpy straight from the text (a
    fifth of what the json module takes on a million ids); anything unusual goes through json."""
    if not segs_path.is_file():
        raise SceneError(f"{segs_path}: missing; a ScanNet scene needs its over-segmentation beside the mesh")
    text = segs_path.read_text(encoding="utf-8", errors="replace")
    key = text.find('"segIndices"')
    start = text.find("[", key) + 1
    end = text.find("]", start)
    body = text[start:end]
    if key >= 0 and 0 < start < end and text.count("{", key) == 0:
        values = _parsed_integers(body)
        if values is not None:
            return values
    segs = read_json(segs_path, "a ScanNet scene needs its over-segmentation beside the mesh")
    values = segs.get("segIndices") if isinstance(segs, dict) else None
    if not isinstance(values, list):
        raise SceneError(f"{segs_path}: no segIndices list; re-download the scene")
    if not all(type(v) is int and INT64_MIN <= v <= INT64_MAX for v in values):  # each entry checked, not the first odd one
        values = [integer_field(v, f"{segs_path}:segIndices[{k}]", INT64_MIN, INT64_MAX) for k, v in enumerate(values)]
    return np.array(values, np.int64)


def _parsed_integers(body: str) -> np.ndarray | None:
    """numpy's parse of comma-separated integers, or None where json must decide: text numpy stops on
    (a fraction, a word, a nested list) and numbers at int64's ends (numpy saturates on overflow)."""
    if not body.strip():
        return np.zeros(0, np.int64)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # numpy warns, then errs, on text it cannot finish
        try:
            values = np.fromstring(body, dtype=np.int64, sep=",")
        except (ValueError, DeprecationWarning):
            return None
    if len(values) != body.count(",") + 1 or (len(values) and (values.max() == INT64_MAX or values.min() == INT64_MIN)):
        return None
    return values


@dataclass
class SegGroup:
    """One `segGroups` entry: its position in the file, object id (objectId + 1), raw name and segments."""

    index: int
    object_id: int
    label: str
    segments: np.ndarray


def read_groups(aggregation_path: Path, segs_name: str | None = None) -> list[SegGroup]:
    """The aggregation's segGroups, each checked: objectId an instance id, label a string, segments integers.

    With `segs_name`, an aggregation whose `segmentsFile` names another segs file fails: ScanNet's
    `<scene>_vh_clean.aggregation.json` refers to the hi-res mesh's `_vh_clean.segs.json`, and its segment
    ids would label the `_vh_clean_2` mesh wrongly (ScanNet's AnnotationTools/common/Aggregation.h writes
    `segmentsFile` = sceneId + "_vh_clean_2.0.010000.segs.json" for the annotated mesh)."""
    document = read_json(aggregation_path, "a ScanNet scene needs its aggregation beside the mesh")
    groups = document.get("segGroups") if isinstance(document, dict) else None
    if not isinstance(groups, list):
        raise SceneError(f"{aggregation_path}: no segGroups list; re-download the scene's annotations")
    named = document.get("segmentsFile")
    if segs_name is not None and isinstance(named, str) and not named.endswith(segs_name):
        raise SceneError(f"{aggregation_path}:segmentsFile: refers to {named[-80:]!r}, not {segs_name} beside the mesh; "
                         "use the aggregation of this mesh (<scene>.aggregation.json for _vh_clean_2.ply)")
    return [_seg_group(aggregation_path, index, group) for index, group in enumerate(groups)]


def _seg_group(path: Path, index: int, group: object) -> SegGroup:
    where = f"{path}:segGroups[{index}]"
    if not isinstance(group, dict):
        raise SceneError(f"{where}: expected {{objectId, label, segments}}, got {type(group).__name__}; "
                         "re-download the scene's annotations")
    object_id = instance_id(group.get("objectId"), f"{where}.objectId") + 1
    label, segments = group.get("label"), group.get("segments")
    if not isinstance(label, str):
        raise SceneError(f"{where}.label: expected a string, got {type(label).__name__}; re-download the scene's annotations")
    if not isinstance(segments, list):
        raise SceneError(f"{where}.segments: expected a list of segment ids, got {type(segments).__name__}; "
                         "re-download the scene's annotations")
    return SegGroup(index, object_id, label, np.unique(np.array(_segment_ids(segments, where), np.int64)))


def _segment_ids(segments: list, where: str) -> list[int]:
    """A group's segment ids. As ScanNet's own reader (AnnotationTools/common/Aggregation.h, getUINT) does, a
    decimal string is read as its number and null is skipped (it becomes a segment no vertex has); anything
    else that is not an int64 fails naming the entry."""
    if all(type(v) is int and INT64_MIN <= v <= INT64_MAX for v in segments):
        return segments
    ids = []
    for k, value in enumerate(segments):
        if value is None:
            continue
        if isinstance(value, str) and value.isascii() and value.isdigit():
            value = int(value)
        ids.append(integer_field(value, f"{where}.segments[{k}]", INT64_MIN, INT64_MAX))
    return ids


def distinct_groups(groups: list[SegGroup], path: Path) -> list[SegGroup]:
    """The groups without exact repeats (a later group with the same label and segments as an earlier one,
    as scene0217_00's aggregation lists every object twice: ScanNet/ScanNet issue #51), one warning for
    all; then a repeated objectId fails naming both entries (a dict keyed by it would keep the last)."""
    seen: dict[tuple[str, bytes], int] = {}
    kept, repeats = [], []
    for group in groups:
        key = (group.label, group.segments.tobytes())
        if key in seen:
            repeats.append((group.index, seen[key]))
            continue
        seen[key] = group.index
        kept.append(group)
    if repeats:
        LOG.warning("%s: %d segGroups repeat an earlier group's label and segments (e.g. segGroups[%d] = segGroups[%d]); "
                    "the repeats are dropped", path, len(repeats), *repeats[0])
    repeat = first_repeat([group.object_id for group in kept])
    if repeat is not None:
        first, second = kept[repeat[0]], kept[repeat[1]]
        raise SceneError(f"{path}:segGroups[{second.index}].objectId: {second.object_id - 1} is also "
                         f"segGroups[{first.index}].objectId ({first.label!r} and {second.label!r}); give each object "
                         "its own objectId")
    return kept


def vertex_objects(segments: np.ndarray, groups: list[SegGroup], segs_path: Path, aggregation_path: Path,
                   overlap: str = "refuse") -> tuple[np.ndarray, dict[int, str]]:
    """(V,) object id (objectId + 1, 0 = none) of each vertex, and each object's raw name.

    Args:
        overlap: a segment listed by two groups: "refuse" (ScanNet v2: fails naming both groups) or
            "smallest" (ScanNet++: the group with the fewest vertices holds it, as scannetpp's
            semantic/transforms/mesh.py keeps the smallest instance of a multi-labelled vertex).
    """
    groups = distinct_groups(groups, aggregation_path)
    member_ids = np.concatenate([g.segments for g in groups]) if groups else np.zeros(0, np.int64)
    owner = np.concatenate([np.full(len(g.segments), k) for k, g in enumerate(groups)]) if groups else np.zeros(0, np.int64)
    held, _ = lookup(segments, segments, member_ids)
    if not held.all():
        stray = int(member_ids[~held][0])
        group = groups[int(owner[~held][0])]
        raise SceneError(f"{aggregation_path}:segGroups[{group.index}].segments: names segment {stray}, which "
                         f"{segs_path.name} (segIndices) does not hold; use the aggregation and segs files of one release")
    member_ids, owner = _one_owner_per_segment(member_ids, owner, groups, segments, aggregation_path, overlap)
    object_ids = np.array([g.object_id for g in groups], np.int64)[owner] if groups else np.zeros(0, np.int64)
    _, per_vertex = lookup(member_ids, object_ids, segments)
    return per_vertex, {g.object_id: g.label for g in groups}


def _one_owner_per_segment(member_ids: np.ndarray, owner: np.ndarray, groups: list[SegGroup], segments: np.ndarray,
                           path: Path, overlap: str) -> tuple[np.ndarray, np.ndarray]:
    """(segment, group) pairs where each segment has one group; see vertex_objects for the two rules."""
    if overlap == "smallest":
        segment_ids, vertex_counts = np.unique(segments, return_counts=True)
        _, counts = lookup(segment_ids, vertex_counts, member_ids)
        size = np.bincount(owner, weights=counts, minlength=len(groups))[owner]
        order = np.lexsort((owner, size, member_ids))  # per segment: smallest group first, then the first listed
    else:
        order = np.lexsort((owner, member_ids))
    member_ids, owner = member_ids[order], owner[order]
    first = np.ones(len(member_ids), bool)
    first[1:] = member_ids[1:] != member_ids[:-1]
    if not first.all():
        again = int(np.flatnonzero(~first)[0])
        one, other = groups[int(owner[again - 1])], groups[int(owner[again])]
        if overlap != "smallest":
            raise SceneError(f"{path}:segGroups[{other.index}].segments: segment {int(member_ids[again])} is also in "
                             f"segGroups[{one.index}] ({one.label!r} and {other.label!r}); a segment belongs to one object: "
                             "fix the aggregation")
        LOG.warning("%s: %d segments are listed by more than one segGroup (e.g. %d in segGroups[%d] and [%d]); each "
                    "goes to its smallest group", path, int((~first).sum()), int(member_ids[again]), one.index, other.index)
    return member_ids[first], owner[first]


def read_scannet(mesh_path: Path, up_axis: str = "z", labels_tsv: str = "") -> Scene:
    """Read a ScanNet v2 or ScanNet++ scene given its mesh (see module doc); raises SceneError naming the file."""
    mesh_path = Path(mesh_path)
    scene_id, segs_path, candidates = scene_files(mesh_path)
    aggregation_path = next((p for p in candidates if p.is_file()), None)
    if aggregation_path is None:
        raise SceneError(f"{candidates[0]}: missing; a ScanNet scene needs its aggregation beside the mesh")
    mesh = read_ply(mesh_path)
    segments = _vertex_segments(segs_path, len(mesh.vertex["x"]))
    overlap = "smallest" if mesh_path.name == SCANNETPP_MESH else "refuse"
    groups = read_groups(aggregation_path, None if mesh_path.name == SCANNETPP_MESH else segs_path.name)
    per_vertex, names = vertex_objects(segments, groups, segs_path, aggregation_path, overlap)
    table = read_labels_tsv(Path(labels_tsv)) if labels_tsv else {}
    objects = {i: SceneObject(i, name, table.get(name.strip().lower()) or category_of(name)) for i, name in names.items()}
    face_ids = faces_from_vertex_labels(per_vertex, mesh.triangles)
    colors = mesh.vertex_colors()
    appearance = {"vertex_colors": colors if colors is not None else
                  palette_vertex_colors(len(per_vertex), mesh.triangles, face_ids)}
    return scan_scene(scene_id, "scannet", mesh_path, mesh.vertices, mesh.triangles, face_ids, objects, up_axis,
                      appearance, short_faces=mesh.short_polygons)
