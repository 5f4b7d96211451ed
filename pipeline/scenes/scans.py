"""What the scan dataset readers share (matterport3d.py, scannet.py, replica.py): labels moved between
meshes and from vertices to faces, the object table joined once, and the Scene assembled.

Every reader turns its dataset's own files into (vertices, triangles, per-face object ids, objects,
colours) in the file's frame and hands them to `scan_scene`, which drops degenerate faces, keeps the
objects that label a face, and rotates into the world (+Y up) recording the transform.
Object ids are the dataset's own instance ids + 1, so 0 stays void and ids stay stable across videos.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.scenes.scene import Scene, SceneError, SceneObject

LOG = logging.getLogger(__name__)


def up_axis_transform(up_axis: str) -> np.ndarray:
    """4x4 transform from a file frame with the given up axis into the world (+Y up)."""
    if up_axis == "y":
        return np.eye(4)
    if up_axis == "z":
        return np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
    raise SceneError(f"up_axis {up_axis!r}: use 'y' or 'z'")


def to_world(vertices: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (V, 3) float32 vertices; exact for axis permutations."""
    if np.array_equal(transform, np.eye(4)):
        return vertices
    rotation = transform[:3, :3]
    if np.all(np.isin(rotation, (-1.0, 0.0, 1.0))) and not transform[:3, 3].any():
        # A signed permutation: move columns instead of multiplying, so no rounding happens.
        columns = [np.argmax(np.abs(row)) for row in rotation]
        return np.stack([rotation[i, c] * vertices[:, c] for i, c in enumerate(columns)], 1).astype(np.float32)
    return (vertices.astype(np.float64) @ rotation.T + transform[:3, 3]).astype(np.float32)


# objects.object_id = instance id + 1 is the panoptic id of a pixel, a uint32 (DESIGN.md), and 0 is void:
# a dataset's instance ids must lie in 0 .. 2^32 - 2. Larger ids are refused, never wrapped.
MAX_INSTANCE_ID = 2**32 - 2


def read_json(path: Path, what: str) -> Any:
    """A dataset's JSON file; SceneError naming the file when it is missing or not JSON.

    Nesting deep enough to exhaust Python's recursion (a corrupt or hostile file) is refused the same way."""
    if not path.is_file():
        raise SceneError(f"{path}: missing; {what}")
    try:
        return json.loads(path.read_bytes().decode("utf-8-sig"))  # a byte-order mark (Windows tools) is not JSON
    except UnicodeDecodeError as error:
        raise SceneError(f"{path}: not UTF-8 text (byte {error.start}); re-download the file") from None
    except json.JSONDecodeError as error:
        raise SceneError(f"{path}:{error.lineno}: not valid JSON ({error.msg}, column {error.colno}); "
                         "re-download the file") from None
    except RecursionError:
        raise SceneError(f"{path}: JSON nested too deeply to be a dataset file; re-download the file") from None


def integer_field(value: Any, where: str, low: int, high: int) -> int:
    """`value` as an int in [low, high]; SceneError naming `where` (`<file>:<field>`) otherwise.

    JSON integers written as floats (3.0) are accepted; fractions, booleans, strings and ids outside the
    range are refused rather than truncated or wrapped."""
    number = int(value) if isinstance(value, float) and value.is_integer() else value
    if isinstance(number, bool) or not isinstance(number, int):
        raise SceneError(f"{where}: {_shown(value)} is not an integer; fix the file or re-download it")
    if not low <= number <= high:
        raise SceneError(f"{where}: {_shown(value)} is outside {low}..{high}; fix the file or re-download it")
    return number


def instance_id(value: Any, where: str) -> int:
    """A dataset instance id that fits objects.object_id = id + 1 (uint32): 0 .. 2^32 - 2, else SceneError."""
    if isinstance(value, int) and not isinstance(value, bool) and not 0 <= value <= MAX_INSTANCE_ID:
        raise SceneError(f"{where}: instance id {_shown(value)} is outside 0..{MAX_INSTANCE_ID} (object id = instance id "
                         "+ 1 is a uint32 panoptic id); renumber the instances")
    return integer_field(value, where, 0, MAX_INSTANCE_ID)


