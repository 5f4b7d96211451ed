"""`geometric`: a weight-free, class-agnostic RGB-D segmenter (graph-based, Felzenszwalb-Huttenlocher).

Why this design: the experiment must run offline in the base install (no torch, no weights), and
indoor RGB-D frames carry strong geometric cues a colour-only method lacks: objects stand out from
walls and floors by depth jumps, and walls meet floors and ceilings at normal creases. So the image
graph (8-connected pixels) weighs each edge by colour difference (CIELAB), relative depth jump and
surface-normal angle, and the Felzenszwalb-Huttenlocher merge criterion (merge while the edge is no
heavier than each region's internal difference + scale / size) grows regions; regions smaller than
`min_area_fraction` of the frame are then merged into their most similar neighbour. It runs on a
downscaled frame (numba, one core) and the labels are upsampled by nearest neighbour.

Good at: walls, floors, ceilings and furniture separated by depth or creases; untextured generated
scenes; stable output for small camera motion (no learned noise); fast (45 ms per 640x480 frame on
one core of a loaded machine, benchmarks/results/models.json).
Bad at: objects flush with their support and of similar colour (a rug on a floor, a picture on a
wall, a closed door in its wall), thin objects below the working resolution, strongly textured
surfaces (split into many regions), and depth-less pixels (windows, beyond the far clip), which only
colour separates. It knows nothing of objects: a chair's seat and back may become two regions.

scikit-image's `felzenszwalb` was not used (no new dependency): it takes one multichannel image and a
single Euclidean edge weight, so depth jumps would have to be scaled into fake colour channels, and
the point-to-plane and normal terms, which keep slanted floors whole, cannot be expressed.
"""

from __future__ import annotations

from typing import Any

import cv2
import numba
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.models.segmenter import FrameInput, Segmenter, parse_options


class GeometricOptions(BaseModel):
    """Options of the `geometric` segmenter (a model file's `options:` section).

    Defaults: a grid over scale, depth and normal weights and the small-region size, scored by VSQ^1 on
    24 frames of bench_models' generated houses at 640x480 (0.14 at the textbook scale 300, 0.41 here);
    larger scales trade false positives for misses with little change.
    """

    model_config = ConfigDict(extra="forbid")

    downscale: int = Field(2, ge=1, le=8, description="work on the frame shrunk by this factor (speed; boundary detail)")
    scale: float = Field(3000.0, gt=0, description="Felzenszwalb's k: larger values give larger regions")
    blur: float = Field(0.8, ge=0, description="Gaussian sigma (working pixels) applied to colour before the graph")
    depth_weight: float = Field(1500.0, ge=0, description="edge weight per unit of point-to-plane gap / depth (0 along any plane, large at occluding edges)")
    normal_weight: float = Field(60.0, ge=0, description="edge weight per unit of (1 - cos) between surface normals")
    min_area_fraction: float = Field(0.005, ge=0, lt=1, description="regions below this fraction of the frame are merged away")
    levels: int = Field(1, ge=1, le=4, description="1 = one partition; more = nested coarser partitions too, "
                        "overlapping masks at several granularities like SAM/FastSAM's everything mode")
    level_factor: float = Field(4.0, gt=1, description="scale multiplier from one level to the next")


class GeometricSegmenter(Segmenter):
    """Graph-based segmentation over colour, depth and surface-normal discontinuities (see module doc)."""

    name = "geometric"

    def __init__(self, **options: Any):
        self.options = parse_options(GeometricOptions, "geometric", options)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "options": self.options.model_dump()}

    def labels(self, frame: FrameInput) -> np.ndarray:
        """(levels, H, W) int32 region labels 0..n-1 per level of the full-resolution frame."""
        options = self.options
        height, width = frame.rgb.shape[:2]
        small_w, small_h = max(1, width // options.downscale), max(1, height // options.downscale)
        rgb = cv2.resize(frame.rgb, (small_w, small_h), interpolation=cv2.INTER_AREA) if options.downscale > 1 else frame.rgb
        if options.blur > 0:
            rgb = cv2.GaussianBlur(rgb, (0, 0), options.blur)
        lab = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2LAB).astype(np.float32)
        points, normals = _geometry(frame, small_w, small_h)
        min_size = max(1, int(round(options.min_area_fraction * small_w * small_h)))
        small = _segment_graph(lab, points, normals, np.float32(options.depth_weight), np.float32(options.normal_weight),
                               np.float32(options.scale), min_size, options.levels, np.float32(options.level_factor))
        if options.downscale == 1:
            return small
        return np.stack([cv2.resize(level, (width, height), interpolation=cv2.INTER_NEAREST) for level in small])

    def segment(self, frame: FrameInput) -> np.ndarray:
        """Every region of every level; a coarser region identical to a finer one is given once."""
        levels = [level[None, :, :] == np.arange(int(level.max()) + 1, dtype=level.dtype)[:, None, None]
                  for level in self.labels(frame)]
        if len(levels) == 1:
            return levels[0]
        masks, seen = [], set()
        for mask in (m for level in levels for m in level):
            key = np.packbits(mask).tobytes()
            if key not in seen:
                seen.add(key)
                masks.append(mask)
        return np.stack(masks)


