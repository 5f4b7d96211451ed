"""Grid shortest paths on hand-drawn navigable areas: coarse search, expansion, fallback to the fine grid."""

from __future__ import annotations

import numpy as np

from pipeline.plan.navigable import NavigableArea, label_islands
from pipeline.plan.search import PathSearch


def area_from_mask(mask: np.ndarray) -> NavigableArea:
    """A flat (y = 0) single-layer navigable area of 0.1 m cells from a boolean picture (rows = z)."""
    heights = np.where(mask, 0.0, np.nan)[None].astype(np.float32)
    area = NavigableArea(origin=np.zeros(2), resolution=0.1, heights=heights, navigable=mask[None].copy(),
                         islands=np.full((1, *mask.shape), -1, np.int32), max_step=0.2)
    area.islands = label_islands(area)
    return area


def node_at(search: PathSearch, row: int, col: int) -> int:
    """Node id of the cell (row, col)."""
    return int(np.flatnonzero((search.rows == row) & (search.cols == col))[0])


def assert_grid_path(search: PathSearch, nodes: np.ndarray, start: int, goal: int) -> None:
    """The nodes go from start to goal, each step to one of the 8 neighbouring cells."""
    assert nodes[0] == start and nodes[-1] == goal
    steps = np.abs(np.stack([np.diff(search.rows[nodes]), np.diff(search.cols[nodes])]))
    assert steps.max() == 1  # every step goes to one of the 8 neighbouring cells


def test_open_floor_path_is_straight_and_made_of_neighbouring_cells():
    search = PathSearch(area_from_mask(np.ones((21, 41), dtype=bool)))
    start, goal = node_at(search, 3, 1), node_at(search, 3, 38)  # odd row: both ends attach to the coarse grid
    nodes = search.shortest_path(start, goal, (np.inf,))
    assert_grid_path(search, nodes, start, goal)
    # The coarse grid runs on even rows: one diagonal step onto it and one off it, never a detour.
    assert len(nodes) <= 38 + 1 and set(search.rows[nodes]) <= {2, 3, 4}


def test_a_corridor_one_cell_wide_on_an_odd_row_is_found_through_the_fine_grid():
    mask = np.zeros((11, 31), dtype=bool)
    mask[:, :10] = True
    mask[:, 21:] = True
    mask[5, 10:21] = True  # row 5 has no coarse node: the coarse graph is cut there
    search = PathSearch(area_from_mask(mask))
    start, goal = node_at(search, 5, 2), node_at(search, 5, 28)
    assert search.coarse_component[search._coarse_index(node_at(search, 4, 2))] != \
        search.coarse_component[search._coarse_index(node_at(search, 4, 28))]
    nodes = search.shortest_path(start, goal, (np.inf,))
    assert_grid_path(search, nodes, start, goal)
    assert set(search.rows[nodes[(search.cols[nodes] >= 10) & (search.cols[nodes] <= 20)]]) == {5}


def test_a_path_longer_than_the_limit_is_not_returned():
    search = PathSearch(area_from_mask(np.ones((5, 61), dtype=bool)))
    start, goal = node_at(search, 2, 0), node_at(search, 2, 60)  # 6 m apart
    assert search.shortest_path(start, goal, (1.0, 5.0)) is None
    assert search.shortest_path(start, goal, (1.0, 6.5)) is not None  # found by the wider second search