def _shown(value: Any) -> str:
    """A short repr of a value for a one-line message."""
    text = repr(value)  # repr escapes newlines: the message stays one line
    return text if len(text) <= 40 else text[:37] + "..."


def first_repeat(keys: list[Any]) -> tuple[int, int] | None:
    """(first index, repeating index) of the first key that occurs twice in `keys`, or None."""
    seen: dict[Any, int] = {}
    for index, key in enumerate(keys):
        if key in seen:
            return seen[key], index
        seen[key] = index
    return None


def faces_from_vertex_labels(vertex_labels: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) label of each face from its corners' labels: the label two corners share, else the first's."""
    a, b, c = (vertex_labels[faces[:, k]] for k in range(3))
    return np.where(b == c, b, a)


def transfer_face_labels(source_vertices: np.ndarray, source_faces: np.ndarray, labels: np.ndarray,
                         target_vertices: np.ndarray, target_faces: np.ndarray) -> np.ndarray:
    """Labels of the source mesh's faces on the target mesh's faces: copied when both meshes have the
    same triangles, else each target face takes the label of the nearest source face that faces the
    same way (centre distance, plus NORMAL_WEIGHT metres per unit of normal difference: the two sides
    of a thin wall or a rug on a floor share centres and differ only in their normals)."""
    if np.array_equal(source_faces, target_faces) and np.array_equal(source_vertices, target_vertices):
        return labels
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(_oriented_centres(source_vertices, source_faces)).query(
        _oriented_centres(target_vertices, target_faces))
    return labels[nearest]


NORMAL_WEIGHT = 0.05


def _oriented_centres(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 6) face centre and NORMAL_WEIGHT x unit normal (zero for degenerate faces)."""
    corners = np.asarray(vertices, np.float64)[faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    return np.concatenate([corners.mean(axis=1), NORMAL_WEIGHT * normal], axis=1)


def palette_color(object_id: int) -> np.ndarray:
    """A stable, distinct-looking colour per object id (golden-ratio hue steps)."""
    import colorsys

    hue = (object_id * 0.618033988749895) % 1.0
    return np.round(np.array(colorsys.hsv_to_rgb(hue, 0.55, 0.9)) * 255).astype(np.uint8)


def palette_vertex_colors(vertex_count: int, faces: np.ndarray, face_ids: np.ndarray) -> np.ndarray:
    """(V, 3) a palette colour per object painted on its faces' corners (for meshes without colours)."""
    colors = np.full((vertex_count, 3), 160, np.uint8)
    ids = np.unique(face_ids)
    palette = np.array([palette_color(int(i)) for i in ids], np.uint8)
    colors[faces.reshape(-1)] = np.repeat(palette[np.searchsorted(ids, face_ids)], 3, axis=0)
    return colors


def scan_scene(scene_id: str, source: str, path: Path, vertices: np.ndarray, faces: np.ndarray, face_ids: np.ndarray,
               objects: dict[int, SceneObject], up_axis: str, appearance: dict, unknown: int = 0,
               short_faces: int = 0) -> Scene:
    """The Scene of a scan (file frame in, world frame out); degenerate faces dropped and counted.

    Args:
        appearance: Scene colour fields (`vertex_colors`, or `face_uvs` / `textures` / `face_material`).
        unknown: distinct labels of the files that name no object (they are void).
        short_faces: polygons of the file with fewer than 3 corners (already without triangles).
    """
    vertices = np.asarray(vertices, np.float32)
    if len(faces) == 0:
        raise SceneError(f"{path}: the mesh is empty (0 triangles); re-download the scene")
    if len(face_ids) and int(np.max(face_ids)) > MAX_INSTANCE_ID + 1:  # readers refuse such ids first; never wrap
        raise SceneError(f"{path}: object id {int(np.max(face_ids))} does not fit a uint32 panoptic id; renumber the instances")
    keep = non_degenerate(vertices, faces)
    dropped = int((~keep).sum())
    if dropped + short_faces:
        LOG.warning("%s: dropped %d degenerate faces (fewer than 3 corners or zero area)", path, dropped + short_faces)
    if dropped:
        faces, face_ids = faces[keep], face_ids[keep]
        appearance = {k: (v[keep] if k in ("face_uvs", "face_material") and v is not None else v) for k, v in appearance.items()}
    present = set(distinct_positive(face_ids).tolist())
    transform = up_axis_transform(up_axis)
    LOG.info("%s: %d triangles, %d objects", path, len(faces), len(present))
    return Scene(scene_id=scene_id, vertices=to_world(vertices, transform), faces=faces.astype(np.int32, copy=False),
                 face_object_ids=face_ids.astype(np.uint32, copy=False),
                 objects={i: o for i, o in sorted(objects.items()) if i in present}, to_world=transform, source=source,
                 path=str(path), unknown_colors=int(unknown), degenerate_faces=dropped + int(short_faces), **appearance)


def lookup(keys: np.ndarray, values: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(found, value) for each query among integer `keys` (value 0 where not found).

    A dense table when the keys are small non-negative integers (dataset ids are), which is linear
    time on a million faces; a binary search otherwise."""
    keys, queries = np.asarray(keys, np.int64), np.asarray(queries, np.int64)
    if len(keys) == 0:
        return np.zeros(len(queries), bool), np.zeros(len(queries), np.int64)
    low, high = int(min(keys.min(), queries.min(initial=0))), int(max(keys.max(), queries.max(initial=0)))
    if low >= 0 and high < 4 * len(queries) + 1_000_000:
        table, known = np.zeros(high + 1, np.int64), np.zeros(high + 1, bool)
        table[keys], known[keys] = values, True
        return known[queries], table[queries]
    order = np.argsort(keys, kind="stable")
    position = np.searchsorted(keys[order], queries).clip(0, len(keys) - 1)
    found = keys[order][position] == queries
    return found, np.where(found, np.asarray(values, np.int64)[order][position], 0)


def distinct_positive(values: np.ndarray) -> np.ndarray:
    """Sorted distinct values > 0 of an integer array (a count table when they are small, else a sort)."""
    values = np.asarray(values, np.int64)
    if len(values) and values.min() >= 0 and values.max() < 4 * len(values) + 1_000_000:
        return np.flatnonzero(np.bincount(values)[1:]) + 1
    unique = np.unique(values)
    return unique[unique > 0]


def labelled_faces(labels: np.ndarray, known: dict[int, SceneObject] | set[int]) -> tuple[np.ndarray, int]:
    """(F,) object ids where the label names a known object, else 0; and the count of distinct unknown labels > 0."""
    keys = np.array(sorted(known), dtype=np.int64)
    listed, _ = lookup(keys, keys, labels)
    unknown = distinct_positive(np.where(listed, 0, labels).clip(min=0))
    return np.where(listed, labels, 0).astype(np.int64), int(len(unknown))


def non_degenerate(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) True for faces with three distinct corners and non-zero area.

    Exact for float32 vertices: their differences and the products of two differences are exact in
    float64, so a cross product component is zero exactly when its two products are equal (no
    tolerance, no norm). Coordinates are gathered one axis at a time (contiguous columns), the
    cheapest layout on a million faces."""
    faces = np.asarray(faces)
    first, second, third = faces[:, 0], faces[:, 1], faces[:, 2]
    distinct = (first != second) & (second != third) & (first != third)
    x, y, z = np.asarray(vertices, np.float64).T.copy()
    ux, uy, uz = x[second] - x[first], y[second] - y[first], z[second] - z[first]
    vx, vy, vz = x[third] - x[first], y[third] - y[first], z[third] - z[first]
    area = uy * vz != uz * vy
    area |= uz * vx != ux * vz
    area |= ux * vy != uy * vx
    return distinct & area
