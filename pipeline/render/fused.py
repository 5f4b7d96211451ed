"""The z-buffer's winners straight to a frame's buffers: depth (mm), panoptic ids, segment statistics, and the colour
under ambient light or a spot light alone on diffuse surfaces.

Why: ambient light with an ideal sensor reads nothing of a pixel's hit but its triangle, barycentrics and depth.
The general path resolves every pixel into float buffers (depth, face, barycentrics: 20 bytes a pixel), then
the shading pass and the depth-and-labels pass read them back, and the segment statistics read the labels
again. `FramePass` takes the place of that resolve in each band of the cast (`Rasterizer.resolve_band`) and
writes the frame's own buffers while the hit is in registers, touching each pixel once; a face of one colour
(half the bench house's) needs no barycentrics, and depth and ids alone need none at all. Every value is the
general path's bit for bit: the same ray, the same Moeller-Trumbore arithmetic (raster.py), the same clip
test, millimetres, colour arithmetic and segment runs.

A spot frame without indirect light on diffuse surfaces reads of a hit only its normal, its ray and its depth besides:
the pass lights it as `lighting._vertex_colour_pixels` does (`_spot_of`, `_lit_albedo`), so the general path's
normal and direction buffers (24 bytes a pixel), its shading pass and its depth-and-labels pass are skipped too.

Measured on the bench's 96 consecutive poses, paired with the general path pose by pose in one process (CPU ms
per frame from the pose to the segment statistics, median of 3 rounds, load ~4): ambient 28.8 -> 26.8 at 1
thread, 28.5 -> 27.0 at 2; depth and ids alone 24.7 -> 23.9 and 25.0 -> 24.4. Most of the work is arithmetic
(the intersection's divisions, the colour), which fusing only moves: the stores and loads it saves are cheap.

A run's label and colour record are read by its winning (reordered) triangle from copies of the per-face tables in
the mesh's cluster order (`by_triangle`): through the original face index they were scattered loads, mostly cache
misses. Moving the divisions or the colour into branch-free passes of their own measured slower (see `_resolve_rows`).
"""

from __future__ import annotations

import threading
import weakref
from typing import TYPE_CHECKING

import numba
import numpy as np

from pipeline.io.segments import FrameSegments, add_run, count_row_runs, empty_boxes, segments_of
from pipeline.render.lighting import Shader, SurfaceColors, _albedo_of_terms, _face_terms, _lit_albedo, _spot_of
from pipeline.render.raster import _column_terms, _intersect, _row_rays, _triangle_frame, _unit_normal
from pipeline.render.sensors import millimetres_of

if TYPE_CHECKING:
    from pipeline.render.raster import ClusteredMesh, Rasterizer
    from pipeline.render.renderer import RenderedFrame, SceneLabels

_NO_RECORDS, _NO_RGB = np.zeros((1, 16), np.uint8), np.zeros((1, 1, 3), np.uint8)
_NO_SCALE, _NO_DECODE, _NO_ENCODE = np.zeros((1, 1), np.float32), np.zeros(1, np.float32), np.zeros(1, np.uint8)
# Entries of `_resolve_depth_and_ids`' table of winners (a power of 2; 32 KB: it stays in the L1 cache)
TRIANGLE_SLOTS = 1024


_BY_TRIANGLE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # mesh -> [(per-face table, by triangle)]
_BY_TRIANGLE_LOCK = threading.Lock()
_TABLES_PER_MESH = 4  # the newest reordered tables kept per mesh (a render stage uses 2: labels and colours)


def by_triangle(mesh: ClusteredMesh, per_face: np.ndarray) -> np.ndarray:
    """`per_face`'s rows in the order of `mesh`'s reordered triangles (`per_face[mesh.face_ids]`), taken once per mesh
    and table. Why: the resolve reads a run's colour record and dense label by its winning triangle; through
    `face_ids` they were scattered loads, mostly cache misses (original faces are in no spatial order), where a
    cluster's triangles are neighbours in memory."""
    with _BY_TRIANGLE_LOCK:  # (a frame's first bands ask at once: one builds, the others wait for it)
        tables = _BY_TRIANGLE.setdefault(mesh, [])
        for table, reordered in tables:
            if table is per_face:
                return reordered
        reordered = np.ascontiguousarray(per_face[mesh.face_ids])
        tables.append((per_face, reordered))
        del tables[:-_TABLES_PER_MESH]  # (renderers built with tables of their own must not pile copies up)
        return reordered