def _geometry(frame: FrameInput, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (z = 0 where no depth) and unit normals (0 where unknown) at the working size.

    Without intrinsics the points are (0, 0, z): the depth term then sees plain depth jumps.
    """
    points = np.zeros((height, width, 3), np.float32)
    if frame.depth is None:
        return points, np.zeros((height, width, 3), np.float32)
    # Nearest neighbour: averaging depth across an object's silhouette would invent surfaces.
    depth = cv2.resize(frame.depth, (width, height), interpolation=cv2.INTER_NEAREST).astype(np.float32) / 1000.0
    if frame.intrinsics is None:
        points[..., 2] = depth
        return points, np.zeros((height, width, 3), np.float32)
    fx, fy, cx, cy = frame.intrinsics
    scale_x, scale_y = width / frame.depth.shape[1], height / frame.depth.shape[0]
    x = (np.arange(width, dtype=np.float32) + 0.5 - cx * scale_x) / (fx * scale_x)
    y = (np.arange(height, dtype=np.float32) + 0.5 - cy * scale_y) / (fy * scale_y)
    points = np.stack([x[None, :] * depth, y[:, None] * depth, depth], axis=-1)
    normals = np.cross(np.gradient(points, axis=1), np.gradient(points, axis=0))
    length = np.linalg.norm(normals, axis=-1, keepdims=True)
    valid = (length[..., 0] > 0) & (depth > 0)
    normals = np.where(valid[..., None], normals / np.maximum(length, 1e-12), 0.0).astype(np.float32)
    return points.astype(np.float32), normals


@numba.njit(cache=True)
def _find(parent: np.ndarray, node: int) -> int:
    root = node
    while parent[root] != root:
        root = parent[root]
    while parent[node] != root:  # path compression
        parent[node], node = root, parent[node]
    return root


@numba.njit(cache=True)
def _edge_weight(lab: np.ndarray, points: np.ndarray, normals: np.ndarray, a_row: int, a_col: int, b_row: int,
                 b_col: int, depth_weight: float, normal_weight: float) -> float:
    colour = 0.0
    for c in range(3):
        d = lab[a_row, a_col, c] - lab[b_row, b_col, c]
        colour += d * d
    weight = np.sqrt(colour)
    za, zb = points[a_row, a_col, 2], points[b_row, b_col, 2]
    if (za > 0) != (zb > 0):
        return weight + depth_weight  # a hole next to a surface is a boundary
    if za <= 0:
        return weight
    # Distance of each point from the other's tangent plane, relative to depth: 0 along any plane,
    # however slanted (a floor seen at a grazing angle), large across an occluding edge. The larger
    # of the two, so that a normal smeared across an edge cannot hide it.
    along_a, along_b, dot, norm_a, norm_b = 0.0, 0.0, 0.0, 0.0, 0.0
    for c in range(3):
        gap = points[b_row, b_col, c] - points[a_row, a_col, c]
        along_a += normals[a_row, a_col, c] * gap
        along_b += normals[b_row, b_col, c] * gap
        dot += normals[a_row, a_col, c] * normals[b_row, b_col, c]
        norm_a += normals[a_row, a_col, c] ** 2
        norm_b += normals[b_row, b_col, c] ** 2
    if norm_a == 0.0 or norm_b == 0.0:  # no normals (no intrinsics): the plain relative depth jump
        return weight + depth_weight * abs(za - zb) / min(za, zb)
    weight += depth_weight * max(abs(along_a), abs(along_b)) / min(za, zb)
    return weight + normal_weight * (1.0 - dot)


@numba.njit(cache=True)
def _segment_graph(lab: np.ndarray, points: np.ndarray, normals: np.ndarray, depth_weight: float,
                   normal_weight: float, scale: float, min_size: int, levels: int, level_factor: float) -> np.ndarray:
    """(levels, H, W) int32 labels; level l merges with scale * level_factor ** l, continuing level l - 1's
    regions, so the levels are nested (every region of a level lies inside one region of the next)."""
    height, width = points.shape[:2]
    pixels = height * width
    edges = 4 * pixels
    first = np.empty(edges, np.int64)
    second = np.empty(edges, np.int64)
    weight = np.empty(edges, np.float32)
    count = 0
    for row in range(height):
        for col in range(width):
            for d_row, d_col in ((0, 1), (1, 0), (1, 1), (1, -1)):
                other_row, other_col = row + d_row, col + d_col
                if other_row < height and 0 <= other_col < width:
                    first[count] = row * width + col
                    second[count] = other_row * width + other_col
                    weight[count] = _edge_weight(lab, points, normals, row, col, other_row, other_col,
                                                 depth_weight, normal_weight)
                    count += 1
    order = np.argsort(weight[:count], kind="mergesort")  # stable: equal weights keep pixel order
    parent = np.arange(pixels)
    size = np.ones(pixels, np.int64)
    internal = np.zeros(pixels, np.float32)  # heaviest edge inside each region (Kruskal order: the last merged)
    labels = np.empty((levels, height, width), np.int32)
    level_scale = scale
    for level in range(levels):
        for index in order:
            a, b = _find(parent, first[index]), _find(parent, second[index])
            if a != b and weight[index] <= internal[a] + level_scale / size[a] \
                    and weight[index] <= internal[b] + level_scale / size[b]:
                if size[a] < size[b]:
                    a, b = b, a
                parent[b] = a
                size[a] += size[b]
                internal[a] = weight[index]
        for index in order:  # small regions join the neighbour across their lightest edge
            a, b = _find(parent, first[index]), _find(parent, second[index])
            if a != b and (size[a] < min_size or size[b] < min_size):
                if size[a] < size[b]:
                    a, b = b, a
                parent[b] = a
                size[a] += size[b]
        relabel = np.full(pixels, -1, np.int64)
        next_label = 0
        for node in range(pixels):
            root = _find(parent, node)
            if relabel[root] < 0:
                relabel[root] = next_label
                next_label += 1
            labels[level, node // width, node % width] = relabel[root]
        level_scale *= level_factor
    return labels
