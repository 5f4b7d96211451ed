"""The z-buffer's pixel loop (raster._fill_rows): rows by their spans, narrow and small boxes column by column,
and either way exactly what the bare per-pixel rule writes."""

from __future__ import annotations

import numpy as np

from pipeline.render.raster import CLUSTER_SIZE, NARROW_BOX, TILE, _fill_rows

WIDTH, HEIGHT, FOCAL = 53, 29, 24.0
PIXEL_X = (np.arange(WIDTH) + 0.5 - 26.2) / FOCAL
PIXEL_Y = (np.arange(HEIGHT) + 0.5 - 14.7) / FOCAL


def _rule(corners: np.ndarray, triangle: int, window: tuple[int, int, int, int], depths: np.ndarray,
          winners: np.ndarray, rank: np.ndarray) -> None:
    """The bare rule, every pixel of the window tested (no spans, no runs): the triangle wins a pixel where its
    three edge values (signed by det(a, b, c)) are >= 0 and its float32 1 / t is larger than the held one, or
    equal (and not 0) when it comes before the held winner in the drawing order (cluster rank, then index)."""
    a, b, c = (tuple(float(v) for v in corner) for corner in corners)
    det = (b[1] * c[2] - b[2] * c[1]) * a[0] + (b[2] * c[0] - b[0] * c[2]) * a[1] + (b[0] * c[1] - b[1] * c[0]) * a[2]
    sign = 1.0 if det > 0.0 else -1.0
    top, bottom, left, right = window
    x, y = PIXEL_X[None, left:right + 1], PIXEL_Y[top:bottom + 1, None]
    inside = np.ones((bottom - top + 1, right - left + 1), bool)
    total = 0.0
    for p, q in ((a, b), (b, c), (c, a)):
        edge = (sign * (p[1] * q[2] - p[2] * q[1]), sign * (p[2] * q[0] - p[0] * q[2]), sign * (p[0] * q[1] - p[1] * q[0]))
        value = edge[0] * x + (edge[1] * y + edge[2])
        inside &= value >= 0.0
        total = total + value
    with np.errstate(invalid="ignore", over="ignore"):
        depth = (total * (1.0 / (det * sign))).astype(np.float32)
    held = depths[top:bottom + 1, left:right + 1]
    held_winner = winners[top:bottom + 1, left:right + 1]
    before = _before(triangle, held_winner, rank)
    wins = inside & ((depth > held) | ((depth == held) & (held > 0.0) & before))
    held[wins] = depth[wins]
    held_winner[wins] = triangle