class FramePass:
    """A frame's depth (mm), panoptic ids, segment statistics and, with `colors`, its RGB (ambient, or lit by `spot`),
    written by the resolve of each band of the cast (pass it as `SceneRaycaster.cast`'s `into`; then call `segments`).

    Args:
        frame: the buffers to fill (its `rgb` is left alone without `colors`, its `dense` labels always: the
            statistics are counted in the same pass).
        labels: the scene's per-face ids and dense labels.
        colors: vertex-coloured albedo (`SurfaceColors.records`), or None for depth and ids alone.
        near, far: the sensor's clip range in metres (a hit outside it is a miss: void, black, 0 mm).
        spot: the whole frame's `Shader` of a spot light on diffuse surfaces without indirect light, to light the
            colours by (None: ambient).
    """

    def __init__(self, frame: RenderedFrame, labels: SceneLabels, colors: SurfaceColors | None, near: float,
                 far: float, spot: Shader | None = None):
        if colors is not None and colors.records is None:
            raise ValueError("FramePass colours vertex-coloured scenes only; shade textured ones with Shader")
        if spot is not None and colors is None:
            raise ValueError("FramePass lights colours: give the scene's SurfaceColors with the spot's Shader")
        self.frame = frame
        self.labels = labels
        self.colors = colors
        self.near, self.far = np.float32(near), np.float32(far)
        self.spot_terms = spot.spot_terms() if spot is not None else None
        self._counts: list[tuple[np.ndarray, np.ndarray]] = []  # (areas, boxes) of each band resolved

    def resolve_band(self, rasterizer: Rasterizer, rows: slice, camera_to_world: np.ndarray) -> None:
        """Resolve the winners of rows `rows` (drawn by `rasterizer.draw_band`) into the frame's buffers."""
        frame, mesh = self.frame, rasterizer.mesh
        areas, boxes = empty_boxes(len(self.labels.dense_ids), *frame.panoptic.shape)
        arguments = (mesh.corners, rasterizer.winner, np.ascontiguousarray(camera_to_world, np.float64),
                     rasterizer.pixel_x, rasterizer.pixel_y, rows.start, rows.stop, self.near, self.far,
                     self.labels.dense_ids, by_triangle(mesh, self.labels.dense_of_face), frame.depth, frame.panoptic,
                     areas, boxes)
        if self.colors is None:
            _resolve_depth_and_ids(*arguments)
            return self._counts.append((areas, boxes))  # (list.append is atomic: bands resolve on several threads)
        records = by_triangle(mesh, self.colors.records)
        if self.spot_terms is not None:  # (flat colours too: a face of one colour takes the flat path)
            _resolve_spot(*arguments, records, frame.rgb, *self.spot_terms)
        elif self.colors.flat:
            _resolve_flat(*arguments, records, frame.rgb)
        else:
            _resolve_ambient(*arguments, records, frame.rgb)
        self._counts.append((areas, boxes))  # (list.append is atomic: bands resolve on several threads)

    def segments(self) -> FrameSegments:
        """The frame's segment statistics (`frame_segments` of its panoptic ids), once every band is resolved."""
        (areas, boxes), *others = self._counts
        for band_areas, band_boxes in others:  # (a compiled merge: numpy's sum, stack and reductions took ~0.25 ms)
            _add_counts(areas, boxes, band_areas, band_boxes)
        return segments_of(areas, boxes, self.labels)


