"""Primary visibility by rasterization: the camera rays' hits, found by a z-buffer instead of a BVH walk.

Why: a camera ray per pixel costs a BVH walk per pixel (~60 ms of CPU for 640x480 on a 1 M-triangle
house), while a z-buffer pays per visible triangle. The mesh is split once into clusters of nearby
triangles; per frame, clusters outside the view are dropped, the rest are drawn nearest first, and a
cluster whose box lies behind everything already drawn in the 8 x 8-pixel tiles it covers is skipped
(occlusion culling), so the triangles of rooms behind walls are never set up; inside a cluster, each triangle
is then proved hidden the same way, all of a cluster's in one loop, by the tiles its pixel box
falls in (of 8 x 8 pixels, or of 4 x 4 for a small box). Triangles facing away from the camera are drawn last,
when the surfaces in front of them are in the z-buffer and cull them. Frame-to-frame coherence: the triangles
that won pixels in the previous frame (5 cm away along a video) are drawn before all others, so the z-buffer
is nearly final when the clusters and triangles are tested against it. The winner of a pixel does not depend on
that history: it is the nearest triangle, of equal ones the first in this frame's drawing order, however the
triangles are drawn, so a frame rendered after any other is bit for bit the frame rendered first.

The coverage test is the ray-triangle test itself, not a projection: with a, b, c the corners relative
to the camera, the ray d of a pixel centre hits the triangle at t > 0 exactly when det(a, b, d),
det(b, c, d) and det(c, a, d) all have the sign of det(a, b, c) (homogeneous rasterization, Olano and
Greer 1997). No clipping is needed (corners behind the camera are fine), hits nearer than the sensor's
`near` are found like the ray cast finds them (VideoRenderer.trace turns them into misses), and a shared
edge is computed bit for bit alike (negated) by both its triangles, so no pixel falls between them (ties
on the edge go to the triangle first in the drawing order: clusters nearest first, then reordered index). The
winning triangle of each pixel is then intersected with the pixel's ray by Embree's own Moeller-Trumbore
arithmetic in float32, so depth, barycentrics and normal are the ray cast's to float precision (measured
in benchmarks/bench_render.py).
"""

from __future__ import annotations

import numba
import numpy as np

CLUSTER_SIZE = 64  # triangles per cluster: small boxes cull well, and 16 k clusters per 1 M triangles test fast
TILE = 8  # pixels per side of the occlusion tiles
SPAN_MARGIN = 1e-3  # pixels: a row's columns are tested this far beyond its edges' zeros (see _draw_triangle)
SMALL_BOX = 4  # pixels: a triangle's box of at most this many pixel centres is tested pixel by pixel
NARROW_BOX = 6  # columns: a box narrower than this is tested column by column, without its rows' spans
# pixels: a triangle's box of at most this many pixel centres whose tiles are not all behind is tested pixel by pixel
# (a triangle whose tiles straddle a depth edge is often behind every pixel of its own box: 36 % fewer edge set-ups
# and 28 % fewer pixel tests on the bench's consecutive poses, while a larger box is rarely behind)
PIXEL_BOX = 1024
# pixels per side of the finer occlusion level that small pixel boxes are proved hidden against in bulk (`_box_behind`;
# TILE / 2: `_refresh_tiles` reads FINE_TILE pixels of a row at once, and `_box_behind` halves to reach TILE)
FINE_TILE = 4
# tiles per side of the window a triangle's pixel box must fit in to be proved hidden in bulk: 3 x 3 tested 4 %
# less draw time than 2 x 2 on the bench's consecutive poses, 4 x 4 (more loads per triangle) 2 % more than 3 x 3
WINDOW = 3
GEOMETRY_ROWS = 14  # numbers `_prepare` sets up per triangle
LANE_BLOCK = 9 * CLUSTER_SIZE  # a cluster's corners in `ClusteredMesh.lanes`
_BEHIND = 1e-6  # metres: a cluster corner nearer than this to the camera plane makes the cluster cover the image
# pixels: a triangle's box of at most this many pixels is proved hidden by its pixels alone, without the occlusion tiles
# first (which prove only what the pixels prove, and refresh stale tiles on the way): draw 0.95 of the tiles-first
# order's (bench poses, draw over resolve in one process, 3 process pairs; 32: 0.98, 512: 0.99)
PIXELS_FIRST_BOX = 128
_CHUNK_MARGIN = 1e-6  # metres: a chunk of clusters is dropped whole only when outside the view by more than this


