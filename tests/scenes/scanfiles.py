"""Scan datasets as they are downloaded, written by the tests themselves at small size: a generated
two-room house stored in Matterport3D's, ScanNet v2's, ScanNet++'s and Replica's own file layouts
(binary little-endian PLY, Z up, metres, their JSON / .house records).

Each writer returns the scene folder; `expected_objects` says what a reader must find: for every
object of the house, its raw name, mpcat40 category and room.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.scenes.categories import raw_names
from pipeline.scenes.ply import write_ply
from pipeline.scenes.scans import to_world, up_axis_transform
from pipeline.scenes.scene import Scene


def file_vertices(scene: Scene) -> np.ndarray:
    """The scene's vertices in a +Z-up file frame (the exact inverse of the readers' rotation)."""
    return to_world(scene.vertices, np.round(np.linalg.inv(up_axis_transform("z"))))


def object_index(scene: Scene) -> dict[int, int]:
    """The house's object id -> 0-based index the datasets number instances with (sorted ids)."""
    return {object_id: k for k, object_id in enumerate(sorted(scene.objects))}


def instance_indices(scene: Scene, object_ids: np.ndarray) -> np.ndarray:
    """The 0-based dataset index (object_index) of each of the given house object ids, vectorised."""
    return np.searchsorted(np.array(sorted(scene.objects), np.int64), np.asarray(object_ids, np.int64))


def expected_objects(scene: Scene) -> list[tuple[str, int]]:
    """Sorted (raw name, mpcat40) of every object, what each reader must give back."""
    return sorted((o.raw_name, o.category) for o in scene.objects.values())


def _vertex_columns(vertices: np.ndarray, colors: np.ndarray, normals: bool = False, alpha: bool = False) -> dict:
    columns = {"x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2]}
    if normals:
        columns |= {"nx": np.zeros(len(vertices), np.float32), "ny": np.zeros(len(vertices), np.float32),
                    "nz": np.ones(len(vertices), np.float32)}
    columns |= {"red": colors[:, 0], "green": colors[:, 1], "blue": colors[:, 2]}
    if alpha:
        columns["alpha"] = np.full(len(vertices), 255, np.uint8)
    return columns


# ------------------------------------------------------------------------------------- Matterport3D


def write_matterport3d(scene: Scene, root: Path, scan: str) -> Path:
    """`<root>/<scan>/house_segmentations/<scan>.house` + `<scan>.ply` (two segments per object)."""
    folder = root / scan / "house_segmentations"
    folder.mkdir(parents=True)
    index = object_index(scene)
    names = sorted({o.raw_name for o in scene.objects.values()})
    category = {name: c for c, name in enumerate(names)}
    table_index = {r.raw_name: k + 1 for k, r in enumerate(raw_names())}
    lines = ["ASCII 1.1", f"H  {scan} -  0 0 0 0 {2 * len(index)} {len(index)} {len(names)} 2 0 1  0 0 0 0 0  "
             "0 0 0 1 1 1  0 0 0 0 0"]
    for name in names:
        obj = next(o for o in scene.objects.values() if o.raw_name == name)
        mpcat40 = obj.category_name.replace(" ", "#")
        lines.append(f"C  {category[name]}  {table_index.get(name, -1)} {name.replace(' ', '#')}  {obj.category} {mpcat40}  0 0 0 0 0")
    for object_id, k in index.items():
        obj = scene.objects[object_id]
        lines.append(f"O  {k} {obj.region} {category[obj.raw_name]}  0 0 0  1 0 0  0 1 0  0.5 0.5 0.5  0 0 0 0 0 0 0 0")
    for object_id, k in index.items():
        for half in (0, 1):
            lines.append(f"E  {2 * k + half} {k} {1000 + 2 * k + half}  1  0 0 0  0 0 0 1 1 1  0 0 0 0 0")
    (folder / f"{scan}.house").write_text("\n".join(lines) + "\n", encoding="utf-8")
    ids = scene.face_object_ids.astype(np.int64)
    k = instance_indices(scene, ids)
    # Each object's faces alternate between its two segments, so segments really group faces.
    segment = 1000 + 2 * k + (np.arange(len(ids)) % 2)
    vertices = file_vertices(scene)
    columns = _vertex_columns(vertices, scene.vertex_colors, normals=True)
    columns = {**{c: columns[c] for c in ("x", "y", "z", "nx", "ny", "nz")},
               "tx": np.zeros(len(vertices), np.float32), "ty": np.zeros(len(vertices), np.float32),
               **{c: columns[c] for c in ("red", "green", "blue")}}
    write_ply(folder / f"{scan}.ply", columns, scene.faces,
              {"material_id": segment.astype(np.int32), "segment_id": k.astype(np.int32),
               "category_id": np.array([category[scene.objects[i].raw_name] for i in sorted(index)], np.int32)[k]})
    return folder / f"{scan}.house"


def write_matterport_textured_mesh(scene: Scene, root: Path, scan: str) -> Path:
    """`<root>/<scan>/matterport_mesh/<uuid>/<uuid>.obj` + .mtl + a JPEG texture (a colour ramp over the faces)."""
    import cv2

    folder = root / scan / "matterport_mesh" / "a1b2c3d4e5f6"
    folder.mkdir(parents=True)
    ramp = np.zeros((16, 64, 3), np.uint8)
    ramp[..., 0] = np.linspace(20, 235, 64, dtype=np.uint8)[None, :]
    ramp[..., 2] = 180
    cv2.imwrite(str(folder / "a1b2c3d4e5f6_000.jpg"), cv2.cvtColor(ramp, cv2.COLOR_RGB2BGR))
    (folder / "a1b2c3d4e5f6.mtl").write_text("newmtl mesh_000\nKd 1 1 1\nmap_Kd a1b2c3d4e5f6_000.jpg\n", encoding="utf-8")
    vertices = file_vertices(scene)
    u = (vertices[:, 0] - vertices[:, 0].min()) / max(float(np.ptp(vertices[:, 0])), 1e-6)
    lines = ["mtllib a1b2c3d4e5f6.mtl"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"vt {value:.6f} 0.5" for value in u]
    lines.append("usemtl mesh_000")
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in scene.faces + 1]
    path = folder / "a1b2c3d4e5f6.obj"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