@numba.njit(nogil=True, cache=True)
def _add_counts(areas, boxes, band_areas, band_boxes):  # pragma: no cover (compiled)
    """Another band's areas and boxes (`add_run`'s) into `areas` and `boxes`: sums, and the boxes' union."""
    for label in range(len(areas)):
        areas[label] += band_areas[label]
        boxes[label, 0] = min(boxes[label, 0], band_boxes[label, 0])
        boxes[label, 1] = min(boxes[label, 1], band_boxes[label, 1])
        boxes[label, 2] = max(boxes[label, 2], band_boxes[label, 2])
        boxes[label, 3] = max(boxes[label, 3], band_boxes[label, 3])


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _resolve_ambient(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far, dense_ids,
                     label_of_triangle, millimetres, panoptic, areas, boxes, records,
                     rgb):  # pragma: no cover (compiled)
    """`_resolve_rows` with the ambient colour interpolated over the triangle."""
    _resolve_rows(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far, dense_ids,
                  label_of_triangle, millimetres, panoptic, areas, boxes, True, records, True, rgb, False, _NO_SCALE,
                  _NO_DECODE, _NO_ENCODE)


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _resolve_spot(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far, dense_ids,
                  label_of_triangle, millimetres, panoptic, areas, boxes, records, rgb, scale_steps, decode,
                  encode):  # pragma: no cover (compiled)
    """`_resolve_rows` with the colour interpolated over the triangle and lit by the spot alone (`Shader.spot_terms`)."""
    _resolve_rows(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far, dense_ids,
                  label_of_triangle, millimetres, panoptic, areas, boxes, True, records, True, rgb, True, scale_steps,
                  decode, encode)


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _resolve_flat(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far, dense_ids,
                  label_of_triangle, millimetres, panoptic, areas, boxes, records, rgb):  # pragma: no cover (compiled)
    """`_resolve_rows` with the ambient colour of flat-coloured faces."""
    _resolve_rows(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far, dense_ids,
                  label_of_triangle, millimetres, panoptic, areas, boxes, True, records, False, rgb, False, _NO_SCALE,
                  _NO_DECODE, _NO_ENCODE)


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _resolve_depth_and_ids(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far,
                           dense_ids, label_of_triangle, millimetres, panoptic, areas,
                           boxes):  # pragma: no cover (compiled)
    """`_resolve_rows` without colour, its hits' t, ids and labels the same bits, with what depends on a winner alone
    (its plane, id and label) kept in a small table of TRIANGLE_SLOTS entries by triangle (`_slot_of`) instead of
    taken anew at each run of pixels it wins.

    Why: a bench frame's rows change winner every ~4 pixels (72 k runs a frame), and that branch, mispredicted, and
    the triangle's set-up took ~0.9 of the loop's ~1.5 ms a frame. Through the table a pixel's branch (is its winner
    in its slot?) is nearly always taken the same way: a band of the bench's frames fills a slot ~1.1 k times, not 36 k.
    Measured on the bench's winners, the resolve alone, 1 thread, in turns in one process: 0.85-0.93 of
    `_resolve_rows`' time (a table of 256 entries 1.28, of 4096 1.10: its stores miss the L1 cache). Measured slower:
    a row's runs of one winner found first without branches, then their planes set up in a loop of their own and read
    per pixel, 1.05-2.07 of `_resolve_rows` (the per-pixel reads are not vectorised); the table's entries copied per
    pixel for a vectorised pass of the divisions, 1.05-1.07 of this loop."""
    width = len(pixel_x)
    ox, oy, oz = np.float32(pose[0, 3]), np.float32(pose[1, 3]), np.float32(pose[2, 3])
    column_terms = _column_terms(pose, pixel_x)  # as raster._resolve takes them: the same bits of every ray
    rays = np.empty((3, width), np.float32)
    # Per slot: the triangle it holds (-2: none; -1, no winner, has a slot of its own like any other) and its normal,
    # N . c, panoptic id and dense label, 32 bytes (the two integers in the float table's bits: one cache line).
    holds = np.full(TRIANGLE_SLOTS, -2, winner.dtype)
    table = np.empty((TRIANGLE_SLOTS, 8), np.float32)
    words = table.view(np.uint32)
    depths = np.empty(width, np.float32)
    row_labels = np.empty((1, width), np.uint32)  # (2-D for `count_row_runs`)
    for row in range(row_start, row_stop):
        _row_rays(column_terms, pose, pixel_y[row], rays)
        for column in range(width):
            triangle = winner[row, column]
            slot = _slot_of(triangle)
            if holds[slot] != triangle:
                holds[slot] = triangle
                _fill_slot(table, words, slot, corners, triangle, ox, oy, oz, dense_ids, label_of_triangle)
            depths[column] = _distance_to_plane(table[slot, 0], table[slot, 1], table[slot, 2], table[slot, 3],
                                                rays[0, column], rays[1, column], rays[2, column])
            panoptic[row, column] = words[slot, 4]
            row_labels[0, column] = words[slot, 5]
        for column in range(width):  # (no branches: vectorised)
            hit = _kept(depths[column], near, far)
            millimetres[row, column] = millimetres_of(depths[column], near, far)  # (0 for any t not kept)
            panoptic[row, column] = panoptic[row, column] if hit else np.uint32(0)
            row_labels[0, column] = row_labels[0, column] if hit else np.uint32(0)
        count_row_runs(row_labels, 0, row, areas, boxes)