def _before(triangle: int, others: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Whether `triangle` comes before each of `others` in the drawing order (clusters by rank, then index)."""
    mine, theirs = rank[triangle // CLUSTER_SIZE], rank[np.maximum(others, 0) // CLUSTER_SIZE]
    return (mine < theirs) | ((mine == theirs) & (triangle < others))


def _draw_both(triangles: list[tuple[np.ndarray, int, tuple[int, int, int, int]]], rank: np.ndarray,
               row_start: int = 0) -> np.ndarray:
    """Draw the triangles (corners in the camera frame, index, window) with `_fill_rows` and with the bare rule,
    one after the other, and check after each that both hold the same pixels and that every tile written to is
    flagged dirty; returns the winners."""
    ours_depth, ours_winner = np.zeros((HEIGHT, WIDTH), np.float32), np.full((HEIGHT, WIDTH), -1, np.int64)
    rule_depth, rule_winner = ours_depth.copy(), ours_winner.copy()
    dirty = np.zeros((-(-(HEIGHT - row_start) // TILE), -(-WIDTH // TILE)), bool)
    for corners, triangle, window in triangles:
        a, b, c = (tuple(float(v) for v in corner) for corner in corners)
        det = (b[1] * c[2] - b[2] * c[1]) * a[0] + (b[2] * c[0] - b[0] * c[2]) * a[1] + (b[0] * c[1] - b[1] * c[0]) * a[2]
        if det == 0.0:
            continue  # `_draw_triangle` returns before its pixel loop
        before = ours_winner.copy()
        _fill_rows(a, b, c, det, triangle, *window, PIXEL_X, PIXEL_Y, FOCAL, row_start, ours_depth, ours_winner,
                   dirty, rank)
        _rule(corners, triangle, window, rule_depth, rule_winner, rank)
        assert np.array_equal(ours_winner, rule_winner), triangle
        assert np.array_equal(ours_depth.view(np.uint32), rule_depth.view(np.uint32)), triangle
        rows, columns = np.nonzero(ours_winner != before)
        assert dirty[(rows - row_start) // TILE, columns // TILE].all()
    return ours_winner


def _random_triangles(rng: np.random.Generator, count: int, spread: float) -> np.ndarray:
    """`count` triangles 1-4 m in front of the camera, about `spread` m across (camera frame)."""
    centres = rng.uniform([-1.2, -0.7, 1.0], [1.2, 0.7, 4.0], (count, 1, 3))
    return centres + rng.normal(0.0, spread, (count, 3, 3))


def test_spans_narrow_and_small_boxes_write_what_the_bare_rule_writes() -> None:
    """Large triangles (rows by their spans), small ones and slivers, over each other, in windows cut by the image
    edge and the band's first row, some narrower than NARROW_BOX columns (tested column by column)."""
    rng = np.random.default_rng(31)
    corners = np.concatenate([_random_triangles(rng, 60, 0.6), _random_triangles(rng, 120, 0.05)])
    rank = rng.permutation(4)
    full = (6, HEIGHT - 1, 0, WIDTH - 1)
    triangles = [(corners[k], int(rng.integers(0, 4 * CLUSTER_SIZE)), full) for k in range(len(corners))]
    triangles += [(corners[k], int(rng.integers(0, 4 * CLUSTER_SIZE)), (9, 15, 40, WIDTH - 1)) for k in range(40)]
    triangles += [(corners[k], int(rng.integers(0, 4 * CLUSTER_SIZE)), (7, 8, 3, 4)) for k in range(20)]
    triangles += [(corners[k], int(rng.integers(0, 4 * CLUSTER_SIZE)), (6, HEIGHT - 1, 20, 20 + NARROW_BOX - 1 - k % 3))
                  for k in range(60)]
    winner = _draw_both(triangles, rank, row_start=6)
    assert (winner[6:] >= 0).mean() > 0.5 and (winner[:6] < 0).all()


def test_exact_depth_ties_go_to_the_first_triangle_in_the_drawing_order() -> None:
    """The same large triangle under several indices and clusters (bit-identical depths at every pixel),
    drawn in an order other than the drawing order: each pixel goes to the first in the drawing order (by
    cluster rank, then index). Also a quad split along its diagonal (ties on the shared edge)."""
    rng = np.random.default_rng(5)
    big = _random_triangles(rng, 6, 0.7)
    rank = np.array([2, 0, 3, 1])
    full = (0, HEIGHT - 1, 0, WIDTH - 1)
    indices = [3 * CLUSTER_SIZE + 5, 1 * CLUSTER_SIZE + 9, 1 * CLUSTER_SIZE + 2, 2 * CLUSTER_SIZE]
    triangles = [(big[k], index, full) for k in range(len(big)) for index in indices]
    quad = np.array([[-1.0, -0.6, 2.0], [1.1, -0.5, 2.5], [1.0, 0.7, 3.0], [-0.9, 0.6, 2.2]])
    triangles += [(quad[[0, 1, 2]], 2 * CLUSTER_SIZE + 7, full), (quad[[0, 2, 3]], 2 * CLUSTER_SIZE + 8, full),
                  (quad[[2, 0, 1]], CLUSTER_SIZE + 40, full)]
    winner = _draw_both(triangles, rank)
    assert (winner == 1 * CLUSTER_SIZE + 2).any()  # the first in the drawing order of the copies


def test_rows_with_non_finite_corners_or_corners_behind_the_camera_write_what_the_bare_rule_writes() -> None:
    """Corners at infinity or NaN (no pixel), and triangles reaching behind the camera (edge values of any size,
    spans from far outside the image), in wide windows and narrow ones."""
    rng = np.random.default_rng(13)
    corners = _random_triangles(rng, 80, 0.8)
    corners[:20, 0, 2] = -rng.uniform(0.1, 3.0, 20)  # one corner behind the camera
    corners[20:30, 1] = corners[20:30, 1] * np.where(rng.random((10, 1)) < 0.5, np.inf, -np.inf)
    corners[30:35, 2, 0] = np.nan
    corners[35:40, 2, 1] = 1e300
    rank = np.arange(2)
    full = (0, HEIGHT - 1, 0, WIDTH - 1)
    narrow = (0, HEIGHT - 1, 30, 30 + NARROW_BOX - 2)
    _draw_both([(corners[k], int(rng.integers(0, 2 * CLUSTER_SIZE)), window) for k in range(len(corners))
                for window in (full, narrow)], rank)