# ------------------------------------------------------------------------------------- ScanNet, ScanNet++


def _vertex_labelled(scene: Scene, unshare: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, colours, triangles and per-vertex object ids. ScanNet labels vertices, so with `unshare`
    no vertex is shared by two objects (exact labels); without it (a real scan's vertex count, for the
    benchmark) a shared vertex takes the object of the last face using it."""
    if not unshare:
        vertex_ids = np.zeros(len(scene.vertices), np.int64)
        vertex_ids[scene.faces.reshape(-1)] = np.repeat(scene.face_object_ids.astype(np.int64), 3)
        return file_vertices(scene), scene.vertex_colors, scene.faces, vertex_ids
    flat = scene.faces.reshape(-1)
    vertex_ids = np.repeat(scene.face_object_ids.astype(np.int64), 3)
    return (file_vertices(scene)[flat], scene.vertex_colors[flat], np.arange(len(flat)).reshape(-1, 3), vertex_ids)


def _segments_and_groups(scene: Scene, vertex_ids: np.ndarray) -> tuple[list[int], list[dict]]:
    """Per-vertex segment ids (two segments per object, ScanNet-style large ids) and the segGroups."""
    index = object_index(scene)
    k = instance_indices(scene, vertex_ids)
    segment = 7 * (2 * k + (np.arange(len(k)) // 3 % 2)) + 11
    groups = [{"id": k_, "objectId": k_, "segments": sorted({7 * (2 * k_) + 11, 7 * (2 * k_ + 1) + 11} & set(segment.tolist())),
               "label": scene.objects[object_id].raw_name} for object_id, k_ in index.items()]
    return segment.tolist(), groups


def write_scannet(scene: Scene, root: Path, scene_id: str, unshare: bool = True) -> Path:
    """`<root>/scans/<scene>/` with `_vh_clean_2.ply`, `_vh_clean_2.0.010000.segs.json`, `.aggregation.json`."""
    folder = root / "scans" / scene_id
    folder.mkdir(parents=True)
    vertices, colors, faces, vertex_ids = _vertex_labelled(scene, unshare)
    segments, groups = _segments_and_groups(scene, vertex_ids)
    mesh = write_ply(folder / f"{scene_id}_vh_clean_2.ply", _vertex_columns(vertices, colors, alpha=True), faces)
    (folder / f"{scene_id}_vh_clean_2.0.010000.segs.json").write_text(json.dumps(
        {"params": {"kThresh": "0.0001", "segMinVerts": "20"}, "sceneId": scene_id, "segIndices": segments}), encoding="utf-8")
    (folder / f"{scene_id}.aggregation.json").write_text(json.dumps(
        {"sceneId": f"scannet.{scene_id}", "appId": "Aggregator.v2", "segGroups": groups,
         "segmentsFile": f"scannet.{scene_id}_vh_clean_2.0.010000.segs.json"}), encoding="utf-8")
    return mesh


def write_labels_tsv(root: Path, names: dict[str, int]) -> Path:
    """ScanNet's `scannetv2-labels.combined.tsv` (its columns; rows for the given raw name -> mpcat40 index)."""
    header = ["id", "raw_category", "category", "count", "nyu40id", "eigen13id", "nyuClass", "nyu40class", "eigen13class",
              "ModelNet40", "ModelNet10", "ShapeNetCore55", "synsetoffset", "wnsynsetid", "wnsynsetkey", "mpcat40", "mpcat40index"]
    rows = ["\t".join(header)]
    for k, (name, index) in enumerate(sorted(names.items()), start=1):
        rows.append("\t".join([str(k), name, name, "1", "40", "13", name, "otherprop", "Other", "", "", "", "", "", "",
                               "misc" if index == 40 else name, str(index)]))
    path = root / "scannetv2-labels.combined.tsv"
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def write_scannetpp(scene: Scene, root: Path, scene_id: str, unshare: bool = True) -> Path:
    """`<root>/data/<scene>/scans/` with `mesh_aligned_0.05.ply`, `segments.json`, `segments_anno.json`."""
    folder = root / "data" / scene_id / "scans"
    folder.mkdir(parents=True)
    vertices, colors, faces, vertex_ids = _vertex_labelled(scene, unshare)
    segments, groups = _segments_and_groups(scene, vertex_ids)
    mesh = write_ply(folder / "mesh_aligned_0.05.ply", _vertex_columns(vertices, colors), faces)
    (folder / "segments.json").write_text(json.dumps({"sceneId": scene_id, "segIndices": segments}), encoding="utf-8")
    (folder / "segments_anno.json").write_text(json.dumps({"sceneId": scene_id, "segGroups": groups}), encoding="utf-8")
    return mesh


# ------------------------------------------------------------------------------------------- Replica


def quads_of(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(Q, 4) quads and their object ids: a triangle (a, b, c) whose neighbour of the same object across
    its edge c-a is (a, c, d) becomes the quad (a, b, c, d) (fanned back into those two triangles);
    a triangle without one is written (a, b, c, c)."""
    faces, ids = scene.faces.tolist(), scene.face_object_ids.tolist()
    owner = {(u, v): i for i, (a, b, c) in enumerate(faces) for u, v in ((a, b), (b, c), (c, a))}
    used = [False] * len(faces)
    quads, quad_ids = [], []
    for i, (a, b, c) in enumerate(faces):
        if used[i]:
            continue
        used[i] = True
        quad = (a, b, c, c)
        for p, q, r in ((a, b, c), (b, c, a), (c, a, b)):
            j = owner.get((p, r))  # the neighbour across edge r-p runs p -> r
            if j is not None and not used[j] and ids[j] == ids[i]:
                used[j] = True
                quad = (p, q, r, next(v for v in faces[j] if v not in (p, r)))
                break
        quads.append(quad)
        quad_ids.append(ids[i])
    return np.array(quads, np.int64), np.array(quad_ids, np.int64)


def write_replica(scene: Scene, root: Path, name: str, first_id: int = 0) -> Path:
    """`<root>/<name>/mesh.ply` (coloured quads), `habitat/mesh_semantic.ply` (quads + object_id) and
    `habitat/info_semantic.json`; instance ids are first_id + the object's index."""
    folder = root / name / "habitat"
    folder.mkdir(parents=True)
    index = object_index(scene)
    quads, quad_ids = quads_of(scene)
    names = sorted({o.raw_name for o in scene.objects.values()})
    classes = [{"id": c + 1, "name": n} for c, n in enumerate(names)]
    class_of = {n: c + 1 for c, n in enumerate(names)}
    objects = [{"id": first_id + k, "class_id": class_of[scene.objects[object_id].raw_name],
                "class_name": scene.objects[object_id].raw_name, "oriented_bbox": {}} for object_id, k in index.items()]
    (folder / "info_semantic.json").write_text(json.dumps(
        {"classes": classes, "objects": objects, "id_to_label": [o["class_id"] for o in objects]}), encoding="utf-8")
    columns = _vertex_columns(file_vertices(scene), scene.vertex_colors, normals=True)
    write_ply(root / name / "mesh.ply", columns, quads)
    object_ids = (first_id + instance_indices(scene, quad_ids)).astype(np.int32)
    return write_ply(folder / "mesh_semantic.ply", columns, quads, {"object_id": object_ids})


# Names published Replica files give instances of class_id -1 (the three scenes: 2 to 22 per scene).
CLASSLESS_NAMES = ("undefined", "non-plane", "anonymize_picture", "anonymize_text")


def _oriented_box(vertices: np.ndarray) -> dict:
    """An `oriented_bbox` as published files write it: an axis box in the box frame, and that frame."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    return {"abb": {"center": ((low + high) / 2).tolist(), "sizes": (high - low).tolist()},
            "orientation": {"rotation": [0.0, 0.0, 0.0, 1.0], "translation": [0.0, 0.0, 0.0]}}


def classless_objects(scene: Scene, count: int = 4) -> dict[int, str]:
    """House object id -> a class -1 name, for the `count` largest objects that are not floors (so walks
    still find a labelled floor), cycling through CLASSLESS_NAMES."""
    sizes = np.bincount(scene.face_object_ids.astype(np.int64), minlength=max(scene.objects) + 1)
    candidates = sorted((i for i in scene.objects if scene.objects[i].category != 2), key=lambda i: (-sizes[i], i))
    return {object_id: CLASSLESS_NAMES[k % len(CLASSLESS_NAMES)] for k, object_id in enumerate(candidates[:count])}


def write_published_replica(scene: Scene, root: Path, name: str, classless: dict[int, str]) -> Path:
    """`write_replica` with `info_semantic.json` in the shape of the published files: the `classless`
    house objects have class_id -1 and their own class_name; `id_to_label` is indexed by instance id
    with [0] = -2 and lists ids no face uses; two such unused instances (one of class -1) are listed
    too; every object has a `node_id` and an oriented box; `gravity_dir` is given."""
    semantic = write_replica(scene, root, name, first_id=1)  # published ids start at 1: id_to_label[0] is -2
    info_path = semantic.with_name("info_semantic.json")
    info = json.loads(info_path.read_text(encoding="utf-8"))
    vertices = file_vertices(scene)
    index = object_index(scene)
    by_replica_id = {1 + k: object_id for object_id, k in index.items()}
    for entry in info["objects"]:
        object_id = by_replica_id[entry["id"]]
        entry["node_id"] = 1000 + entry["id"]
        entry["oriented_bbox"] = _oriented_box(vertices[scene.faces[scene.face_object_ids == object_id].reshape(-1)])
        if object_id in classless:
            entry["class_id"], entry["class_name"] = -1, classless[object_id]
    unused = len(index) + 4
    info["objects"] += [
        {"id": unused, "class_id": info["classes"][0]["id"], "class_name": info["classes"][0]["name"], "node_id": 9,
         "oriented_bbox": _oriented_box(vertices[:3])},
        {"id": unused + 2, "class_id": -1, "class_name": "undefined", "node_id": 11, "oriented_bbox": _oriented_box(vertices[:3])},
    ]
    labels = [-2] * (unused + 3)
    for entry in info["objects"]:
        labels[entry["id"]] = entry["class_id"]
    info["id_to_label"] = labels
    info["gravity_dir"] = [0.0, 0.0, -1.0]
    info_path.write_text(json.dumps(info, indent=2), encoding="utf-8")
    return semantic