@numba.njit(nogil=True, cache=True, inline="always")
def _slot_of(triangle):  # pragma: no cover (compiled)
    """A triangle's entry in `_resolve_depth_and_ids`' table (neighbouring triangles, a cluster's, get distinct ones)."""
    return triangle & (TRIANGLE_SLOTS - 1)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _fill_slot(table, words, slot, corners, triangle, ox, oy, oz, dense_ids,
               label_of_triangle):  # pragma: no cover (compiled)
    """Write a winner's normal, N . c (0 for no winner: t = 0, a miss), panoptic id and dense label into `slot`."""
    frame = _triangle_frame(corners, max(triangle, 0), ox, oy, oz)
    table[slot, 0], table[slot, 1], table[slot, 2] = frame[6], frame[7], frame[8]
    table[slot, 3] = frame[12] if triangle >= 0 else np.float32(0.0)
    label = label_of_triangle[max(triangle, 0)]
    words[slot, 4], words[slot, 5] = dense_ids[label], label


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _resolve_rows(corners, winner, pose, pixel_x, pixel_y, row_start, row_stop, near, far, dense_ids,
                  label_of_triangle, millimetres, panoptic, areas, boxes, colour, records, interpolate, rgb, spot,
                  scale_steps, decode, encode):  # pragma: no cover (compiled)
    """Per pixel of rows row_start..row_stop: `raster._resolve`'s hit (its rays and intersection, same bits), a
    miss where it reports none or `VideoRenderer.trace` clips it, then what `renderer._depth_and_labels` and,
    with `colour`, the shading (`lighting._vertex_colour_pixels`, or the face's first corner when not
    `interpolate`; with `spot`, lit by the spot alone: the hit's unit normal, ray and depth as `raster._resolve`
    writes them) make of it; each row's runs of one dense label are counted into `areas` and `boxes` as
    `segments._areas_and_boxes` counts them. What depends on the triangle alone is taken once per run of pixels
    it wins (~4 pixels on a bench frame): its corners, its dense label (`label_of_triangle`, then its id from
    `dense_ids`) and its colour record, each by reordered triangle (`by_triangle`)."""
    width = len(pixel_x)
    steps = np.float32(len(encode) - 1)
    # A row in passes: a loop per pixel that branches only on its winner takes each pixel's t, id and label and, with
    # `colour`, its albedo (and light); a branch-free loop, vectorised, clips them (millimetres, void); a third
    # blackens the colour of misses and, with `spot`, lights the rest; then the label runs are counted. Against one
    # loop doing it all per pixel (bench poses, 1 band, 1 thread, paired in one process, median ratio per frame):
    # depth and ids 0.67, ambient 0.89-0.93, spot 0.88 (0.95 against a loop of its own for the light alone).
    # Measured slower (same poses, paired with c3aff85's loop, which this one takes 0.95-0.96 of): t's division in the
    # vectorised pass (numerator and |den| kept per pixel) 1.00-1.04 for depth and ids; the albedo in a branch-free
    # pass of its own from the winner's record and kept barycentrics 1.29-1.32 (ambient and spot); every quotient and
    # the colour terms kept per pixel for one vectorised pass 1.49-1.53; each pixel reading its winner's plane and
    # corner without branches 1.40-1.42 (depth and ids).
    depths = np.empty(width, np.float32)
    row_labels = np.empty(width, label_of_triangle.dtype)
    lights = np.zeros(width if spot else 1, np.float32)
    black = encode[0] if spot else np.uint8(0)  # a miss: no albedo, no light (the general path's encode[0])
    ox, oy, oz = np.float32(pose[0, 3]), np.float32(pose[1, 3]), np.float32(pose[2, 3])
    column_terms = _column_terms(pose, pixel_x)  # as raster._resolve takes them: the same bits of every ray
    rays = np.empty((3, width), np.float32)
    terms = np.zeros((3, 3), np.float32)
    current, frame = -1, _triangle_frame(np.zeros((1, 3, 3), np.float32), 0, ox, oy, oz)
    object_id, label, uniform = dense_ids[0], label_of_triangle[0], True
    unit = (np.float32(0.0), np.float32(0.0), np.float32(0.0))
    for row in range(row_start, row_stop):
        _row_rays(column_terms, pose, pixel_y[row], rays)
        for column in range(width):
            triangle = winner[row, column]
            t, u, v = np.float32(0.0), np.float32(0.0), np.float32(0.0)
            if triangle >= 0:
                if triangle != current:
                    current, frame = triangle, _triangle_frame(corners, triangle, ox, oy, oz)
                    label = label_of_triangle[triangle]
                    object_id = dense_ids[label]
                    if colour and interpolate:
                        _face_terms(records, triangle, terms)
                        uniform = _uniform(terms)
                    if spot:
                        unit = _unit_normal(frame)
                if colour and interpolate and not uniform:
                    t, u, v = _intersect(frame, rays[0, column], rays[1, column], rays[2, column])
                else:
                    t = _distance(frame, rays[0, column], rays[1, column], rays[2, column])
            depths[column] = t
            panoptic[row, column] = object_id
            row_labels[column] = label
            if not colour or triangle < 0:
                continue
            if spot:
                lights[column] = _spot_of(unit[0], unit[1], unit[2], rays[0, column], rays[1, column], rays[2, column],
                                          scale_steps[row, column], t)[1]
            if colour and interpolate and not uniform:
                rgb[row, column, 0] = _albedo_of_terms(terms, 0, u, v)
                rgb[row, column, 1] = _albedo_of_terms(terms, 1, u, v)
                rgb[row, column, 2] = _albedo_of_terms(terms, 2, u, v)
            elif colour:
                for channel in range(3):
                    rgb[row, column, channel] = records[triangle, channel]
        for column in range(width):
            hit = _kept(depths[column], near, far)
            millimetres[row, column] = millimetres_of(depths[column], near, far)  # (0 for any t not kept)
            panoptic[row, column] = panoptic[row, column] if hit else np.uint32(0)
            row_labels[column] = row_labels[column] if hit else 0
        if colour:
            for column in range(width):
                if not _kept(depths[column], near, far):
                    rgb[row, column, 0] = rgb[row, column, 1] = rgb[row, column, 2] = black
                elif spot:
                    light = lights[column]
                    for channel in range(3):
                        rgb[row, column, channel] = _lit_albedo(decode, encode, rgb[row, column, channel], light, steps)
        run_label, run_start = row_labels[0], 0
        for column in range(1, width):
            if row_labels[column] != run_label:
                add_run(areas, boxes, run_label, row, run_start, column)
                run_label, run_start = row_labels[column], column
        add_run(areas, boxes, run_label, row, run_start, width)


