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
"""

from __future__ import annotations

import csv
from functools import lru_cache
from pathlib import Path

import numpy as np

from pipeline.scenes.categories import category_of
from pipeline.scenes.ply import read_ply
from pipeline.scenes.scans import faces_from_vertex_labels, lookup, palette_vertex_colors, read_json, scan_scene
from pipeline.scenes.scene import Scene, SceneError, SceneObject

SCANNET_MESH = "_vh_clean_2.ply"
SCANNET_SEGS = "_vh_clean_2.0.010000.segs.json"
SCANNETPP_MESH = "mesh_aligned_0.05.ply"
LABELS_TSV = "scannetv2-labels.combined.tsv"


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
        rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines(), delimiter="\t"))
    except (OSError, UnicodeDecodeError) as error:
        raise SceneError(f"{path}: cannot read the label table ({error}); re-download it or drop scenes.scannet.labels_tsv") from None
    if rows and not {"raw_category", "mpcat40index"} <= set(rows[0]):
        raise SceneError(f"{path}: no raw_category / mpcat40index columns; give ScanNet's {LABELS_TSV}")
    return {row["raw_category"].strip().lower(): int(row["mpcat40index"]) for row in rows
            if (row.get("mpcat40index") or "").strip().lstrip("-").isdigit()}


def _vertex_segments(segs_path: Path, vertex_count: int) -> np.ndarray:
    segments = _segment_list(segs_path)
    if segments.ndim != 1 or len(segments) != vertex_count:
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
    if key >= 0 and 0 < start < end and text.count("{", key) == 0:
        body = text[start:end]
        values = np.fromstring(body, dtype=np.int64, sep=",") if body.strip() else np.zeros(0, np.int64)
        if len(values) == body.count(",") + 1 or (not body.strip() and len(values) == 0):
            return values
    segs = read_json(segs_path, "a ScanNet scene needs its over-segmentation beside the mesh")
    try:
        return np.asarray(segs["segIndices"], np.int64)
    except (KeyError, TypeError, ValueError, IndexError):
        raise SceneError(f"{segs_path}: no segIndices list of integers; re-download the scene") from None


def _groups(aggregation_path: Path) -> list[dict]:
    document = read_json(aggregation_path, "a ScanNet scene needs its aggregation beside the mesh")
    groups = document.get("segGroups") if isinstance(document, dict) else None
    if not isinstance(groups, list):
        raise SceneError(f"{aggregation_path}: no segGroups list; re-download the scene's annotations")
    return groups


def vertex_objects(segments: np.ndarray, groups: list[dict], segs_path: Path,
                   aggregation_path: Path) -> tuple[np.ndarray, dict[int, str]]:
    """(V,) object id (objectId + 1, 0 = none) of each vertex, and each object's raw name."""
    members, owners, names = [], [], {}
    for index, group in enumerate(groups):
        try:
            object_id, label, listed = int(group["objectId"]) + 1, str(group["label"]), [int(s) for s in group["segments"]]
        except (KeyError, TypeError, ValueError):
            raise SceneError(f"{aggregation_path}: segGroups[{index}] needs objectId, label and segments; "
                             "re-download the scene's annotations") from None
        members.append(np.array(listed, np.int64))
        owners.append(np.full(len(listed), object_id, np.int64))
        names[object_id] = label
    member_ids = np.concatenate(members) if members else np.zeros(0, np.int64)
    owner_ids = np.concatenate(owners) if owners else np.zeros(0, np.int64)
    held, _ = lookup(segments, segments, member_ids)
    if not held.all():
        stray = int(member_ids[~held][0])
        group = next(k for k, m in enumerate(members) if stray in m)
        raise SceneError(f"{aggregation_path}: segGroups[{group}].segments names segment {stray}, which "
                         f"{segs_path.name} (segIndices) does not hold; use the aggregation and segs files of one release")
    _, per_vertex = lookup(member_ids, owner_ids, segments)
    return per_vertex, names


def read_scannet(mesh_path: Path, up_axis: str = "z", labels_tsv: str = "") -> Scene:
    """Read a ScanNet v2 or ScanNet++ scene given its mesh (see module doc); raises SceneError naming the file."""
    mesh_path = Path(mesh_path)
    scene_id, segs_path, candidates = scene_files(mesh_path)
    aggregation_path = next((p for p in candidates if p.is_file()), None)
    if aggregation_path is None:
        raise SceneError(f"{candidates[0]}: missing; a ScanNet scene needs its aggregation beside the mesh")
    mesh = read_ply(mesh_path)
    segments = _vertex_segments(segs_path, len(mesh.vertex["x"]))
    per_vertex, names = vertex_objects(segments, _groups(aggregation_path), segs_path, aggregation_path)
    table = read_labels_tsv(Path(labels_tsv)) if labels_tsv else {}
    objects = {i: SceneObject(i, name, table.get(name.strip().lower()) or category_of(name)) for i, name in names.items()}
    face_ids = faces_from_vertex_labels(per_vertex, mesh.triangles)
    colors = mesh.vertex_colors()
    appearance = {"vertex_colors": colors if colors is not None else
                  palette_vertex_colors(len(per_vertex), mesh.triangles, face_ids)}
    return scan_scene(scene_id, "scannet", mesh_path, mesh.vertices, mesh.triangles, face_ids, objects, up_axis,
                      appearance, short_faces=mesh.short_polygons)
