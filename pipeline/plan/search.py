"""Shortest grid paths between navigable nodes, searched on a graph of every other row and column.

Dijkstra's cost grows with the nodes it settles, and drawing a scene's trajectories runs it for every
start/goal draw (about twice as many draws as kept paths). So the search runs on the *coarse* graph:
the navigable nodes whose row and column are both even, linked when a fine two-step path joins them
(a quarter of the nodes). The coarse path is then expanded back into fine nodes, so it is a path of
the navigable grid; string pulling (paths.py) straightens it afterwards, so the coarse detour costs
nothing in the result. Where the coarse graph cannot connect a pair that the fine graph connects (a
passage one cell wide), the search falls back to the fine graph.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from pipeline.plan.navigable import NavigableArea


class PathSearch:
    """Shortest paths on one navigable area (node ids as in `NavigableArea.node_cells()`)."""

    def __init__(self, area: NavigableArea) -> None:
        self.area = area
        self.layers, self.rows, self.cols = area.node_cells()
        self.x, self.z = area.cell_centres(self.rows, self.cols)
        self.y = area.heights[self.layers, self.rows, self.cols].astype(np.float64)
        self.fine = area.graph()
        self.ids = np.full(area.navigable.shape, -1, dtype=np.int64)
        self.ids[self.layers, self.rows, self.cols] = np.arange(len(self.layers))
        self.is_coarse = (self.rows % 2 == 0) & (self.cols % 2 == 0)
        self.coarse_nodes = np.flatnonzero(self.is_coarse)
        self.coarse = self._coarse_graph()
        _, self.coarse_component = connected_components(self.coarse, directed=False)

    def _coarse_graph(self) -> csr_matrix:
        """Coarse nodes linked (both ways) when two fine links join them, weighted by their 3D distance."""
        pattern = self.fine.copy()
        pattern.data = np.ones_like(pattern.data)
        two_steps = (pattern[self.coarse_nodes] @ pattern[:, self.coarse_nodes]).tocoo()
        keep = two_steps.row != two_steps.col
        source, target = two_steps.row[keep], two_steps.col[keep]
        a, b = self.coarse_nodes[source], self.coarse_nodes[target]
        weights = np.sqrt((self.x[a] - self.x[b]) ** 2 + (self.z[a] - self.z[b]) ** 2 + (self.y[a] - self.y[b]) ** 2)
        count = len(self.coarse_nodes)
        return csr_matrix((weights, (source, target)), shape=(count, count))

    def shortest_path(self, start: int, goal: int, limits: tuple[float, ...]) -> np.ndarray | None:
        """Fine node ids from start to goal, or None when the path is longer than the last limit (metres).

        Each limit in turn bounds how far the search explores; a later, wider limit is tried only
        when the goal was not reached within the earlier one.
        """
        entry, exit_ = self._attach(start), self._attach(goal)
        if entry is None or exit_ is None or self._component(entry[-1]) != self._component(exit_[-1]):
            return self._search(self.fine, start, goal, limits, lambda nodes: nodes)
        middle = self._search(self.coarse, self._coarse_index(entry[-1]), self._coarse_index(exit_[-1]), limits,
                              self._expand)
        if middle is None:
            return None
        return _without_repeats(np.concatenate([entry[:-1], middle, exit_[::-1][1:]]))

    def _coarse_index(self, node: int) -> int:
        return int(np.searchsorted(self.coarse_nodes, node))

    def _component(self, coarse_node: int) -> int:
        """Connected component of the coarse graph that a coarse node (fine id) belongs to."""
        return int(self.coarse_component[self._coarse_index(coarse_node)])

    @staticmethod
    def _search(graph: csr_matrix, start: int, goal: int, limits: tuple[float, ...],
                to_fine: Callable[[np.ndarray], np.ndarray]) -> np.ndarray | None:
        """Dijkstra from start with each limit in turn until the goal is reached; nodes mapped by `to_fine`."""
        for limit in limits:
            distances, predecessors, _ = dijkstra(graph, indices=[start], return_predecessors=True, limit=limit,
                                                  min_only=True)
            if np.isfinite(distances[goal]):
                nodes = [goal]
                while nodes[-1] != start:
                    nodes.append(int(predecessors[nodes[-1]]))
                return to_fine(np.array(nodes[::-1], dtype=np.int64))
        return None

    def _attach(self, node: int) -> np.ndarray | None:
        """Fine nodes from `node` to its nearest coarse node within two links ([node] if it is coarse)."""
        if self.is_coarse[node]:
            return np.array([node])
        best: tuple[float, int, int] | None = None
        for first in self._neighbours(node):
            hops = [(first, first)] if self.is_coarse[first] else [(first, n) for n in self._neighbours(first)
                                                                   if self.is_coarse[n]]
            for via, coarse in hops:
                cost = self._distance(node, via) + (self._distance(via, coarse) if via != coarse else 0.0)
                if best is None or (cost, via, coarse) < best:
                    best = (cost, int(via), int(coarse))
        if best is None:
            return None
        _, via, coarse = best
        return np.array([node, coarse] if via == coarse else [node, via, coarse])

    def _expand(self, coarse_path: np.ndarray) -> np.ndarray:
        """Fine nodes of a coarse path: a shared fine neighbour between each pair of coarse nodes."""
        nodes = self.coarse_nodes[coarse_path]
        if len(nodes) < 2:
            return nodes
        a, b = nodes[:-1], nodes[1:]
        middle = self._straight_middles(a, b)
        for k in np.flatnonzero(middle < 0):
            shared = np.intersect1d(self._neighbours(a[k]), self._neighbours(b[k]))
            middle[k] = shared[0]  # a coarse link exists only where a shared neighbour does
        path = np.empty(2 * len(nodes) - 1, dtype=np.int64)
        path[0::2], path[1::2] = nodes, middle
        return path

    def _straight_middles(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The fine node halfway between each pair, when it links to both (else -1)."""
        rows, cols = (self.rows[a] + self.rows[b]) // 2, (self.cols[a] + self.cols[b]) // 2
        candidates = self.ids[:, rows, cols]  # (L, P)
        heights = np.where(candidates >= 0, self.y[np.maximum(candidates, 0)], np.nan)
        step = self.area.max_step
        fits = (np.abs(heights - self.y[a]) <= step) & (np.abs(heights - self.y[b]) <= step)
        offset = np.where(fits, np.abs(heights - (self.y[a] + self.y[b]) / 2.0), np.inf)
        best = np.argmin(offset, axis=0)
        chosen = candidates[best, np.arange(len(a))]
        return np.where(np.isfinite(offset[best, np.arange(len(a))]), chosen, -1)

    def _neighbours(self, node: int) -> np.ndarray:
        return self.fine.indices[self.fine.indptr[node]:self.fine.indptr[node + 1]]

    def _distance(self, a: int, b: int) -> float:
        return math.sqrt((self.x[a] - self.x[b]) ** 2 + (self.z[a] - self.z[b]) ** 2 + (self.y[a] - self.y[b]) ** 2)


def _without_repeats(nodes: np.ndarray) -> np.ndarray:
    keep = np.ones(len(nodes), dtype=bool)
    keep[1:] = nodes[1:] != nodes[:-1]
    return nodes[keep]
