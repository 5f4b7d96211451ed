"""`IndirectGather`: the indirect light of the spot at every pixel of a frame, from the steps of this package.

Per frame: the virtual lights of the pose (light_paths.py); gather points every `gather_stride` pixels, each
summing the lights of its subset past shadow rays (grid.py, shadow_rays.py) and the near field the clamp leaves
out (near_field.py); the interleave filter, twice (filter.py); the blocks of pixels from the four nearest points
(upsample.py), and the orphan blocks that none of them lies on gathered on a finer grid of their own.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from pipeline.config import Illumination
from pipeline.render.embree import EmbreeMesh
from pipeline.render.indirect.filter import interleave_filter
from pipeline.render.indirect.grid import CHANNELS, GatherGrid
from pipeline.render.indirect.light_paths import LightPaths, VirtualLights
from pipeline.render.indirect.near_field import add_near_field, near_directions
from pipeline.render.indirect.sampling import SEED_STREAM
from pipeline.render.indirect.shadow_rays import gather_lights, light_rows
from pipeline.render.indirect.upsample import upsample_blocks
from pipeline.render.lighting import INDIRECT_BLOCK, SurfaceColors
from pipeline.render.material import reflection_tables
from pipeline.render.raycaster import RayHits, row_bands, thread_pool

# Orphan blocks (`_fill_orphans`) share one gather point per ORPHAN_CELL x ORPHAN_CELL blocks (of 1 pixel): a cell
# of 3 x 3 pixels measured the same PSNR (35.85 against 35.92 dB median) at 4x the orphans' gather points, and
# 12 x 12 the same as 6 x 6 (median over the 8 bench poses, seeds 0 / 1: 36.07 / 35.80 against 36.09 / 35.77 dB)
# at about half the orphans' points (35-271 against 65-517 per frame) and ~2.5 ms less CPU per frame.
ORPHAN_CELL = 12


class IndirectGather:
    """Indirect irradiance of one spot light at every pixel of a camera, in one scene.

    Args:
        mesh: the scene's BVH (shared with the camera rays).
        colors: the scene's albedo lookup.
        illumination: the spot (its `indirect` settings; `bounces` must be > 0).
        seed: the job's seed: it fixes the pattern of light directions for every frame.
        threads: threads per frame (bands of gather rows).
    """

    def __init__(self, mesh: EmbreeMesh, colors: SurfaceColors, illumination: Illumination, seed: int, threads: int = 1):
        self.mesh, self.colors, self.illumination = mesh, colors, illumination
        self.settings = illumination.indirect
        self.threads = max(1, threads)
        self.tables = reflection_tables(illumination)
        self._seed, self._near_cache = seed, {}
        self.paths = LightPaths(mesh, colors, illumination, np.random.default_rng([seed, SEED_STREAM]))

    def virtual_lights(self, camera_to_world: np.ndarray) -> VirtualLights:
        """The virtual lights of the spot at `camera_to_world` (`LightPaths.virtual_lights`)."""
        return self.paths.virtual_lights(camera_to_world)

    def irradiance_at(self, points: np.ndarray, normals: np.ndarray, camera_to_world: np.ndarray) -> np.ndarray:
        """(n, 6) indirect light at surface points (n, 3) with unit normals (n, 3) facing the side to light,
        from every virtual light of the spot at `camera_to_world` and the near field (no interleaving, no
        filter): the irradiance E (W/m^2, RGB) and the glossy term G (RGB; the points' lobe reflects G / pi towards the camera): the
        estimator itself, for checks against analytic cases."""
        lights = self.virtual_lights(camera_to_world)
        starts = np.array([0, len(lights.positions)], np.int64)
        camera = np.asarray(camera_to_world, np.float32)[:3, 3]
        eyes = camera - np.asarray(points, np.float32)
        eyes /= np.linalg.norm(eyes, axis=1, keepdims=True)
        depth = np.ones((1, len(points)), np.float32)
        out = np.zeros((1, len(points), CHANNELS), np.float32)
        points, normals = np.asarray(points, np.float32)[None], np.asarray(normals, np.float32)[None]
        self._gather(points, normals, eyes[None], depth, 0, 1, light_rows(lights), starts, out)
        local = self._near_directions(1, points.shape[1])
        self._near_field(points, normals, eyes[None], depth, local, camera_to_world, out)
        return out[0]

    def irradiance(self, hits: RayHits, camera_to_world: np.ndarray, out: np.ndarray | None = None,
                   lights: VirtualLights | None = None) -> np.ndarray:
        """(ceil(H / INDIRECT_BLOCK), ceil(W / INDIRECT_BLOCK), 6) float32 indirect light: one value per
        INDIRECT_BLOCK x INDIRECT_BLOCK pixels, at the surface of the block's first pixel, 0 where that pixel
        hit nothing: irradiance E (W/m^2, RGB) and glossy term G (RGB), as `irradiance_at`. `lights`: this
        pose's `virtual_lights`, when already traced (the renderer traces them beside the camera rays)."""
        lights = self.virtual_lights(camera_to_world) if lights is None else lights
        order = np.argsort(lights.groups, kind="stable")
        group_count = self.settings.interleave ** 2
        starts = np.searchsorted(lights.groups[order], np.arange(group_count + 1)).astype(np.int64)
        # Each gather point sees one subset: its lights shine group_count times as bright.
        lights = VirtualLights(lights.positions[order], lights.normals[order], lights.incoming[order],
                               lights.flux[order] * np.float32(group_count),
                               lights.coloured_flux[order] * np.float32(group_count), lights.groups[order])
        rows = light_rows(lights)  # once per frame: every band of both grids reads them
        origin = np.asarray(camera_to_world, np.float32)[:3, 3].copy()
        stride = self.settings.gather_stride
        grid = GatherGrid(hits.depth, hits.normal, hits.direction, origin, stride)
        combined = self._gather_filtered(grid, rows, starts, camera_to_world)
        height, width = hits.depth.shape
        out = (np.empty((-(-height // INDIRECT_BLOCK), -(-width // INDIRECT_BLOCK), CHANNELS), np.float32)
               if out is None else out)
        orphans = np.zeros(out.shape[:2], np.bool_)

        def upsample(band: slice) -> None:
            upsample_blocks(combined, grid.points, grid.normals, grid.depth, hits.depth, hits.direction, hits.normal, origin,
                            stride, INDIRECT_BLOCK, band.start, out[band], orphans[band])

        self._run_bands(upsample, len(out))
        self._fill_orphans(hits, origin, orphans, rows, starts, camera_to_world, out)
        return out

    def _gather_filtered(self, grid: GatherGrid, lights: np.ndarray, starts: np.ndarray,
                         camera_to_world: np.ndarray) -> np.ndarray:
        """(rows, columns, 6) light at the points of `grid`: each point's subset of `lights` (`light_rows`) and its
        near field, then the interleave filter."""
        rows, columns = grid.depth.shape
        interleave = self.settings.interleave
        gathered = np.zeros((rows, columns, CHANNELS), np.float32)
        local = self._near_directions(rows, columns)

        def gather(band: slice) -> None:
            points, normals, eyes, depth = grid.points[band], grid.normals[band], grid.eyes[band], grid.depth[band]
            self._gather(points, normals, eyes, depth, band.start, interleave, lights, starts, gathered[band])
            self._near_field(points, normals, eyes, depth, local[band], camera_to_world, gathered[band])

        self._run_bands(gather, rows)
        # Twice: the first pass sums every subset once, the second smooths what few lights per subset leave
        # (at 1024 lights per bounce: median PSNR 30.7 -> 31.3 dB against the reference).
        combined, smoothed = np.zeros_like(gathered), np.zeros_like(gathered)
        for source, target in ((gathered, smoothed), (smoothed, combined)):
            self._run_bands(lambda band: interleave_filter(source, grid.points, grid.normals, grid.depth, interleave,
                                                            band, target), rows)
        return combined

    def _fill_orphans(self, hits: RayHits, origin: np.ndarray, orphans: np.ndarray, lights: np.ndarray,
                      starts: np.ndarray, camera_to_world: np.ndarray, out: np.ndarray) -> None:
        """Gather the light of the `orphans` blocks of `out` anew. Their surface has none of the four gather points
        around them: a door frame, a wall seen edge-on, the top of a box, narrower than the gather stride. Taking
        a point of another surface instead left 1-3 % of the pixels with 10-50 % of the squared error against the
        reference. Here every ORPHAN_CELL x ORPHAN_CELL blocks with an orphan get a gather point (at their first
        orphan), filtered with the points around it, which lends its light to the orphans of its cell (a point
        per 2 x 2 blocks measured the same PSNR at 1.5x the extra CPU time)."""
        if not orphans.any():
            return
        rows, columns = orphans.shape
        cell = ORPHAN_CELL
        cells = np.zeros((-(-rows // cell), cell, -(-columns // cell), cell), np.bool_)
        cells.reshape(cell * cells.shape[0], cell * cells.shape[2])[:rows, :columns] = orphans
        cells = cells.transpose(0, 2, 1, 3).reshape(cells.shape[0], cells.shape[2], cell * cell)
        first = cells.argmax(axis=2)
        block_rows = cell * np.arange(cells.shape[0])[:, None] + first // cell
        block_columns = cell * np.arange(cells.shape[1])[None, :] + first % cell
        pixels = (INDIRECT_BLOCK * block_rows, INDIRECT_BLOCK * block_columns)
        grid = GatherGrid(hits.depth[pixels], hits.normal[pixels], hits.direction[pixels], origin, 1)
        grid.depth[~cells.any(axis=2)] = np.inf
        combined = self._gather_filtered(grid, lights, starts, camera_to_world)
        orphan_rows, orphan_columns = np.nonzero(orphans)
        out[orphan_rows, orphan_columns] = combined[orphan_rows // cell, orphan_columns // cell]

    def _near_field(self, points: np.ndarray, normals: np.ndarray, eyes: np.ndarray, depth: np.ndarray,
                    local: np.ndarray, camera_to_world: np.ndarray, gathered: np.ndarray) -> None:
        """Add the near field of the points to `gathered` (near_field.add_near_field)."""
        add_near_field(self.mesh, self.colors, self.illumination, self.tables, points, normals, eyes, depth, local,
                       camera_to_world, gathered)

    def _near_directions(self, rows: int, columns: int) -> np.ndarray:
        """The near-field directions of a grid of rows x columns gather points (cached: the frame's grid and the
        grid of its orphan blocks)."""
        if (rows, columns) not in self._near_cache:
            self._near_cache[rows, columns] = near_directions(self._seed, rows, columns)
        return self._near_cache[rows, columns]

    def _gather(self, points: np.ndarray, normals: np.ndarray, eyes: np.ndarray, depth: np.ndarray, row_offset: int,
                interleave: int, lights: np.ndarray, starts: np.ndarray, out: np.ndarray) -> None:
        """Add to `out` what the lights (`light_rows`) of each point's subset bring it (shadow_rays.gather_lights)."""
        gather_lights(self.mesh, self.tables, self.settings.clamp_distance, self._seed, points, normals, eyes, depth,
                      row_offset, interleave, lights, starts, out)

    def _run_bands(self, work: Callable[[slice], None], rows: int) -> None:
        """`work` on bands of `rows` rows, on this gather's threads (inline with one thread)."""
        bands = row_bands(rows, self.threads)
        if len(bands) == 1:
            work(bands[0])
        else:
            list(thread_pool(self.threads).map(work, bands))
