"""Look at a scene: a top-down picture coloured by category with a legend, and summary statistics.

The picture is an orthographic view from above (+Y) drawn with OpenCV: faces that face up or down
are painted lowest first, so the tops of furniture cover the floor; ceilings are left out so the
rooms can be seen; walls are dark.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from pipeline.scenes.categories import categories
from pipeline.scenes.scene import Scene, SceneError

WALL_COLOR = (45, 45, 50)
BACKGROUND = (255, 255, 255)
LEGEND_WIDTH = 230


def _category_per_face(scene: Scene) -> np.ndarray:
    """(F,) mpcat40 index of each face (0 for void)."""
    ids = np.array(sorted(scene.objects), dtype=np.int64)
    cats = np.array([scene.objects[i].category for i in ids], dtype=np.int64)
    if len(ids) == 0:
        return np.zeros(len(scene.faces), dtype=np.int64)
    position = np.clip(np.searchsorted(ids, scene.face_object_ids.astype(np.int64)), 0, len(ids) - 1)
    found = ids[position] == scene.face_object_ids
    return np.where(found, cats[position], 0)


def top_down_image(scene: Scene, size: int = 1024, below: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB top-down view of the scene coloured by mpcat40 category, legend on the right.

    `below` (metres) leaves out faces entirely above that height, e.g. to see the ground floor of a
    two-storey house.
    """
    face_category = _category_per_face(scene)
    vertices = scene.vertices.astype(np.float64)
    normals = scene.face_normals()
    keep = (np.abs(normals[:, 1]) > 0.3) & (face_category != 17)
    if below is not None:
        keep &= vertices[scene.faces][:, :, 1].min(axis=1) < below
    low, high = scene.bounds()
    extent = max(high[0] - low[0], high[2] - low[2], 1e-6)
    scale = (size - 20) / extent
    present = sorted(set(int(c) for c in face_category[keep]))
    height = max(int((high[2] - low[2]) * scale) + 20, 30 + 22 * len(present))  # room for the legend
    image = np.full((height, size + LEGEND_WIDTH, 3), BACKGROUND, np.uint8)
    palette = {i: c.rgb for i, c in categories().items()}
    palette[1] = WALL_COLOR
    corners = vertices[scene.faces[keep]]
    order = np.argsort(corners[:, :, 1].max(axis=1), kind="stable")
    pixels = np.round((corners[:, :, [0, 2]] - low[[0, 2]]) * scale + 10).astype(np.int32)[order]
    kept_categories = face_category[keep][order]
    for category in range(len(pixels)):
        cv2.fillConvexPoly(image, pixels[category], palette.get(int(kept_categories[category]), (0, 0, 0)))
    _legend(image, present, palette, size)
    return image


def _legend(image: np.ndarray, present: list[int], palette: dict[int, tuple[int, int, int]], left: int) -> None:
    names = categories()
    for row, index in enumerate(present):
        y = 20 + row * 22
        if y + 12 > image.shape[0]:
            break
        cv2.rectangle(image, (left + 10, y - 12), (left + 28, y + 4), palette.get(index, (0, 0, 0)), -1)
        label = names[index].name if index in names else "void"
        cv2.putText(image, label, (left + 36, y + 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)


def write_preview(scene: Scene, path: str | Path, size: int = 1024, below: float | None = None) -> Path:
    """Write the top-down picture of `scene` as a PNG; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    image = top_down_image(scene, size, below)
    if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise SceneError(f"{path}: could not write the PNG; check the folder is writable and the name ends in .png")
    return path


FLOOR_AREA_CELL = 0.01  # metres
STOREY_BAND = 0.5  # floor faces within one band of heights cover one storey's floor


def floor_area(scene: Scene) -> float:
    """Square metres of floor seen from above: the union of the upward faces of floor-category objects
    per storey, so a rug lying on the floor (mpcat40 counts rugs as floor) is not counted twice.

    Rasterised on a 1 cm grid per band of heights (about 1 % error along the floor's outline)."""
    floor = (scene.face_normals()[:, 1] > 0.9) & (_category_per_face(scene) == 2)
    corners = scene.vertices[scene.faces[floor]]  # (N, 3 corners, xyz)
    if len(corners) == 0:
        return 0.0
    bands = np.floor(corners[:, :, 1].mean(axis=1) / STOREY_BAND).astype(np.int64)
    area = 0.0
    for band in np.unique(bands):
        triangles = corners[bands == band][:, :, [0, 2]]
        origin = triangles.reshape(-1, 2).min(axis=0)
        cells = np.rint((triangles - origin) / FLOOR_AREA_CELL).astype(np.int32)
        grid = np.zeros(cells.reshape(-1, 2).max(axis=0)[::-1] + 1, np.uint8)
        for triangle in cells:  # one by one: fillPoly would cut overlaps out (even-odd rule)
            cv2.fillConvexPoly(grid, triangle, 1)
        area += np.count_nonzero(grid) * FLOOR_AREA_CELL**2
    return float(area)


def scene_stats(scene: Scene) -> dict:
    """Rooms, triangles, vertices, objects per category and floor area of a scene."""
    per_category = Counter(o.category_name for o in scene.objects.values())
    regions = {o.region for o in scene.objects.values() if o.region >= 0}
    return {
        "scene_id": scene.scene_id,
        "source": scene.source,
        "rooms": len(regions) if regions else None,
        "triangles": scene.triangle_count,
        "vertices": int(len(scene.vertices)),
        "objects": len(scene.objects),
        "void_triangles": int((scene.face_object_ids == 0).sum()),
        "unknown_colors": scene.unknown_colors,
        "floor_area_m2": round(floor_area(scene), 2),
        "objects_per_category": dict(sorted(per_category.items(), key=lambda kv: (-kv[1], kv[0]))),
    }