@numba.njit(nogil=True, cache=True, inline="always")
def _kept(t, near, far):  # pragma: no cover (compiled)
    """Whether a pixel's t is a hit as the resolve reports it (0 < t < inf; no winner: t = 0) that the clip keeps
    (near <= t <= far, in float32). Combined by `&`: no branches, so a loop of it is vectorised."""
    return (t > np.float32(0.0)) & (t < np.float32(np.inf)) & (t >= near) & (t <= far)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _distance(frame, dx, dy, dz):  # pragma: no cover (compiled)
    """The t of `raster._intersect` alone (the same float32 operations): for pixels whose barycentrics no buffer reads."""
    return _distance_to_plane(frame[6], frame[7], frame[8], frame[12], dx, dy, dz)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _distance_to_plane(nx, ny, nz, normal_dot_c, dx, dy, dz):  # pragma: no cover (compiled)
    """`_distance` of a triangle's normal N and N . c (`_triangle_frame`'s)."""
    den = nx * dx + ny * dy + nz * dz
    sign = np.float32(1.0) if den >= 0 else np.float32(-1.0)
    return normal_dot_c * sign / abs(den)


@numba.njit(nogil=True, cache=True, inline="always")
def _uniform(terms):  # pragma: no cover (compiled)
    """Whether a face's colour terms (`_face_terms`) are one colour at every point: then its albedo is its first
    corner's colour, c0 + 0.5 + 0 u + 0 v truncated, for any finite barycentrics (half the bench house's faces)."""
    return ((terms[0, 1] == 0.0) & (terms[0, 2] == 0.0) & (terms[1, 1] == 0.0) & (terms[1, 2] == 0.0)
            & (terms[2, 1] == 0.0) & (terms[2, 2] == 0.0))