class ClusteredMesh:
    """A triangle mesh reordered into spatially compact clusters (Morton order of the triangle centres).

    Attributes:
        corners: (F, 3, 3) float32 triangle corners, cluster by cluster.
        face_ids: (F,) int64 index of each reordered triangle in the original mesh.
        starts: (C + 1,) first triangle of each cluster.
        planes: (F, 4) float32 plane of each triangle: N and N . v0, N = (v1 - v0) x (v2 - v0) (which side
            of it a camera lies on tells whether the triangle faces it, before its corners are transformed).
        low, high: (C, 3) float64 bounding boxes of the clusters.
        chunk_low, chunk_high: (C / CLUSTER_SIZE, 3) float64 bounding boxes of each CLUSTER_SIZE consecutive
            clusters (the chunks `_cull_clusters` tests together, and drops whole when outside the view).
        lanes: (C LANE_BLOCK,) float32 the corners again, cluster by cluster, in 9 rows of CLUSTER_SIZE (x of
            the first corners, their y, z, then the second's, the third's; a last short cluster padded), so that
            the camera transform and projection of a cluster's triangles run several at a time (`_prepare`).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        corners = np.asarray(vertices, np.float32)[np.asarray(faces, np.int64)]
        centres = corners.mean(axis=1, dtype=np.float64)
        self.face_ids = np.argsort(_morton_codes(centres), kind="stable")
        self.corners = np.ascontiguousarray(corners[self.face_ids])
        edges = self.corners[:, 1:].astype(np.float64) - self.corners[:, :1]
        normals = np.cross(edges[:, 0], edges[:, 1])
        offsets = np.einsum("ij,ij->i", normals, self.corners[:, 0].astype(np.float64))
        self.planes = np.concatenate([normals, offsets[:, None]], axis=1).astype(np.float32)
        self.starts = np.append(np.arange(0, len(faces), CLUSTER_SIZE), len(faces)).astype(np.int64)
        self.low = np.minimum.reduceat(self.corners.min(axis=1), self.starts[:-1]).astype(np.float64)
        self.high = np.maximum.reduceat(self.corners.max(axis=1), self.starts[:-1]).astype(np.float64)
        chunks = np.arange(0, len(self.low), CLUSTER_SIZE)
        self.chunk_low = np.minimum.reduceat(self.low, chunks)
        self.chunk_high = np.maximum.reduceat(self.high, chunks)
        padded = np.zeros((len(self.starts) - 1) * CLUSTER_SIZE * 9, np.float32)
        padded[:self.corners.size] = self.corners.ravel()
        self.lanes = np.ascontiguousarray(padded.reshape(-1, CLUSTER_SIZE, 9).transpose(0, 2, 1)).ravel()


def _morton_codes(points: np.ndarray) -> np.ndarray:
    """63-bit Morton codes of points quantised to 2^21 steps of their bounding box per axis."""
    low, high = points.min(axis=0), points.max(axis=0)
    cells = ((points - low) / np.maximum(high - low, 1e-12) * (2**21 - 1)).astype(np.uint64)
    return _spread_bits(cells[:, 0]) | _spread_bits(cells[:, 1]) << np.uint64(1) | _spread_bits(cells[:, 2]) << np.uint64(2)


def _spread_bits(values: np.ndarray) -> np.ndarray:
    """21-bit integers with two zero bits inserted after each bit (bit k moves to bit 3 k)."""
    values = values & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        values = (values | values << np.uint64(shift)) & np.uint64(mask)
    return values


class Rasterizer:
    """Primary hits of one camera on one clustered mesh, in row bands (each band an independent z-buffer).

    Buffers are per camera and reused from frame to frame (a band's winners are the first triangles its next
    frame draws); `visible_clusters` runs once per frame, then `draw_band` and `resolve_band` may run on
    different bands in parallel (they release the GIL).
    """

    def __init__(self, mesh: ClusteredMesh, pixel_x: np.ndarray, pixel_y: np.ndarray, fx: float, fy: float):
        """`pixel_x`, `pixel_y`: camera-frame x / z per column and y / z per row of the pixel centres
        (`Camera.pixel_axes`); `fx`, `fy`: the focal lengths in pixels (columns per unit of x / z)."""
        self.mesh = mesh
        self.focal = (float(fx), float(fy))
        self.pixel_x = np.ascontiguousarray(pixel_x, np.float64)
        self.pixel_y = np.ascontiguousarray(pixel_y, np.float64)
        height, width = len(pixel_y), len(pixel_x)
        self.inverse_depth = np.empty((height, width), np.float32)
        # The previous frame's winners, until a band is drawn anew. int32: every pass and the resolve read and write
        # them, and a band's z-buffer and winners (1.8 MB with int64 ones on the bench) then fit a 2 MB L2 with room.
        self.winner = np.full((height, width), -1, _triangle_index_type(len(mesh.corners)))
        # Per band of rows: occlusion tiles, their dirty flags, and `_draw`'s scratch space.
        self._scratch: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}
        self.order = np.empty(0, np.int64)
        self.rank = np.empty(len(mesh.starts) - 1, np.int64)  # position of each visible cluster in `order`
        self.rects = np.empty((len(mesh.starts) - 1, 4), np.int64)
        self.nearest = np.empty(len(mesh.starts) - 1, np.float64)

    def visible_clusters(self, camera_to_world: np.ndarray) -> None:
        """The clusters inside the view, nearest first, with their pixel rectangles (for `draw_band`)."""
        pose = np.ascontiguousarray(camera_to_world, np.float64)
        self.order = _visible_order(self.mesh.low, self.mesh.high, self.mesh.chunk_low, self.mesh.chunk_high, pose,
                                    self.pixel_x, self.pixel_y, *self.focal, self.rects, self.nearest, self.rank)

    def draw_band(self, rows: slice, camera_to_world: np.ndarray) -> None:
        """Z-buffer the visible clusters into rows `rows`: the nearest reordered triangle per pixel (-1: none)."""
        band = (rows.start, rows.stop)
        if band not in self._scratch:
            shape = (-(-(rows.stop - rows.start) // TILE), -(-len(self.pixel_x) // TILE))
            self._scratch[band] = (np.empty(shape, np.float32), np.empty(shape, np.bool_),
                                   np.empty(len(self.mesh.corners), np.int64), np.empty_like(self.rects[:, :2]),
                                   np.empty((rows.stop - rows.start) * len(self.pixel_x), self.winner.dtype),
                                   np.zeros(len(self.mesh.corners), np.bool_),
                                   np.empty(LANE_BLOCK, np.float32), np.empty(GEOMETRY_ROWS * CLUSTER_SIZE, np.float64),
                                   np.empty(len(self.mesh.corners), np.float32),
                                   np.empty((len(self.mesh.corners), 4), np.int16),  # (Sensor: <= 8192 px a side)
                                   np.empty((-(-(rows.stop - rows.start) // FINE_TILE),
                                             -(-len(self.pixel_x) // FINE_TILE)), np.float32))
        _draw(self.mesh.lanes, self.mesh.planes, self.mesh.starts, self.order, self.rank, self.rects, self.nearest,
              np.ascontiguousarray(camera_to_world, np.float64), self.pixel_x, self.pixel_y, *self.focal, rows.start,
              rows.stop, self.inverse_depth, self.winner, *self._scratch[band])

    def resolve_band(self, rows: slice, camera_to_world: np.ndarray, miss: int, out: tuple[np.ndarray, ...],
                     surfaces: bool = True) -> None:
        """Intersect each pixel's ray of rows `rows` with its winning triangle, into `out` = (depth, face,
        barycentric, normal, direction) as `EmbreeMesh.cast_rows` fills them. Without `surfaces`, the normals and
        directions are left as they were (ambient light with an ideal sensor reads neither: ~7 MB of stores a frame)."""
        _resolve(self.mesh.corners, self.mesh.face_ids, self.winner, np.ascontiguousarray(camera_to_world, np.float64),
                 self.pixel_x, self.pixel_y, rows.start, rows.stop, miss, *out, surfaces)


def _triangle_index_type(triangles: int) -> type:
    """int32, the type of the z-buffer's winners (reordered triangle indices, -1 for none), or a ValueError for a
    mesh with more triangles than int32 can index."""
    if triangles > 2**31:
        raise ValueError(f"the mesh has {triangles} triangles; the rasterizer indexes at most 2**31 (2147483648): "
                         "split the scene's mesh into parts of at most that many")
    return np.int32


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _visible_order(low, high, chunk_low, chunk_high, pose, pixel_x, pixel_y, fx, fy, rects, nearest,
                   rank):  # pragma: no cover (compiled)
    """`_cull_clusters`' clusters sorted nearest first (a stable sort: of equal depths, the lower index first), and
    each cluster's position in that order into `rank` (-1: outside the view). One compiled call for what numpy's
    argsort, the fancy indexing and the rank's two writes took (sort and ranks 0.2 -> 0.13 ms a bench frame)."""
    inside = _cull_clusters(low, high, chunk_low, chunk_high, pose, pixel_x, pixel_y, fx, fy, rects, nearest)
    keys = np.empty(len(inside), np.float64)
    for k in range(len(inside)):
        keys[k] = nearest[inside[k]] + 0.0  # (-0.0 becomes 0.0: its bits would sort after every depth)
    order = inside[_stable_order(keys.view(np.uint64))]
    rank[:] = -1
    for position in range(len(order)):
        rank[order[position]] = position
    return order


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _stable_order(keys):  # pragma: no cover (compiled)
    """`np.argsort(keys, kind="stable")` of uint64 keys (the bits of non-negative float64 depths sort as the depths):
    a least-significant-digit radix sort, a byte a pass, skipping the bytes all keys share. ~2 k visible clusters a
    bench frame: 8 passes of 2 k keys against a comparison sort's ~11 (numpy's stable argsort and numba's mergesort
    both took ~0.2 ms a frame)."""
    order, spare = np.arange(len(keys)), np.empty(len(keys), np.int64)
    counts = np.empty(257, np.int64)
    for shift in range(0, 64, 8):
        counts[:] = 0
        for index in range(len(keys)):
            counts[((keys[index] >> np.uint64(shift)) & np.uint64(255)) + 1] += 1
        if counts.max() == len(keys):  # (every key has this byte: the pass would move nothing)
            continue
        for digit in range(256):  # (counts[digit]: where the keys of this byte start)
            counts[digit + 1] += counts[digit]
        for index in order:  # (in the order so far: keys of one byte keep it, so the sort is stable)
            digit = (keys[index] >> np.uint64(shift)) & np.uint64(255)
            spare[counts[digit]] = index
            counts[digit] += 1
        order, spare = spare, order
    return order


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _cull_clusters(low, high, chunk_low, chunk_high, pose, pixel_x, pixel_y, fx, fy, rects,
                   nearest):  # pragma: no cover (compiled)
    """Indices of the clusters whose boxes reach into the view (in front of the camera, inside the outermost
    pixel rays); for each, its pixel rectangle (row0, row1, col0, col1, inclusive) and nearest planar depth.
    The boxes are taken into the camera frame CLUSTER_SIZE at a time by `_box_views`, on vector lanes; a chunk whose
    box (`ClusteredMesh.chunk_low`, `chunk_high`) lies outside the view by a margin (`_box_outside_view`) is
    dropped whole, untested."""
    height, width = len(pixel_y), len(pixel_x)
    inside = np.empty(len(low), np.int64)
    boxes = np.empty(6 * CLUSTER_SIZE, np.float64)  # a chunk's low and high corners, one row per coordinate
    views = np.empty(7 * CLUSTER_SIZE, np.float64)
    count = 0
    for chunk in range(0, len(low), CLUSTER_SIZE):
        if _box_outside_view(chunk_low[chunk // CLUSTER_SIZE], chunk_high[chunk // CLUSTER_SIZE], pose, pixel_x[0],
                             pixel_x[-1], pixel_y[0], pixel_y[-1]):
            continue
        size = min(CLUSTER_SIZE, len(low) - chunk)
        for slot in range(size):
            for k in range(3):
                boxes[k * CLUSTER_SIZE + slot] = low[chunk + slot, k]
                boxes[(3 + k) * CLUSTER_SIZE + slot] = high[chunk + slot, k]
        _box_views(boxes, size, pose, pixel_x[0], pixel_x[-1], pixel_y[0], pixel_y[-1], fx, fy, views)
        for slot in range(size):
            z_min, z_max, outside = views[slot], views[CLUSTER_SIZE + slot], views[2 * CLUSTER_SIZE + slot]
            if z_max <= 0.0 or outside != 0.0:
                continue
            cluster = chunk + slot
            if z_min <= _BEHIND:  # the box reaches the camera plane: it may cover any pixel
                top, bottom, left, right, z_min = 0, height - 1, 0, width - 1, max(z_min, 0.0)
            else:
                top = max(int(np.floor(views[5 * CLUSTER_SIZE + slot])), 0)
                bottom = min(int(np.ceil(views[6 * CLUSTER_SIZE + slot])), height - 1)
                left = max(int(np.floor(views[3 * CLUSTER_SIZE + slot])), 0)
                right = min(int(np.ceil(views[4 * CLUSTER_SIZE + slot])), width - 1)
                if top > bottom or left > right:
                    continue
            rects[cluster, 0], rects[cluster, 1], rects[cluster, 2], rects[cluster, 3] = top, bottom, left, right
            nearest[cluster] = z_min
            inside[count] = cluster
            count += 1
    return inside[:count]


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _box_outside_view(low, high, pose, x0, x1, y0, y1):  # pragma: no cover (compiled)
    """Whether every corner of a world-frame box lies behind the camera, or outside one side of the view, by more than
    _CHUNK_MARGIN: then so does every corner of every box inside it (each test is affine in the corner, and the
    margin is ~10^5 times the rounding of `_corner_view`'s float64 arithmetic on coordinates of up to 10^4 m), and
    `_cull_clusters` would drop each of them (its test of a side is the same affine function, with a margin of 0)."""
    behind = left = right = above = below = True
    margin = 1e-9  # (`_corner_view`'s, on the slopes)
    for corner in range(8):
        px = (high[0] if corner & 1 else low[0]) - pose[0, 3]
        py = (high[1] if corner & 2 else low[1]) - pose[1, 3]
        pz = (high[2] if corner & 4 else low[2]) - pose[2, 3]
        x = pose[0, 0] * px + pose[1, 0] * py + pose[2, 0] * pz
        y = pose[0, 1] * px + pose[1, 1] * py + pose[2, 1] * pz
        z = pose[0, 2] * px + pose[1, 2] * py + pose[2, 2] * pz
        behind &= z < -_CHUNK_MARGIN
        left &= x - (x0 - margin) * z < -_CHUNK_MARGIN
        right &= (x1 + margin) * z - x < -_CHUNK_MARGIN
        above &= y - (y0 - margin) * z < -_CHUNK_MARGIN
        below &= (y1 + margin) * z - y < -_CHUNK_MARGIN
    return behind or left or right or above or below


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _box_views(boxes, size, pose, x0, x1, y0, y1, fx, fy, views):  # pragma: no cover (compiled)
    """For `size` world-frame boxes (`boxes`: rows low x, y, z, high x, y, z, CLUSTER_SIZE apart), into the rows
    of `views`: the nearest and farthest planar depth of their corners, whether all corners lie outside one side
    of the view (1) or not (0), and the range of the columns u and rows v of the corners in front of the camera
    (nearer than _BEHIND: none, the range is empty). A loop without branches, which the compiler vectorises."""
    rotation = (pose[0, 0], pose[0, 1], pose[0, 2], pose[1, 0], pose[1, 1], pose[1, 2], pose[2, 0], pose[2, 1],
                pose[2, 2])  # read before the loop: its stores might otherwise alias the pose
    origin = (pose[0, 3], pose[1, 3], pose[2, 3])
    for slot in range(size):
        view = (np.inf, -np.inf, True, True, True, True, np.inf, -np.inf, np.inf, -np.inf)
        low = (boxes[slot] - origin[0], boxes[CLUSTER_SIZE + slot] - origin[1],
               boxes[2 * CLUSTER_SIZE + slot] - origin[2])
        high = (boxes[3 * CLUSTER_SIZE + slot] - origin[0], boxes[4 * CLUSTER_SIZE + slot] - origin[1],
                boxes[5 * CLUSTER_SIZE + slot] - origin[2])
        # The corners in the order of bits x, y, z (written out: a loop over them is neither unrolled nor vectorised).
        view = _corner_view(view, low[0], low[1], low[2], rotation, x0, x1, y0, y1, fx, fy)
        view = _corner_view(view, high[0], low[1], low[2], rotation, x0, x1, y0, y1, fx, fy)
        view = _corner_view(view, low[0], high[1], low[2], rotation, x0, x1, y0, y1, fx, fy)
        view = _corner_view(view, high[0], high[1], low[2], rotation, x0, x1, y0, y1, fx, fy)
        view = _corner_view(view, low[0], low[1], high[2], rotation, x0, x1, y0, y1, fx, fy)
        view = _corner_view(view, high[0], low[1], high[2], rotation, x0, x1, y0, y1, fx, fy)
        view = _corner_view(view, low[0], high[1], high[2], rotation, x0, x1, y0, y1, fx, fy)
        view = _corner_view(view, high[0], high[1], high[2], rotation, x0, x1, y0, y1, fx, fy)
        z_min, z_max, left, right, above, below, u_min, u_max, v_min, v_max = view
        views[slot], views[CLUSTER_SIZE + slot] = z_min, z_max
        views[2 * CLUSTER_SIZE + slot] = 1.0 if left or right or above or below else 0.0
        views[3 * CLUSTER_SIZE + slot], views[4 * CLUSTER_SIZE + slot] = u_min, u_max
        views[5 * CLUSTER_SIZE + slot], views[6 * CLUSTER_SIZE + slot] = v_min, v_max


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _corner_view(view, px, py, pz, rotation, x0, x1, y0, y1, fx, fy):  # pragma: no cover (compiled)
    """`_box_views`' running view (z_min, z_max, left, right, above, below, u_min, u_max, v_min, v_max) with one
    more corner (px, py, pz: world frame, relative to the camera centre)."""
    z_min, z_max, left, right, above, below, u_min, u_max, v_min, v_max = view
    margin = 1e-9
    x = rotation[0] * px + rotation[3] * py + rotation[6] * pz
    y = rotation[1] * px + rotation[4] * py + rotation[7] * pz
    z = rotation[2] * px + rotation[5] * py + rotation[8] * pz
    u, v = (x / z - x0) * fx, (y / z - y0) * fy
    front = z > _BEHIND
    return (min(z_min, z), max(z_max, z), left and x < (x0 - margin) * z, right and x > (x1 + margin) * z,
            above and y < (y0 - margin) * z, below and y > (y1 + margin) * z,
            min(u_min, u) if front else u_min, max(u_max, u) if front else u_max,
            min(v_min, v) if front else v_min, max(v_max, v) if front else v_max)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _occluded(rect, nearest, row_start, row_stop, inverse_depth, tiles, dirty):  # pragma: no cover (compiled)
    """True when every pixel of the rectangle (within the band) already holds a surface nearer than `nearest`."""
    if nearest <= _BEHIND:
        return False
    closest = np.float32(1.0 / nearest * (1.0 + 1e-5))  # the cluster's largest inverse depth, rounded up
    width = inverse_depth.shape[1]
    top, bottom = max(rect[0], row_start), min(rect[1], row_stop - 1)
    for tile_row in range((top - row_start) // TILE, (bottom - row_start) // TILE + 1):
        for tile_column in range(rect[2] // TILE, rect[3] // TILE + 1):
            if tiles[tile_row, tile_column] >= closest:
                continue  # a stale value suffices: the tile's inverse depths only grow while a band is drawn
            if not dirty[tile_row, tile_column]:
                return False
            farthest = np.inf
            for row in range(row_start + tile_row * TILE, min(row_start + (tile_row + 1) * TILE, row_stop)):
                for column in range(tile_column * TILE, min((tile_column + 1) * TILE, width)):
                    farthest = min(farthest, inverse_depth[row, column])
            tiles[tile_row, tile_column] = farthest
            dirty[tile_row, tile_column] = False
            if farthest < closest:
                return False
    return True


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _draw(lanes, planes, starts, order, rank, rects, nearest, pose, pixel_x, pixel_y, fx, fy, row_start,
          row_stop, inverse_depth, winner, tiles, dirty, deferred, groups, hints, drawn, corner_batch,
          geometry, deferred_closest, deferred_boxes, fine):  # pragma: no cover (compiled)
    """Z-buffer (by inverse planar depth 1/t, 0 = nothing) the triangles of the clusters in `order` into rows
    row_start..row_stop; `winner` gets the reordered index of the nearest triangle per pixel, or -1.

    The winners `winner` holds on entry (the previous frame's, along a video a few centimetres away) are drawn
    first: they are nearly this frame's, so the z-buffer is nearly final before the clusters are tested
    against it, and most hidden clusters and triangles are culled. Then the clusters are drawn nearest first,
    without the triangles already drawn. Each cluster's triangles are proved hidden in bulk first (`_hide_prepared`,
    against the occlusion tiles and a finer level of them, `fine`, both refreshed once after the previous
    winners), so that only the others take the scalar tests of `_draw_triangle`. Triangles facing away from the
    camera are drawn after all others: in a closed surface they lie behind one facing the camera, so by then
    most of them are occluded and never reach the pixel loop. With the tiles refreshed again, they are proved
    hidden in bulk once more (`_hide_deferred`), by the numbers `_defer` kept of their first set-up; the rest are
    set up again and proved hidden one by one by the fine tiles their edges reach and their planes' depth there
    (`_covered_tiles_behind`, which proves whatever `_draw_triangle`'s own tests would), and only the others drawn.

    Triangles are set up in batches (a cluster's, a cluster's facing-away ones, CLUSTER_SIZE previous winners):
    `_prepare` takes them all into the camera frame and projects their boxes several lanes at a time, and the
    tests and pixel loops that follow read those numbers (the ones a triangle by itself would compute, bit for bit).

    Whatever the order, a pixel's winner is the nearest triangle, of equal ones the first in the drawing order
    of this frame (clusters by rank, then index: `_drawn_before`), as every draw breaks ties by that order and
    a culled triangle lies strictly behind what its pixels hold: a frame is the same whether its band was
    drawn before, from any pose, or not.
    `deferred` (one slot per triangle) and `groups` (two per cluster) are scratch space for the facing-away
    triangles of each cluster, `hints` (one slot per pixel) for the previous winners, `drawn` (one flag per
    triangle, all False between calls) marks them, `corner_batch` (9 CLUSTER_SIZE) and `geometry` (GEOMETRY_ROWS
    CLUSTER_SIZE) hold a batch's corners and set-up, `deferred_closest` and `deferred_boxes` (one slot per triangle)
    what `_defer` keeps of each deferred triangle, and `fine` the band's FINE_TILE tiles."""
    hint_count = _take_previous_winners(rank, row_start, row_stop, inverse_depth, winner, hints, drawn)
    # In the order they were found (row by row): they seldom overlap (bench poses 1-39: of 305 k stores a pose, 7.2 k
    # overwrite another winner's; drawn in the drawing order, 9.85 k), and their corners gathered from
    # `ClusteredMesh.corners` (a triangle's 36 bytes together) instead of `lanes` drew no faster (0.99-1.02 of a
    # control, in-process, 6 rounds).
    x0, y0 = pixel_x[0], pixel_y[0]
    for batch in range(0, hint_count, CLUSTER_SIZE):
        batch_stop = min(batch + CLUSTER_SIZE, hint_count)
        _gather(lanes, hints[batch:batch_stop], corner_batch)
        _prepare(corner_batch, 0, batch_stop - batch, pose, x0, y0, fx, fy, geometry)
        for slot in range(batch_stop - batch):
            triangle = hints[batch + slot]
            cluster = triangle // CLUSTER_SIZE
            rect = (rects[cluster, 0], rects[cluster, 1], rects[cluster, 2], rects[cluster, 3])
            _draw_triangle(geometry, slot, triangle, rect, pixel_x, pixel_y, fx, fy, row_start, row_stop,
                           inverse_depth, winner, tiles, dirty, rank, False)
    _refresh_tiles(row_start, row_stop, inverse_depth, tiles, dirty, fine)
    skip = np.empty(CLUSTER_SIZE, np.bool_)
    ox, oy, oz = pose[0, 3], pose[1, 3], pose[2, 3]
    count = group_count = 0
    for cluster in order:
        rect = (rects[cluster, 0], rects[cluster, 1], rects[cluster, 2], rects[cluster, 3])
        if rect[1] < row_start or rect[0] >= row_stop:
            continue
        if _occluded(rect, nearest[cluster], row_start, row_stop, inverse_depth, tiles, dirty):
            continue
        first, stop = starts[cluster], starts[cluster + 1]
        # All of the cluster is set up (66.2 k triangles a bench pose, of which `_hide_prepared` leaves 14.4 k).
        # Parts of 8 triangles proved hidden by their boxes first hid 27 % of the parts (set-ups 66.2 k -> 48.5 k)
        # but cost more than they saved: draw 1.09-1.10 of this, set up part by part or in one span (one process,
        # both trees' raster.py interleaved per pose, min of 5; identical code 0.994; parts of 16, 18 % hidden, no
        # better in process pairs); facing-away triangles deferred without their window test here (left to
        # `_hide_deferred`'s fresher tiles): 1.06.
        _prepare(lanes, cluster * LANE_BLOCK, stop - first, pose, x0, y0, fx, fy, geometry)
        _hide_prepared(geometry, stop - first, rect, row_start, row_stop, drawn[first:stop], tiles, fine, skip)
        group_start = count
        for triangle in range(first, stop):
            if skip[triangle - first]:
                continue
            # Facing away when N . (v0 - o) > 0 (o: the camera centre), which is det(a, b, c) but for
            # rounding: a triangle seen nearly edge-on may land in either pass, which changes no winner.
            if planes[triangle, 3] > planes[triangle, 0] * ox + planes[triangle, 1] * oy + planes[triangle, 2] * oz:
                deferred[count] = triangle  # drawn in the second pass (unless it draws nothing)
                count += _defer(geometry, triangle - first, rect, row_start, row_stop, deferred_closest,
                                deferred_boxes, count)
                continue
            _draw_triangle(geometry, triangle - first, triangle, rect, pixel_x, pixel_y, fx, fy, row_start,
                           row_stop, inverse_depth, winner, tiles, dirty, rank, True)
        if count > group_start:
            groups[group_count, 0], groups[group_count, 1] = cluster, count
            group_count += 1
    _refresh_tiles(row_start, row_stop, inverse_depth, tiles, dirty, fine)
    _hide_deferred(deferred, deferred_closest, deferred_boxes, groups[:group_count], tiles, fine)
    group_start = 0
    for group in range(group_count):
        cluster, group_stop = groups[group, 0], groups[group, 1]
        if group_stop == group_start:
            continue  # all proved hidden in bulk
        rect = (rects[cluster, 0], rects[cluster, 1], rects[cluster, 2], rects[cluster, 3])
        _gather(lanes, deferred[group_start:group_stop], corner_batch)
        _prepare(corner_batch, 0, group_stop - group_start, pose, x0, y0, fx, fy, geometry)
        for slot in range(group_start, group_stop):
            if _covered_tiles_behind(geometry, slot - group_start, rect, row_start, row_stop, pixel_x, pixel_y,
                                     inverse_depth, fine):
                continue
            # Without `_draw_triangle`'s tests: they would prove none that `_covered_tiles_behind` could not.
            _draw_triangle(geometry, slot - group_start, deferred[slot], rect, pixel_x, pixel_y, fx, fy, row_start,
                           row_stop, inverse_depth, winner, tiles, dirty, rank, False)
        group_start = group_stop
    for triangle in hints[:hint_count]:
        drawn[triangle] = False


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _gather(lanes, triangles, batch):  # pragma: no cover (compiled)
    """The corners of `triangles` (at most CLUSTER_SIZE) from `lanes` into `batch`, laid out as a cluster's."""
    for slot in range(len(triangles)):
        source = triangles[slot] // CLUSTER_SIZE * LANE_BLOCK + triangles[slot] % CLUSTER_SIZE
        for row in range(9):
            batch[row * CLUSTER_SIZE + slot] = lanes[source + row * CLUSTER_SIZE]


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _prepare(source, offset, count, pose, x0, y0, fx, fy, geometry):  # pragma: no cover (compiled)
    """The set-up of `count` triangles whose corners lie in `source` from `offset` as a cluster's in
    `ClusteredMesh.lanes`, into the rows of `geometry` (one column per triangle, CLUSTER_SIZE apart): the corners
    a, b, c in the camera frame (rows 0-8), det(a, b, c) (row 9) and the projection's box (rows 10-13,
    `_projected_box`). A loop without branches over rows a fixed distance apart, which the compiler vectorises
    (4 triangles per instruction), computing bit for bit what a triangle set up by itself would get: the same
    operations in the same order on each lane (no fused multiply-adds: numba does not contract)."""
    rotation = (pose[0, 0], pose[0, 1], pose[0, 2], pose[1, 0], pose[1, 1], pose[1, 2], pose[2, 0], pose[2, 1],
                pose[2, 2])  # read before the loop: its stores might otherwise alias the pose
    origin = (pose[0, 3], pose[1, 3], pose[2, 3])
    for slot in range(count):
        a = _to_camera(source, offset + slot, rotation, origin)
        b = _to_camera(source, offset + slot + 3 * CLUSTER_SIZE, rotation, origin)
        c = _to_camera(source, offset + slot + 6 * CLUSTER_SIZE, rotation, origin)
        top, bottom, left, right = _projected_box(a, b, c, x0, y0, fx, fy)
        geometry[slot], geometry[CLUSTER_SIZE + slot], geometry[2 * CLUSTER_SIZE + slot] = a
        geometry[3 * CLUSTER_SIZE + slot], geometry[4 * CLUSTER_SIZE + slot], geometry[5 * CLUSTER_SIZE + slot] = b
        geometry[6 * CLUSTER_SIZE + slot], geometry[7 * CLUSTER_SIZE + slot], geometry[8 * CLUSTER_SIZE + slot] = c
        geometry[9 * CLUSTER_SIZE + slot] = _determinant(a, b, c)
        geometry[10 * CLUSTER_SIZE + slot], geometry[11 * CLUSTER_SIZE + slot] = top, bottom
        geometry[12 * CLUSTER_SIZE + slot], geometry[13 * CLUSTER_SIZE + slot] = left, right


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _projected_box(a, b, c, x0, y0, fx, fy):  # pragma: no cover (compiled)
    """The rows and columns (top, bottom, left, right, as whole floats) whose pixel centres lie within
    SPAN_MARGIN of the bounding box of the projection of corners a, b, c (camera frame; meaningful when all
    three lie in front of the camera: other lanes of a batch get any number). x0, y0: the first column's x / z
    and row's y / z. The corners' projections err by ~1e-16 of themselves, far below the margin (see the spans
    in `_draw_triangle`)."""
    inverse_a, inverse_b, inverse_c = 1.0 / a[2], 1.0 / b[2], 1.0 / c[2]
    ya, yb, yc = a[1] * inverse_a, b[1] * inverse_b, c[1] * inverse_c
    xa, xb, xc = a[0] * inverse_a, b[0] * inverse_b, c[0] * inverse_c
    return (np.ceil((min(ya, yb, yc) - y0) * fy - SPAN_MARGIN), np.floor((max(ya, yb, yc) - y0) * fy + SPAN_MARGIN),
            np.ceil((min(xa, xb, xc) - x0) * fx - SPAN_MARGIN), np.floor((max(xa, xb, xc) - x0) * fx + SPAN_MARGIN))


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _prepared(geometry, slot):  # pragma: no cover (compiled)
    """What `_prepare` set up in column `slot`: corners a, b, c (camera frame), det(a, b, c), the projection's box."""
    a = (geometry[slot], geometry[CLUSTER_SIZE + slot], geometry[2 * CLUSTER_SIZE + slot])
    b = (geometry[3 * CLUSTER_SIZE + slot], geometry[4 * CLUSTER_SIZE + slot], geometry[5 * CLUSTER_SIZE + slot])
    c = (geometry[6 * CLUSTER_SIZE + slot], geometry[7 * CLUSTER_SIZE + slot], geometry[8 * CLUSTER_SIZE + slot])
    box = (geometry[10 * CLUSTER_SIZE + slot], geometry[11 * CLUSTER_SIZE + slot], geometry[12 * CLUSTER_SIZE + slot],
           geometry[13 * CLUSTER_SIZE + slot])
    return a, b, c, geometry[9 * CLUSTER_SIZE + slot], box


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _take_previous_winners(rank, row_start, row_stop, inverse_depth, winner, hints,
                           drawn):  # pragma: no cover (compiled)
    """Gathers into `hints` (marked in `drawn`) the distinct triangles `winner` holds in rows row_start..row_stop
    whose clusters are in this frame's view (rank >= 0), and empties those rows; returns how many.

    One loop, whose test is true for nearly every pixel (the triangle last taken, or one taken before), so that its
    branch mispredicts about once per triangle taken: 0.47-0.67 ms a bench frame (1 band; the stores alone 0.14-0.17).
    Testing a change of triangle first (once per run of ~4 pixels) took 0.89-0.91 ms, the same branch-free 0.95-0.97,
    the stores in a pass of their own 1.09-1.24; scanning every other row only (the triangles missed are drawn by the
    cluster pass, the frame unchanged) drew no faster (1.00-1.03 of the unchanged code in-process, where a control
    read 1.01-1.03)."""
    count = 0
    previous = -1
    for row in range(row_start, row_stop):
        for column in range(winner.shape[1]):
            triangle = winner[row, column]
            inverse_depth[row, column] = 0.0
            winner[row, column] = -1
            if triangle < 0 or triangle == previous or drawn[triangle]:
                continue
            previous = triangle
            if rank[triangle // CLUSTER_SIZE] < 0:  # (ClusteredMesh's clusters hold CLUSTER_SIZE triangles)
                continue
            drawn[triangle] = True
            hints[count] = triangle
            count += 1
    return count


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _drawn_before(triangle, other, rank):  # pragma: no cover (compiled)
    """True when `triangle` comes before `other` in the drawing order (clusters by rank, then index)."""
    # (ClusteredMesh's clusters hold CLUSTER_SIZE triangles each, so `starts` need not be searched)
    return (rank[triangle // CLUSTER_SIZE], triangle) < (rank[other // CLUSTER_SIZE], other)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _to_camera(source, index, rotation, origin):  # pragma: no cover (compiled)
    """The corner whose x is source[index] (y and z CLUSTER_SIZE and twice that further) in the camera frame,
    relative to the camera centre (rotation: the pose's 3 x 3 row by row, origin: its translation)."""
    px = np.float64(source[index]) - origin[0]
    py = np.float64(source[index + CLUSTER_SIZE]) - origin[1]
    pz = np.float64(source[index + 2 * CLUSTER_SIZE]) - origin[2]
    return (rotation[0] * px + rotation[3] * py + rotation[6] * pz,
            rotation[1] * px + rotation[4] * py + rotation[7] * pz,
            rotation[2] * px + rotation[5] * py + rotation[8] * pz)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _determinant(a, b, c):  # pragma: no cover (compiled)
    """det(a, b, c) = a . (b x c)."""
    e = _edge(b, c, 1.0)
    return e[0] * a[0] + e[1] * a[1] + e[2] * a[2]


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _edge(p, q, sign):  # pragma: no cover (compiled)
    """sign (p x q): the normal of the plane through the camera centre and corners p and q, times +-1."""
    return (sign * (p[1] * q[2] - p[2] * q[1]), sign * (p[2] * q[0] - p[0] * q[2]), sign * (p[0] * q[1] - p[1] * q[0]))


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _defer(geometry, slot, rect, row_start, row_stop, closest, boxes, index):  # pragma: no cover (compiled)
    """For a facing-away triangle prepared in column `slot` of `geometry`, what `_hide_deferred` tests it by:
    into closest[index] its largest inverse depth rounded up as `_occluded` rounds it (NaN when a corner lies
    within _BEHIND of the camera plane: never proved hidden), into boxes[index] the pixels of the band it may
    cover (first and last row, counted from row_start, first and last column). Returns 0 when it draws nothing
    (degenerate, behind the camera or no pixel centre: `_draw_triangle`'s early returns), so it need not be
    deferred, else 1."""
    a, b, c, det, box = _prepared(geometry, slot)
    if det == 0.0 or a[2] <= 0.0 and b[2] <= 0.0 and c[2] <= 0.0:
        return 0
    z_min = min(a[2], b[2], c[2])
    top, bottom = max(rect[0], row_start), min(rect[1], row_stop - 1)
    left, right = rect[2], rect[3]
    if z_min <= _BEHIND:
        closest[index] = np.nan
    else:
        top, bottom = max(top, int(box[0])), min(bottom, int(box[1]))
        left, right = max(left, int(box[2])), min(right, int(box[3]))
        if top > bottom or left > right:
            return 0
        closest[index] = np.float32(1.0 / z_min * (1.0 + 1e-5))
    boxes[index, 0], boxes[index, 1] = top - row_start, bottom - row_start
    boxes[index, 2], boxes[index, 3] = left, right
    return 1


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _refresh_tiles(row_start, row_stop, inverse_depth, tiles, dirty, fine):  # pragma: no cover (compiled)
    """Every occlusion tile of the band set to the smallest inverse depth of its pixels (none left dirty), and
    `fine` likewise per FINE_TILE x FINE_TILE pixels: one pass over the band's z-buffer."""
    width = inverse_depth.shape[1]
    whole = width // FINE_TILE  # fine tiles of FINE_TILE columns (a last narrower one after them)
    fine[:, :] = np.inf
    for row in range(row_start, row_stop):
        fine_row = fine[(row - row_start) // FINE_TILE]
        pixels = inverse_depth[row]
        for column in range(whole):
            at = FINE_TILE * column
            fine_row[column] = min(fine_row[column], pixels[at], pixels[at + 1], pixels[at + 2], pixels[at + 3])
        for column in range(FINE_TILE * whole, width):
            fine_row[whole] = min(fine_row[whole], pixels[column])
    step = TILE // FINE_TILE
    for tile_row in range(tiles.shape[0]):
        for tile_column in range(tiles.shape[1]):
            least = np.inf
            for fine_row_index in range(step * tile_row, min(step * (tile_row + 1), fine.shape[0])):
                for fine_column in range(step * tile_column, min(step * (tile_column + 1), fine.shape[1])):
                    least = min(least, fine[fine_row_index, fine_column])
            tiles[tile_row, tile_column] = least
    dirty[:, :] = False


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _hide_deferred(deferred, closest, boxes, groups, tiles, fine):  # pragma: no cover (compiled)
    """Drops from `deferred` (in place, keeping the order; each group's end in `groups` moved to match) the
    facing-away triangles proved hidden by their `_defer` numbers (`_box_behind`: a pixel box within a window of
    tiles that all lie at or beyond the triangle's largest inverse depth). A loop without branches on the tests,
    one triangle per step: the scalar tests of `_draw` are left to the triangles it keeps (larger boxes, failed
    tests)."""
    kept = start = 0
    for group in range(len(groups)):
        stop = groups[group, 1]
        for index in range(start, stop):
            hidden = _box_behind(closest[index], boxes[index, 0], boxes[index, 1], boxes[index, 2], boxes[index, 3],
                                 tiles, fine)
            deferred[kept] = deferred[index]
            kept += 0 if hidden else 1
        groups[group, 1] = kept
        start = stop


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _covered_tiles_behind(geometry, slot, rect, row_start, row_stop, pixel_x, pixel_y, inverse_depth,
                          fine):  # pragma: no cover (compiled)
    """True when the triangle `_prepare` set up in column `slot` of `geometry` (drawn within its cluster's pixel
    rectangle `rect`) can win no pixel of the band, proved by the FINE_TILE tiles of `fine` its pixel box falls in:
    a tile none of whose pixel centres it can cover (an edge negative at all of them) is passed over, and every other
    tile must lie at or beyond the triangle's largest inverse depth over the tile's pixels (its plane's, linear in
    the pixel ray's x and y, so largest at a corner of the tile's pixel centres; at most that of its nearest corner).

    A tile that fails is tested pixel by pixel, the same way (`_covered_pixels_behind`), so whatever the box tests of
    `_draw_triangle` prove (every pixel of the box behind the nearest corner), this proves too.

    Why: a facing-away triangle's box holds pixels it never covers, where the surface seen lies farther than its
    nearest corner (the far side of a silhouette), and a slanted one lies farther than its nearest corner over most of
    its pixels; the box tests fail on both. On the bench's consecutive poses, of the 5.1 k facing-away triangles per
    pose that `_hide_deferred` leaves, this proves all but 12 (42 k tiles and 23 k pixels tested), where runs of 4
    joint boxes and then the box tests left 1.7 k to be drawn (all hidden) after 190 k pixel tests.
    Conservative: the edge and depth values are taken at the pixel centres' extreme x and y with the arithmetic of
    `_fill_rows`, then moved by a margin (1e-12 of the sum of their terms' magnitudes) far above the rounding of
    either (~1e-15 of it), and the depth bound rounded up as `_occluded` rounds it (so a tie is never proved)."""
    a, b, c, det, box = _prepared(geometry, slot)
    if det == 0.0 or a[2] <= 0.0 and b[2] <= 0.0 and c[2] <= 0.0:
        return True  # draws nothing
    z_min = min(a[2], b[2], c[2])
    if z_min <= _BEHIND:
        return False  # it may cover any pixel of the rectangle
    top, bottom = max(rect[0], row_start, int(box[0])), min(rect[1], row_stop - 1, int(box[1]))
    left, right = max(rect[2], int(box[2])), min(rect[3], int(box[3]))
    sign = 1.0 if det > 0.0 else -1.0
    e0, e1, e2 = _edge(a, b, sign), _edge(b, c, sign), _edge(c, a, sign)
    inverse_det = 1.0 / (det * sign)
    slope_x, slope_y, offset = e0[0] + e1[0] + e2[0], e0[1] + e1[1] + e2[1], e0[2] + e1[2] + e2[2]
    reach_x = max(abs(pixel_x[0]), abs(pixel_x[-1]))
    reach_y = max(abs(pixel_y[0]), abs(pixel_y[-1]))
    margin0 = 1e-12 * (abs(e0[0]) * reach_x + abs(e0[1]) * reach_y + abs(e0[2]))
    margin1 = 1e-12 * (abs(e1[0]) * reach_x + abs(e1[1]) * reach_y + abs(e1[2]))
    margin2 = 1e-12 * (abs(e2[0]) * reach_x + abs(e2[1]) * reach_y + abs(e2[2]))
    depth_margin = margin0 + margin1 + margin2
    closest = 1.0 / z_min
    for tile_row in range((top - row_start) // FINE_TILE, (bottom - row_start) // FINE_TILE + 1):
        first_row = max(top, row_start + tile_row * FINE_TILE)
        last_row = min(bottom, row_start + tile_row * FINE_TILE + FINE_TILE - 1)
        y_low, y_high = pixel_y[first_row], pixel_y[last_row]
        row0 = max(e0[1] * y_low, e0[1] * y_high) + e0[2]
        row1 = max(e1[1] * y_low, e1[1] * y_high) + e1[2]
        row2 = max(e2[1] * y_low, e2[1] * y_high) + e2[2]
        row_depth = max(slope_y * y_low, slope_y * y_high) + offset + depth_margin
        for tile_column in range(left // FINE_TILE, right // FINE_TILE + 1):
            first_column = max(left, tile_column * FINE_TILE)
            last_column = min(right, tile_column * FINE_TILE + FINE_TILE - 1)
            x_low, x_high = pixel_x[first_column], pixel_x[last_column]
            if (max(e0[0] * x_low, e0[0] * x_high) + row0 < -margin0 or max(e1[0] * x_low, e1[0] * x_high) + row1
                    < -margin1 or max(e2[0] * x_low, e2[0] * x_high) + row2 < -margin2):
                continue  # no pixel centre of the tile is covered
            bound = _depth_bound(max(slope_x * x_low, slope_x * x_high) + row_depth, inverse_det, closest)
            if not fine[tile_row, tile_column] >= bound and not _covered_pixels_behind(
                    first_row, last_row, first_column, last_column, (e0, e1, e2), (margin0, margin1, margin2),
                    (slope_x, slope_y, offset + depth_margin), inverse_det, closest, pixel_x, pixel_y, inverse_depth):
                return False
    return True


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _covered_pixels_behind(top, bottom, left, right, edges, margins, plane, inverse_det, closest, pixel_x, pixel_y,
                           inverse_depth):  # pragma: no cover (compiled)
    """`_covered_tiles_behind` for the pixels of rows top..bottom, columns left..right (all in the band) one by one:
    True when each pixel either lies beyond an edge (`edges`: scaled as `_fill_rows` scales them; `margins`: how far)
    or holds an inverse depth of at least the triangle's there (`plane`: x and y slopes and offset with its margin)."""
    for row in range(top, bottom + 1):
        y = pixel_y[row]
        for column in range(left, right + 1):
            x = pixel_x[column]
            if (edges[0][0] * x + (edges[0][1] * y + edges[0][2]) < -margins[0]
                    or edges[1][0] * x + (edges[1][1] * y + edges[1][2]) < -margins[1]
                    or edges[2][0] * x + (edges[2][1] * y + edges[2][2]) < -margins[2]):
                continue  # not covered
            if inverse_depth[row, column] < _depth_bound(plane[0] * x + plane[1] * y + plane[2], inverse_det, closest):
                return False
    return True


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _depth_bound(plane_value, inverse_det, closest):  # pragma: no cover (compiled)
    """The float32 above any inverse depth `_fill_rows` computes where the triangle's summed edge values are at most
    `plane_value` (margin included): that over det, at most the nearest corner's `closest`, rounded up as `_occluded`
    rounds it, so that a pixel holding at least this is strictly nearer (a tie is never proved)."""
    largest = plane_value * inverse_det
    if not largest < closest:
        largest = closest  # (NaN too: an infinite 1 / det, whose pixels `_occluded` also bounds by `closest`)
    if largest < 1e-30:
        largest = 1e-30  # the plane lies behind the camera there: below anything drawn
    return np.float32(largest * (1.0 + 1e-5))


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _hide_prepared(geometry, count, rect, row_start, row_stop, drawn, tiles, fine, skip):  # pragma: no cover (compiled)
    """Into `skip`, for each of the `count` triangles `_prepare` set up in `geometry` (a cluster's, drawn within
    its pixel rectangle `rect`), whether it is flagged in `drawn` (a previous winner, drawn first), draws nothing
    (`_draw_triangle`'s early returns) or is proved hidden as `_hide_deferred` proves it (`_box_behind`), by the
    tiles as they stand (stale tiles only prove less). The compiler vectorises none of it (the windows' loads are
    scattered), so a triangle already decided (drawn before, drawing nothing, no pixel centre: most of a cluster's)
    branches past the window test: the draw took 0.957 of the branch-free loop's time (bench poses, draw over
    resolve in one process, 3 process pairs; the tiles read only when the fine window is too small: 1.09)."""
    top, bottom = max(rect[0], row_start), min(rect[1], row_stop - 1)
    left, right = rect[2], rect[3]
    for slot in range(count):
        a, b, c, det, box = _prepared(geometry, slot)
        z_min = min(a[2], b[2], c[2])
        # The box as `_draw_triangle` clips it, kept inside the rectangle whatever its numbers (a corner behind
        # the camera leaves them meaningless, NaN included: a comparison with NaN picks the rectangle's side).
        slot_top = box[0] if box[0] > top else np.float64(top)
        slot_bottom = box[1] if box[1] < bottom else np.float64(bottom)
        slot_left = box[2] if box[2] > left else np.float64(left)
        slot_right = box[3] if box[3] < right else np.float64(right)
        empty = slot_top > slot_bottom or slot_left > slot_right
        slot_top, slot_bottom = min(slot_top, np.float64(bottom)), max(slot_bottom, np.float64(top))
        slot_left, slot_right = min(slot_left, np.float64(right)), max(slot_right, np.float64(left))
        nothing = det == 0.0 or a[2] <= 0.0 and b[2] <= 0.0 and c[2] <= 0.0
        if drawn[slot] or nothing or z_min > _BEHIND and empty:
            skip[slot] = True
            continue
        if not z_min > _BEHIND:
            skip[slot] = False
            continue
        skip[slot] = _box_behind(np.float32(1.0 / z_min * (1.0 + 1e-5)), int(slot_top) - row_start,
                                 int(slot_bottom) - row_start, int(slot_left), int(slot_right), tiles, fine)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _box_behind(closest, top, bottom, left, right, tiles, fine):  # pragma: no cover (compiled)
    """True when the pixels top..bottom (counted from the band's first row), left..right lie within WINDOW x WINDOW
    FINE_TILE tiles of `fine`, or else occlusion tiles of `tiles`, whose values (each at most the least inverse
    depth of its pixels) are all at least `closest` (a triangle's largest inverse depth, rounded up)."""
    top, bottom, left, right = top // FINE_TILE, bottom // FINE_TILE, left // FINE_TILE, right // FINE_TILE
    least = _window_least(fine, top, bottom, left, right)
    within = bottom - top < WINDOW and right - left < WINDOW
    top, bottom, left, right = top // 2, bottom // 2, left // 2, right // 2  # (TILE = 2 FINE_TILE)
    least = least if within else _window_least(tiles, top, bottom, left, right)
    return least >= closest and bottom - top < WINDOW and right - left < WINDOW


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _window_least(grid, top, bottom, left, right):  # pragma: no cover (compiled)
    """The least of grid's entries in the WINDOW rows from `top` and WINDOW columns from `left`, each row and
    column clamped to `bottom` and `right`: all of the block top..bottom, left..right when it spans at most
    WINDOW x WINDOW entries (a fixed number of loads, without branches)."""
    least = np.float32(np.inf)
    for step_down in range(WINDOW):
        row = min(top + step_down, bottom)
        for step_right in range(WINDOW):
            least = min(least, grid[row, min(left + step_right, right)])
    return least


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _draw_triangle(geometry, slot, triangle, rect, pixel_x, pixel_y, fx, fy, row_start, row_stop, inverse_depth,
                   winner, tiles, dirty, rank, cull):  # pragma: no cover (compiled)
    """Z-buffer one triangle (set up in column `slot` of `geometry` by `_prepare`: corners a, b, c relative to
    the camera, camera frame, det = det(a, b, c), its projection's box) into the band's pixels: it wins a pixel
    it is nearer at, or as near as a triangle it comes before in the drawing order. With `cull`, a box of at most
    PIXELS_FIRST_BOX pixels is tested against its pixels; a larger one against the occlusion tiles, then against
    the pixels of its box (when the tiles do not cull it and the box is under PIXEL_BOX).

    The edge planes are scaled by the sign of det(a, b, c), so that inside means all three edge values >= 0.
    Negation is exact in floating point (x * -1 and -(x y + z) = (-x) y + (-z) bit for bit, but for the sign
    of a zero, which no test here tells apart), so this decides exactly as testing w * sign < 0 would."""
    a, b, c, det, projected = _prepared(geometry, slot)
    if det == 0.0:
        return  # degenerate, or seen exactly edge-on
    top, bottom = max(rect[0], row_start), min(rect[1], row_stop - 1)
    left, right = rect[2], rect[3]
    if a[2] <= 0.0 and b[2] <= 0.0 and c[2] <= 0.0:
        return  # behind the camera
    if a[2] > _BEHIND and b[2] > _BEHIND and c[2] > _BEHIND:
        # The rows and columns whose pixel centres lie within SPAN_MARGIN of the projection's bounding box
        # (`_projected_box`): most triangles of a detailed mesh are a pixel or smaller and hold no pixel centre.
        top, bottom = max(top, int(projected[0])), min(bottom, int(projected[1]))
        left, right = max(left, int(projected[2])), min(right, int(projected[3]))
        if top > bottom or left > right:
            return
        box = (bottom - top + 1) * (right - left + 1)
        if cull and box <= PIXELS_FIRST_BOX:
            if _pixels_occluded(top, bottom, left, right, min(a[2], b[2], c[2]), inverse_depth):
                return
        elif cull and (_occluded((top, bottom, left, right), min(a[2], b[2], c[2]), row_start, row_stop, inverse_depth,
                                 tiles, dirty)
                       or box <= PIXEL_BOX and _pixels_occluded(top, bottom, left, right, min(a[2], b[2], c[2]),
                                                                inverse_depth)):
            return
    _fill_rows(a, b, c, det, triangle, top, bottom, left, right, pixel_x, pixel_y, fx, row_start, inverse_depth,
               winner, dirty, rank)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _pixels_occluded(top, bottom, left, right, nearest, inverse_depth):  # pragma: no cover (compiled)
    """`_occluded` for a box of a few pixels (all in the band), pixel by pixel: cheaper than its tiles."""
    closest = np.float32(1.0 / nearest * (1.0 + 1e-5))
    for row in range(top, bottom + 1):
        for column in range(left, right + 1):
            if inverse_depth[row, column] < closest:
                return False
    return True


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _span(slope, inverse, offset, x_from, x_to):  # pragma: no cover (compiled)
    """The interval [x_from, x_to] narrowed to where slope x + offset >= 0 (inverse: 1 / slope)."""
    if slope > 0.0:
        return max(x_from, -offset * inverse), x_to
    if slope < 0.0:
        return x_from, min(x_to, -offset * inverse)
    return (x_from, -np.inf) if offset < 0.0 else (x_from, x_to)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _reciprocal(value):  # pragma: no cover (compiled)
    """1 / value, or 0 for 0 (an edge parallel to the rows bounds no column)."""
    return 1.0 / value if value != 0.0 else 0.0


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _fill_rows(a, b, c, det, triangle, top, bottom, left, right, pixel_x, pixel_y, fx, row_start, inverse_depth,
               winner, dirty, rank):  # pragma: no cover (compiled)
    """`_draw_triangle`'s pixel loop: z-buffer the triangle with corners a, b, c (camera frame, det = det(a, b, c)
    != 0) into the pixels it covers of rows top..bottom, columns left..right (all in the band): it wins a pixel
    it is nearer at, or as near as a triangle it comes before in the drawing order."""
    sign = 1.0 if det > 0.0 else -1.0
    e0, e1, e2 = _edge(a, b, sign), _edge(b, c, sign), _edge(c, a, sign)
    inverse_det = 1.0 / (det * sign)
    # Each edge's value along a row is linear in x: e[0] x + r. Only the columns within SPAN_MARGIN of where
    # all three are >= 0 are tested. That skips no pixel the exact test would take: a skipped column x lies
    # more than SPAN_MARGIN / fx beyond the zero z of some edge, where the value is -|e[0]| |x - z|, while its
    # rounding errs by at most ~4e-16 |e[0]| (|x| + |z|) (z itself, from the edge's reciprocal slope: one
    # division per edge and triangle, errs by ~2e-16 |z|). For |x|, |z| < 1e6 that is under 1e-9 |e[0]|, far
    # below |e[0]| SPAN_MARGIN / fx for any focal length under 1e5 px; for larger |z|, |x - z| ~ |z| dwarfs it.
    # A box of at most SMALL_BOX pixels is tested whole: its spans would skip only pixels that fail the test,
    # and their three divisions cost more than the pixels.
    # So is a box narrower than NARROW_BOX columns with finite edges (a sliver along the columns: its spans
    # would cost more than its few columns' tests; non-finite edges keep the spans, which skip their rows).
    # The spans' branches on the edges' slopes (fixed per triangle) cost less than selects: spans without branches
    # drew 1.00-1.03 of a control (median 1.02; in-process, 6 rounds). The tiles' index `// TILE` compiles to a shift.
    small = (bottom - top + 1) * (right - left + 1) <= SMALL_BOX or right - left < NARROW_BOX and _finite(
        e0[0] + e0[1] + e0[2] + e1[0] + e1[1] + e1[2] + e2[0] + e2[1] + e2[2])
    inverse0, inverse1, inverse2 = (0.0, 0.0, 0.0) if small else (
        _reciprocal(e0[0]), _reciprocal(e1[0]), _reciprocal(e2[0]))
    for row in range(top, bottom + 1):
        y = pixel_y[row]
        r0, r1, r2 = e0[1] * y + e0[2], e1[1] * y + e1[2], e2[1] * y + e2[2]
        first, last = left, right
        if not small:
            x_from, x_to = _span(e0[0], inverse0, r0, -np.inf, np.inf)
            x_from, x_to = _span(e1[0], inverse1, r1, x_from, x_to)
            x_from, x_to = _span(e2[0], inverse2, r2, x_from, x_to)
            low = (x_from - pixel_x[0]) * fx - SPAN_MARGIN  # in columns
            high = (x_to - pixel_x[0]) * fx + SPAN_MARGIN
            if not low <= high:
                continue  # no column (or a triangle with non-finite corners, which never wins a pixel)
            # Clamped to the columns before the int conversion (a zero may lie far outside the image).
            first = int(np.ceil(min(max(low, left), right + 1)))
            last = int(np.floor(max(min(high, right), left - 1)))
        entered = False
        # Unsigned indices (all >= 0 here): numba then skips its wrap-around of negative ones, 3 instructions per
        # index of each pixel's loads and stores that the compiler cannot prove needless (~45 per pixel stored):
        # the draw took 0.93-0.95 of a control's (bench poses, in-process, 6 rounds), the frames the same.
        at_row, tile_row = np.uint64(row), np.uint64((row - row_start) // TILE)
        for column in range(first, last + 1):
            at = np.uint64(column)
            x = pixel_x[at]
            w0, w1, w2 = e0[0] * x + r0, e1[0] * x + r1, e2[0] * x + r2
            if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                if entered:
                    break  # a row crosses a triangle in one run of pixels
                continue
            entered = True
            depth = np.float32((w0 + w1 + w2) * inverse_det)  # 1 / t: the plane's N . d over det(a, b, c)
            held = inverse_depth[at_row, at]
            if depth > held or (depth == held and held > 0.0 and _drawn_before(triangle, winner[at_row, at], rank)):
                inverse_depth[at_row, at] = depth
                winner[at_row, at] = triangle
                dirty[tile_row, np.uint64(column // TILE)] = True


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _finite(value):  # pragma: no cover (compiled)
    """True when `value` is neither infinite nor NaN (a sum of numbers is finite only when each of them is)."""
    return value - value == 0.0


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _resolve(corners, face_ids, winner, pose, pixel_x, pixel_y, row_start, row_stop, miss, depth, face, barycentric,
             normal, direction, surfaces=True):  # pragma: no cover (compiled)
    """Per pixel of rows row_start..row_stop: the ray (camera centre, R (x, y, 1) in float32, as the ray cast
    builds it) against its winning triangle with Embree's Moeller-Trumbore arithmetic (float32): t, u, v and
    the geometric normal (v1 - v0) x (v2 - v0), normalised; a miss as `EmbreeMesh.cast_rows` writes it.
    What depends on the triangle alone is computed once per run of pixels with the same winner.

    A row's directions are computed first, in a pass of their own that the compiler vectorises: R[k, 0] x + R[k, 1] y
    + R[k, 2] left to right in float64 as before (so the same bits), with the products R[k, 0] x taken once per
    frame and R[k, 1] y once per row: 11-22 % less time than computing them per pixel (bench house, 1 thread)."""
    width = len(pixel_x)
    ox, oy, oz = np.float32(pose[0, 3]), np.float32(pose[1, 3]), np.float32(pose[2, 3])
    zero = np.float32(0.0)
    column_terms = _column_terms(pose, pixel_x)
    rays = np.empty((3, width), np.float32)  # the row's directions, one component per row of the scratch
    current, frame, unit = -1, _triangle_frame(np.zeros((1, 3, 3), np.float32), 0, ox, oy, oz), (zero, zero, zero)
    for row in range(row_start, row_stop):
        _row_rays(column_terms, pose, pixel_y[row], rays)
        for column in range(width):
            dx, dy, dz = rays[0, column], rays[1, column], rays[2, column]
            if surfaces:
                direction[row, column, 0], direction[row, column, 1], direction[row, column, 2] = dx, dy, dz
            triangle = winner[row, column]
            t = zero
            if triangle >= 0:
                if triangle != current:
                    current, frame = triangle, _triangle_frame(corners, triangle, ox, oy, oz)
                    unit = _unit_normal(frame)
                t, u, v = _intersect(frame, dx, dy, dz)
            if not (t > 0.0 and t < np.inf):  # no triangle, or one the ray only grazes (no hit to report)
                depth[row, column] = np.inf
                face[row, column] = miss
                barycentric[row, column, 0] = barycentric[row, column, 1] = 0.0
                if surfaces:
                    normal[row, column, 0] = normal[row, column, 1] = normal[row, column, 2] = 0.0
                continue
            depth[row, column] = t
            face[row, column] = face_ids[triangle]
            barycentric[row, column, 0], barycentric[row, column, 1] = u, v
            if surfaces:
                normal[row, column, 0], normal[row, column, 1], normal[row, column, 2] = unit


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _column_terms(pose, pixel_x):  # pragma: no cover (compiled)
    """(3, W) float64 R[k, 0] x per column: the part of every ray `_row_rays` takes once per frame."""
    column_terms = np.empty((3, len(pixel_x)), np.float64)
    for k in range(3):
        for column in range(len(pixel_x)):
            column_terms[k, column] = pose[k, 0] * pixel_x[column]
    return column_terms


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _row_rays(column_terms, pose, y, rays):  # pragma: no cover (compiled)
    """The world-frame directions of a row of pixels (camera-frame y) into `rays` (3, W) float32: R[k, 0] x + R[k, 1]
    y + R[k, 2] left to right in float64, as the ray cast builds them (a loop the compiler vectorises)."""
    for k in range(3):
        row_term, offset = pose[k, 1] * y, pose[k, 2]
        for column in range(rays.shape[1]):
            rays[k, column] = np.float32(column_terms[k, column] + row_term + offset)


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _triangle_frame(corners, triangle, ox, oy, oz):  # pragma: no cover (compiled)
    """What Embree's Moeller-Trumbore (float32) computes per triangle and ray origin: the edges e1 = v0 - v1,
    e2 = v2 - v0, the geometric normal Ng = e2 x e1 = (v1 - v0) x (v2 - v0) (not normalised), c = v0 - o,
    and Ng . c; flat, in that order. The corners are read as scalars, not through a view `corners[triangle]`
    and its reference counting, once per run of ~4 pixels on a bench frame (~3 % of a resolve)."""
    v0x, v0y, v0z = corners[triangle, 0, 0], corners[triangle, 0, 1], corners[triangle, 0, 2]
    v1x, v1y, v1z = corners[triangle, 1, 0], corners[triangle, 1, 1], corners[triangle, 1, 2]
    v2x, v2y, v2z = corners[triangle, 2, 0], corners[triangle, 2, 1], corners[triangle, 2, 2]
    e1x, e1y, e1z = v0x - v1x, v0y - v1y, v0z - v1z
    e2x, e2y, e2z = v2x - v0x, v2y - v0y, v2z - v0z
    nx, ny, nz = e2y * e1z - e2z * e1y, e2z * e1x - e2x * e1z, e2x * e1y - e2y * e1x
    cx, cy, cz = v0x - ox, v0y - oy, v0z - oz
    return e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, cx, cy, cz, nx * cx + ny * cy + nz * cz


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _unit_normal(frame):  # pragma: no cover (compiled)
    """The geometric normal of a `_triangle_frame`, normalised in float32: the hits' `normal`."""
    length = np.sqrt(frame[6] * frame[6] + frame[7] * frame[7] + frame[8] * frame[8])
    return frame[6] / length, frame[7] / length, frame[8] / length


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _intersect(frame, dx, dy, dz):  # pragma: no cover (compiled)
    """Embree's Moeller-Trumbore in float32: (t, u, v) of the ray o + t d in the plane of the triangle whose
    `_triangle_frame` (for origin o) is `frame`."""
    e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, cx, cy, cz, normal_dot_c = frame
    rx, ry, rz = cy * dz - cz * dy, cz * dx - cx * dz, cx * dy - cy * dx
    den = nx * dx + ny * dy + nz * dz
    sign = np.float32(1.0) if den >= 0 else np.float32(-1.0)
    absolute = abs(den)
    u = (rx * e2x + ry * e2y + rz * e2z) * sign / absolute
    v = (rx * e1x + ry * e1y + rz * e1z) * sign / absolute
    t = normal_dot_c * sign / absolute
    return t, u, v
