"""Indirect light of the spot at the camera: virtual point lights, gathered with shadow rays (instant radiosity).

Beside the direct term (lighting.py), not inside it, as Mitsuba keeps `direct` and `path` apart: this
module returns the irradiance E_indirect (W/m^2, RGB) that bounced light brings to each pixel's surface,
and the glossy term its lobe sends to the eye; the shader reflects both (material.py). Per frame:

1. Virtual lights. Rays leave the spot (the camera centre) in a stratified pattern distributed like the
   spot's intensity I s(theta) over its cone, each carrying an equal share of the spot's flux. Where a
   ray lands, the surface reflects its share as a virtual light with the surface's material (diffuse base
   and GGX lobe about the direction the light came from); for each further bounce the light sends its flux
   on along a direction sampled from that material, and where that lands a new virtual light shines
   what that surface reflects. Camera pixels are where the spot's light
   first lands, so the first-bounce lights are spread over the visible surfaces and those beside, below
   and above the view that the 180-degree cone also lights.
2. Gather. Every `gather_stride` pixels a gather point x sums E = sum_j Phi_j f_j cos_j cos_x / max(r^2,
   clamp^2) over the virtual lights it sees (one shadow ray each), and the glossy term sum_j E_j pi f_x.
   Interleaved sampling (Keller and Heidrich 2001): the lights are split into interleave^2 stratified subsets and neighbouring gather
   points take different subsets, so each point pays for 1 / interleave^2 of the shadow rays; Russian roulette
   skips most rays of lights that bring a point little (`_roulette`).
3. Filter. Each gather point averages the block of interleave x interleave points around it (every
   subset once), weighted by how alike the surfaces are (normal, plane distance, distance), and then once more
   (fewer blotches from the few lights of each subset); every pixel then takes
   the bilinear mix of its four nearest gather points under the same geometric weights. Pixels whose surface
   none of the four lies on (narrower than the stride: door frames, box tops) gather on a finer grid of their
   own (`_fill_orphans`).

The pattern of directions is drawn once from the job's seed: a still camera gives the same frame every
time (no flicker), and the same job gives the same bytes. Virtual lights clamp the 1/r^2 of near pairs
(`clamp_distance`); rays from each gather point bring back what the clamp leaves out (`_near_field`).
"""

from __future__ import annotations

import math
from typing import Callable

import numba
import numpy as np

from pipeline.config import Illumination
from pipeline.render.embree import EmbreeMesh
from pipeline.render.lighting import (INDIRECT_BLOCK, SurfaceColors, cone_falloff, radiant_intensity,
                                      srgb_to_linear)
from pipeline.render.material import (TABLE_SIZE, fresnel_dielectric, glossy_brdf, reflection_tables,
                                      smith_g2)
from pipeline.render.raycaster import RayHits, row_bands, thread_pool

# Offset of shadow and bounce rays off their surface, relative to the distance from the camera (float32
# hits are accurate to ~1e-7 of that distance).
SURFACE_OFFSET = 1e-4
# Geometric weights of the filter: cos^8 of the angle between normals (fixed in `_similarity`) times
# 1 - (plane distance / tolerance)^2, the tolerance being this fraction of the depth.
PLANE_TOLERANCE = 0.05
# ... and, in the interleave filter, 1 - (distance / reach)^2 with the reach this fraction of the depth: a block
# of 8 x 8 gather points spans metres along a wall seen at a grazing angle (a corridor), over which the
# bounced light changes several-fold; without it the far end of a corridor took the light of its near end.
FILTER_REACH = 0.3
# Ratio of successive bounces used for the untraced ones at most (a white closed room would give 1).
MAX_BOUNCE_RATIO = 0.95
# Cycles' Filter Glossy (its default 1.0, which the authors' and the reference renders kept): on a path that
# already bounced with direction pdf p < 1, every lobe is widened to alpha >= 0.5 sqrt(1 - FILTER_GLOSSY p).
# A virtual light is such a vertex: seen from a gather point x, p is x's cosine pdf cos_x / pi; further back
# along the light's path p is below 1 / pi, so the lights' own bounces take cos_x = 1 (`widened_alpha`).
FILTER_GLOSSY = 1.0
# Values per gather point: irradiance E (RGB), then the glossy term G (RGB) the point's lobe reflects to the eye.
CHANNELS = 6
# Russian roulette on shadow rays: a pair bringing less than this many times its gather point's mean
# contribution keeps its ray with probability contribution / (ROULETTE_BELOW mean), weighted 1 / p (unbiased).
# Far and grazing lights bring little: at 2304 lights per bounce 35 % of the rays are cast, which pays for
# 2.25x the lights of 1024 (fewer of the blotches a light leaves where it lands near a surface: +0.5 dB).
ROULETTE_BELOW = 2.0
# Rays per gather point that find the surfaces nearer than the clamp distance (bias compensation).
NEAR_FIELD_RAYS = 8
# Orphan blocks (`_fill_orphans`) share one gather point per ORPHAN_CELL x ORPHAN_CELL blocks (6 x 6 pixels).
ORPHAN_CELL = 3
_SEED_STREAM = 0x1D1EC7  # separates the pattern's draws from every other use of the job seed


class VirtualLights:
    """The virtual point lights of one frame: positions (n, 3), normals (n, 3) facing the side lit, unit
    directions back to where their light came from (n, 3), the flux that arrived (n, 3) watts per channel,
    that flux times the surface's albedo (n, 3), and the interleaving group of each (n,). A light shines
    as its surface reflects what arrived: diffuse base and GGX lobe (material.py)."""

    def __init__(self, positions: np.ndarray, normals: np.ndarray, incoming: np.ndarray, flux: np.ndarray,
                 coloured_flux: np.ndarray, groups: np.ndarray):
        self.positions, self.normals, self.incoming = positions, normals, incoming
        self.flux, self.coloured_flux, self.groups = flux, coloured_flux, groups


class _GatherGrid:
    """Gather points every `stride` pixels: the surface under the centre pixel of each stride x stride cell
    (`_gather_points`): positions (rows, columns, 3), normals facing the camera, unit directions to the camera
    (eyes), depth (inf where the pixel hit nothing)."""

    def __init__(self, depth: np.ndarray, normal: np.ndarray, direction: np.ndarray, origin: np.ndarray, stride: int):
        height, width = depth.shape
        rows, columns = -(-height // stride), -(-width // stride)
        self.points = np.zeros((rows, columns, 3), np.float32)
        self.normals = np.zeros((rows, columns, 3), np.float32)
        self.eyes = np.zeros((rows, columns, 3), np.float32)
        self.depth = np.full((rows, columns), np.inf, np.float32)
        _gather_points(depth, normal, direction, origin, stride, self.points, self.normals, self.eyes, self.depth)


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
        rng = np.random.default_rng([seed, _SEED_STREAM])
        self.directions, self.ray_flux, self.ray_groups = spot_pattern(illumination, self.settings.virtual_lights,
                                                                       self.settings.interleave, rng)
        # Three uniform numbers per light and further bounce: the lobe (diffuse or glossy), then its direction.
        self.traced = min(self.settings.bounces, self.settings.traced_bounces)
        self._bounce_numbers = rng.random((max(0, self.traced - 1), len(self.directions), 3))

    # ------------------------------------------------------------------------------ lights
    def virtual_lights(self, camera_to_world: np.ndarray) -> VirtualLights:
        """Trace the pattern from the spot at `camera_to_world` through every bounce."""
        rotation = np.asarray(camera_to_world, np.float64)[:3, :3]
        origins = np.repeat(np.asarray(camera_to_world, np.float32)[None, :3, 3], len(self.directions), 0)
        directions = (self.directions @ rotation.T).astype(np.float32)
        flux = np.repeat(self.ray_flux[:, None], 3, 1)
        groups, pattern_index = self.ray_groups, np.arange(len(self.directions))
        camera = np.asarray(camera_to_world, np.float64)[:3, 3]
        found: list[list[np.ndarray]] = []
        emitted = [np.full(3, self.ray_flux.sum())]  # RGB flux leaving the spot, then each bounce's lights
        for bounce in range(self.traced):
            positions, normals, incoming, rho, keep = self._land(origins, directions)
            positions, normals, incoming, rho = positions[keep], normals[keep], incoming[keep], rho[keep]
            flux, groups, pattern_index = flux[keep], groups[keep], pattern_index[keep]
            found.append([positions, normals, incoming, flux, flux * rho, groups])
            emitted.append(np.sum(flux * self._reflectance(normals, incoming, rho), axis=0))
            if bounce + 1 == self.traced:
                break
            # Each light's path keeps its own numbers of the pattern, whichever other paths were lost.
            directions, weights = self._scatter(normals, incoming, rho, self._bounce_numbers[bounce][pattern_index])
            flux = flux * weights
            lift = SURFACE_OFFSET * (1.0 + np.linalg.norm(positions - camera, axis=1, keepdims=True))
            origins = (positions + normals * lift).astype(np.float32)
        untraced = self.settings.bounces - self.traced
        if untraced > 0:
            # Later bounces look like the last traced one, each r times as strong per channel (r < 1: light is
            # absorbed; per channel, because each bounce saturates the colour of the light further).
            ratio = np.minimum(emitted[-1] / np.maximum(emitted[-2], 1e-30), MAX_BOUNCE_RATIO)
            series = sum(ratio**k for k in range(untraced + 1))
            found[-1][3], found[-1][4] = found[-1][3] * series, found[-1][4] * series
        parts = [np.concatenate([part[k] for part in found]) for k in range(6)]
        return VirtualLights(*(np.ascontiguousarray(part, np.float32) for part in parts[:5]), parts[5])

    def _land(self, origins: np.ndarray, directions: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Where rays land: positions, normals facing the ray, unit directions back along the ray, the linear
        albedo there (n, 3), and which rays hit."""
        count = len(origins)
        t, face = np.empty(count, np.float32), np.empty(count, np.int64)
        barycentric, normal = np.empty((count, 2), np.float32), np.empty((count, 3), np.float32)
        self.mesh.intersect(np.ascontiguousarray(origins), np.ascontiguousarray(directions), 0.0,
                            (t, face, barycentric, normal))
        keep = face >= 0
        positions = origins + directions * np.where(keep, t, 0.0)[:, None]
        facing = np.sum(normal * directions, axis=1)
        normal *= np.where(facing > 0, -1.0, 1.0)[:, None].astype(np.float32)  # the side the light came from
        incoming = -directions / np.maximum(np.linalg.norm(directions, axis=1, keepdims=True), 1e-12)
        rho = np.zeros((count, 3), np.float32)
        rho[keep] = srgb_to_linear(self.colors.albedo_at(face[keep], barycentric[keep]) / 255.0)
        return positions.astype(np.float32), normal, incoming.astype(np.float32), rho, keep

    def _reflectance(self, normals: np.ndarray, incoming: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """(n, 3) fraction of the light arriving from `incoming` that a surface reflects (base and lobe)."""
        lobe = self.tables.albedo[table_entries(np.sum(normals * incoming, axis=1))][:, None]
        return rho * (1.0 - lobe) + lobe

    def _scatter(self, normals: np.ndarray, incoming: np.ndarray, rho: np.ndarray, numbers: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The next direction of each path (n, 3) and the factor (n, 3) of its flux, f cos / pdf: the lobe
        is picked by numbers[:, 0] in proportion to what it reflects, then sampled (cosine or GGX)."""
        tables = self.tables
        alpha = float(widened_alpha(tables.alpha, 1.0))
        lobe = tables.albedo[table_entries(np.sum(normals * incoming, axis=1))]
        glossy_share = lobe / np.maximum(lobe + rho.mean(axis=1) * (1.0 - lobe), 1e-12)
        glossy = numbers[:, 0] < glossy_share
        directions = cosine_directions(normals, numbers[:, 1:])
        half = ggx_half_vectors(normals, numbers[:, 1:], alpha)
        cos_oh = np.sum(incoming * half, axis=1)
        mirrored = 2.0 * cos_oh[:, None] * half - incoming
        directions = np.where(glossy[:, None], mirrored, directions)
        cos_o = np.sum(normals * directions, axis=1)
        cos_i, cos_h = np.sum(normals * incoming, axis=1), np.sum(normals * half, axis=1)
        energy = tables.energy[table_entries(cos_o)]
        with np.errstate(divide="ignore", invalid="ignore"):
            # GGX sampled by D cos_h: f cos_o / pdf = G2 F (w_o . h) / (mu_i cos_h).
            glossy_weight = (smith_g2(cos_i, cos_o, alpha) * fresnel_dielectric(cos_oh, tables.ior) * cos_oh
                             / (cos_i * cos_h) * energy / glossy_share)
            glossy_weight = np.where(cos_o > 0, glossy_weight, 0.0)[:, None]
            diffuse_weight = rho * (1.0 - tables.albedo[table_entries(cos_o)])[:, None] / (1.0 - glossy_share)[:, None]
        weights = np.where(glossy[:, None], glossy_weight, diffuse_weight)
        return directions.astype(np.float32), weights

    # ------------------------------------------------------------------------------ gather
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
        self._gather(points, normals, eyes[None], depth, 0, 1, lights, starts, out)
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
        origin = np.asarray(camera_to_world, np.float32)[:3, 3].copy()
        stride = self.settings.gather_stride
        grid = _GatherGrid(hits.depth, hits.normal, hits.direction, origin, stride)
        combined = self._gather_filtered(grid, lights, starts, camera_to_world)
        height, width = hits.depth.shape
        out = (np.empty((-(-height // INDIRECT_BLOCK), -(-width // INDIRECT_BLOCK), CHANNELS), np.float32)
               if out is None else out)
        orphans = np.zeros(out.shape[:2], np.bool_)

        def upsample(band: slice) -> None:
            _upsample(combined, grid.points, grid.normals, grid.depth, hits.depth, hits.direction, hits.normal, origin,
                      stride, band.start, out[band], orphans[band])

        self._run_bands(upsample, len(out))
        self._fill_orphans(hits, origin, orphans, lights, starts, camera_to_world, out)
        return out

    def _gather_filtered(self, grid: _GatherGrid, lights: VirtualLights, starts: np.ndarray,
                         camera_to_world: np.ndarray) -> np.ndarray:
        """(rows, columns, 6) light at the points of `grid`: each point's subset of `lights` and its near field,
        then the interleave filter."""
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
            self._run_bands(lambda band: _interleave_filter(source, grid.points, grid.normals, grid.depth, interleave,
                                                            band, target), rows)
        return combined

    def _fill_orphans(self, hits: RayHits, origin: np.ndarray, orphans: np.ndarray, lights: VirtualLights,
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
        grid = _GatherGrid(hits.depth[pixels], hits.normal[pixels], hits.direction[pixels], origin, 1)
        grid.depth[~cells.any(axis=2)] = np.inf
        combined = self._gather_filtered(grid, lights, starts, camera_to_world)
        out[orphans] = np.repeat(np.repeat(combined, cell, axis=0), cell, axis=1)[:rows, :columns][orphans]

    def _near_field(self, points: np.ndarray, normals: np.ndarray, eyes: np.ndarray, depth: np.ndarray,
                    local: np.ndarray, camera_to_world: np.ndarray, gathered: np.ndarray) -> None:
        """Add to `gathered` the light the clamp of the virtual lights leaves out (Kollig and Keller's bias
        compensation): K = NEAR_FIELD_RAYS cosine rays per gather point x (`local`: their directions in the
        frame of x's normal); a surface y hit at r < clamp brings pi / K L_y (1 - r^2 / clamp^2), L_y being
        what y reflects towards x: the spot's direct light (one shadow ray back to the camera) through the base
        and the lobe (widened as Filter Glossy does after x's bounce), and, as a stand-in for y's own indirect
        light, x's irradiance through the base. The kernels keep the dtypes and the order of the operations of the
        numpy code they replace (float64 mostly), so frames stay the same to the byte."""
        camera = np.asarray(camera_to_world, np.float64)[:3, 3].copy()
        cells, origins, directions = _near_rays(points, normals, depth, local, camera, SURFACE_OFFSET)
        if len(cells) == 0:
            return
        count = len(origins)
        t, face = np.empty(count, np.float32), np.empty(count, np.int64)
        barycentric, hit_normals = np.empty((count, 2), np.float32), np.empty((count, 3), np.float32)
        # Only hits nearer than the clamp count: Embree may stop looking a margin beyond it (1 % + 1 mm, far more
        # than float32 rounding puts between t along the unit ray and the distance `_near_hits` tests).
        reach = 1.01 * self.settings.clamp_distance + 1e-3
        self.mesh.intersect(origins.astype(np.float32), directions.astype(np.float32), 0.0,
                            (t, face, barycentric, hit_normals), reach)
        axis = np.asarray(camera_to_world, np.float64)[:3, 2].copy()
        near, positions, distance, shadow_origins, shadow_directions, off_axis = _near_hits(
            origins, directions, t, face, hit_normals, camera, axis, self.settings.clamp_distance, SURFACE_OFFSET)
        if len(near) == 0:
            return
        blocked = np.empty(len(near), np.bool_)
        self.mesh.occluded(shadow_origins, shadow_directions, np.full(1, 1.0 - SURFACE_OFFSET, np.float32), blocked)
        spot = radiant_intensity(self.illumination) * cone_falloff(off_axis, self.illumination)
        rho = srgb_to_linear(self.colors.albedo_at(face[near], barycentric[near]) / 255.0)
        tables = self.tables
        _near_light(near, cells, directions, positions, hit_normals, distance, rho, spot, blocked, normals,
                    eyes, camera, self.settings.clamp_distance, tables.diffuse, tables.energy, tables.alpha, tables.ior,
                    gathered)

    def _near_directions(self, rows: int, columns: int) -> np.ndarray:
        """(rows, columns, NEAR_FIELD_RAYS, 3) cosine-distributed directions in the frame of a normal (z) of the
        near-field rays of a grid of gather points, stratified per point (fixed per job and grid)."""
        rays = NEAR_FIELD_RAYS
        if (rows, columns) not in self._near_cache:  # the frame's grid and the grid of its orphan blocks
            rng = np.random.default_rng([self._seed, _SEED_STREAM, 1])
            strata = (np.arange(rays) + rng.random((rows, columns, rays))) / rays
            cos_theta = np.sqrt(np.maximum(0.0, 1.0 - strata))
            self._near_cache[rows, columns] = _local_directions(cos_theta.ravel(), rng.random((rows, columns, rays)).ravel()
                                                                ).reshape(rows, columns, rays, 3)
        return self._near_cache[rows, columns]

    def _gather(self, points: np.ndarray, normals: np.ndarray, eyes: np.ndarray, depth: np.ndarray, row_offset: int,
                interleave: int, lights: VirtualLights, starts: np.ndarray, out: np.ndarray) -> None:
        """Add to `out` (rows, columns, 6) what the lights of each point's subset bring it past the shadow rays."""
        tables = self.tables
        shadow = _shadow_rays(points, normals, eyes, depth, row_offset, interleave, lights.positions, lights.normals,
                              lights.incoming, lights.flux, lights.coloured_flux, starts,
                              np.float32(self.settings.clamp_distance ** 2), np.float32(SURFACE_OFFSET),
                              tables.diffuse, tables.energy, tables.alpha, tables.ior, np.float32(ROULETTE_BELOW),
                              np.uint64(self._seed))
        cells, contributions, ray_origins, ray_directions = shadow
        blocked = np.empty(len(cells), np.bool_)
        self.mesh.occluded(ray_origins, ray_directions, np.full(1, 1.0 - SURFACE_OFFSET, np.float32), blocked)
        _accumulate(cells, contributions, blocked, out)

    def _run_bands(self, work: Callable[[slice], None], rows: int) -> None:
        """`work` on bands of `rows` rows, on this gather's threads (inline with one thread)."""
        bands = row_bands(rows, self.threads)
        if len(bands) == 1:
            work(bands[0])
        else:
            list(thread_pool(self.threads).map(work, bands))


def spot_pattern(illumination: Illumination, count: int, interleave: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame directions (n, 3), flux per ray (n,) watts and interleaving group (n,) of the spot's rays.

    Stratified on a k x k grid (k = a multiple of `interleave`, k^2 >= count) over (u1, u2): u1 picks
    cos(theta) by the inverse of the cone's cumulative intensity, u2 the azimuth. Group of stratum (a, b):
    (a mod interleave) * interleave + b mod interleave, so every group spans the whole cone.
    """
    k = interleave * max(1, math.ceil(math.sqrt(count) / interleave))
    a, b = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    u1 = (a.ravel() + rng.random(k * k)) / k
    u2 = (b.ravel() + rng.random(k * k)) / k
    cos_edge = math.cos(math.radians(illumination.cone) / 2.0)
    grid = np.linspace(cos_edge, 1.0, 4097)
    falloff = cone_falloff(grid, illumination).astype(np.float64)
    cumulative = np.concatenate([[0.0], np.cumsum((falloff[1:] + falloff[:-1]) / 2 * np.diff(grid))])
    total_flux = 2.0 * math.pi * radiant_intensity(illumination) * cumulative[-1]
    cos_theta = np.interp(u1 * cumulative[-1], cumulative, grid)
    sin_theta = np.sqrt(np.maximum(0.0, 1.0 - cos_theta**2))
    phi = 2.0 * math.pi * u2
    directions = np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], 1)
    groups = ((a.ravel() % interleave) * interleave + b.ravel() % interleave).astype(np.int64)
    return directions, np.full(k * k, total_flux / (k * k)), groups


@numba.njit(nogil=True, cache=True)
def widened_alpha(alpha, cos_x):  # pragma: no cover (compiled)
    """GGX alpha of a lobe after a cosine bounce at cos_x, as Cycles' Filter Glossy widens it (scalars or arrays)."""
    return np.maximum(alpha, 0.5 * np.sqrt(np.maximum(0.0, 1.0 - FILTER_GLOSSY * cos_x / math.pi)))


def table_entries(mu: np.ndarray) -> np.ndarray:
    """Entries of the material tables for cosines `mu` (clipped to [0, 1])."""
    return np.rint(np.clip(mu, 0.0, 1.0) * (TABLE_SIZE - 1)).astype(np.int64)


def cosine_directions(normals: np.ndarray, numbers: np.ndarray) -> np.ndarray:
    """Unit directions (n, 3) distributed as cos(theta) about `normals`, from uniform `numbers` (n, 2)."""
    return _about_normals(np.sqrt(np.maximum(0.0, 1.0 - numbers[:, 0])), numbers[:, 1], normals)


def ggx_half_vectors(normals: np.ndarray, numbers: np.ndarray, alpha: float) -> np.ndarray:
    """Unit half vectors (n, 3) distributed as D(h) cos(theta_h) of GGX about `normals`, from `numbers` (n, 2)."""
    u = numbers[:, 0]
    return _about_normals(np.sqrt((1.0 - u) / (1.0 + (alpha * alpha - 1.0) * u)), numbers[:, 1], normals)


def _about_normals(cos_theta: np.ndarray, turn: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit directions at cos_theta (n,) to `normals` (n, 3), at azimuth 2 pi turn (n,) about them."""
    local = _local_directions(cos_theta, turn)
    normals = normals.astype(np.float64)
    helper = np.where(np.abs(normals[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    tangent = np.cross(helper, normals)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    bitangent = np.cross(normals, tangent)
    return local[:, :1] * tangent + local[:, 1:2] * bitangent + local[:, 2:] * normals


def _local_directions(cos_theta: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Unit directions (n, 3) at cos_theta (n,) to the z axis, at azimuth 2 pi turn (n,) about it."""
    radius, phi = np.sqrt(np.maximum(0.0, 1.0 - cos_theta**2)), 2.0 * math.pi * turn
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), cos_theta], 1)


@numba.njit(nogil=True, cache=True)
def _gather_points(depth, normal, direction, origin, stride, points, point_normals, eyes,
                   point_depth):  # pragma: no cover (compiled)
    """The surface under the centre pixel of each stride x stride cell: position, normal facing the camera, unit
    direction to the camera, depth."""
    height, width = depth.shape
    for i in range(points.shape[0]):
        row = min(i * stride + stride // 2, height - 1)
        for k in range(points.shape[1]):
            column = min(k * stride + stride // 2, width - 1)
            z = depth[row, column]
            if not np.isfinite(z):
                continue
            facing = np.float32(0.0)
            for axis in range(3):
                points[i, k, axis] = origin[axis] + z * direction[row, column, axis]
                facing += normal[row, column, axis] * direction[row, column, axis]
            sign = np.float32(-1.0) if facing > 0 else np.float32(1.0)
            ray = direction[row, column]
            length = np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2])
            for axis in range(3):
                point_normals[i, k, axis] = sign * normal[row, column, axis]
                eyes[i, k, axis] = -direction[row, column, axis] / length
            point_depth[i, k] = z


@numba.njit(nogil=True, cache=True)
def _near_rays(points, normals, depth, local, camera, offset):  # pragma: no cover (compiled)
    """The near-field rays of every gather point with a surface: its cell (flat index), and per ray the origin off
    the surface and the direction `local` turned into the frame of its normal (float64, as `_about_normals`)."""
    columns, rays = depth.shape[1], local.shape[2]
    cells = np.flatnonzero(np.isfinite(depth.ravel()))
    origins = np.empty((len(cells) * rays, 3), np.float64)
    directions = np.empty((len(cells) * rays, 3), np.float64)
    x, gap = np.empty(3, np.float64), np.empty(3, np.float64)
    for m in range(len(cells)):
        i, k = cells[m] // columns, cells[m] % columns
        nx, ny, nz = np.float64(normals[i, k, 0]), np.float64(normals[i, k, 1]), np.float64(normals[i, k, 2])
        hx, hy, hz = (0.0, 1.0, 0.0) if abs(nx) > 0.9 else (1.0, 0.0, 0.0)
        tx, ty, tz = hy * nz - hz * ny, hz * nx - hx * nz, hx * ny - hy * nx
        length = np.sqrt(tx * tx + ty * ty + tz * tz)
        tx, ty, tz = tx / length, ty / length, tz / length
        bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
        for axis in range(3):
            x[axis] = points[i, k, axis]
            gap[axis] = x[axis] - camera[axis]
        away = np.sqrt(_dot(gap, gap))
        lift = offset * (1.0 + away)
        for q in range(rays):
            r = m * rays + q
            l0, l1, l2 = local[i, k, q, 0], local[i, k, q, 1], local[i, k, q, 2]
            directions[r, 0] = l0 * tx + l1 * bx + l2 * nx
            directions[r, 1] = l0 * ty + l1 * by + l2 * ny
            directions[r, 2] = l0 * tz + l1 * bz + l2 * nz
            origins[r, 0], origins[r, 1], origins[r, 2] = x[0] + nx * lift, x[1] + ny * lift, x[2] + nz * lift
    return cells, origins, directions


@numba.njit(nogil=True, cache=True)
def _near_hits(origins, directions, t, face, hit_normals, camera, axis, clamp, offset):  # pragma: no cover (compiled)
    """The near-field rays that land nearer than `clamp`: their indices, where they land (float32, as the ray
    arithmetic in float32 puts them), the distance from the ray's origin, and the shadow ray from there back to
    the spot (origin off the surface, direction: t in [0, 1)) with its cosine to the spot's axis. Turns
    `hit_normals` of those rays to the side the ray came from."""
    count = len(face)
    near = np.empty(count, np.int64)
    positions = np.empty((count, 3), np.float32)
    distance = np.empty(count, np.float64)
    m = 0
    for r in range(count):
        if face[r] < 0:
            continue
        squared = 0.0
        for a in range(3):
            positions[m, a] = np.float32(origins[r, a]) + np.float32(directions[r, a]) * t[r]
            gap = np.float64(positions[m, a]) - origins[r, a]
            squared += gap * gap
        distance[m] = np.sqrt(squared)
        if distance[m] < clamp:
            near[m] = r
            m += 1
    shadow_origins = np.empty((m, 3), np.float32)
    shadow_directions = np.empty((m, 3), np.float32)
    off_axis = np.empty(m, np.float64)
    to_light = np.empty(3, np.float64)
    for q in range(m):
        r = near[q]
        facing = (hit_normals[r, 0] * np.float32(directions[r, 0]) + hit_normals[r, 1] * np.float32(directions[r, 1])
                  + hit_normals[r, 2] * np.float32(directions[r, 2]))
        sign = np.float32(-1.0) if facing > 0 else np.float32(1.0)
        for a in range(3):
            hit_normals[r, a] *= sign
            to_light[a] = camera[a] - np.float64(positions[q, a])
        away = np.sqrt(_dot(to_light, to_light))
        lift = offset * (1.0 + away)
        off_axis[q] = -(to_light[0] / away * axis[0] + to_light[1] / away * axis[1] + to_light[2] / away * axis[2])
        for a in range(3):
            shadow_origins[q, a] = np.float32(np.float64(positions[q, a]) + np.float64(hit_normals[r, a]) * lift)
            shadow_directions[q, a] = np.float32(camera[a] - np.float64(shadow_origins[q, a]))
    return near[:m], positions[:m], distance[:m], shadow_origins, shadow_directions, off_axis


@numba.njit(nogil=True, cache=True)
def _near_light(near, cells, directions, positions, hit_normals, distance, rho, spot, blocked, normals, eyes, camera,
                clamp, diffuse, energy, alpha, ior, gathered):  # pragma: no cover (compiled)
    """Add to `gathered` what each near hit y brings its gather point x (see `_near_field`): pi / K (1 - r^2 /
    clamp^2) L_y, and x's lobe times that; every L_y reads x's irradiance before any is added."""
    rays, columns = NEAR_FIELD_RAYS, gathered.shape[1]
    contributions = np.empty((len(near), CHANNELS), np.float32)
    vectors = np.empty((8, 3), np.float64)  # scratch, one row per 3-vector (no allocation per ray)
    n, eye, d, y, m, towards_x, to_light, half = (vectors[0], vectors[1], vectors[2], vectors[3], vectors[4],
                                                  vectors[5], vectors[6], vectors[7])
    ray = np.empty(3, np.float32)
    for q in range(len(near)):
        r = near[q]
        cell = cells[r // rays]
        i, k = cell // columns, cell % columns
        for a in range(3):
            n[a], eye[a], d[a] = normals[i, k, a], eyes[i, k, a], directions[r, a]
            y[a], m[a], ray[a] = positions[q, a], hit_normals[r, a], directions[r, a]
            to_light[a] = camera[a] - y[a]
        # The direction back along the ray as the float32 landing computes it.
        length = max(np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2]), np.float32(1e-12))
        for a in range(3):
            towards_x[a] = -ray[a] / length
        away = np.sqrt(_dot(to_light, to_light))
        for a in range(3):
            to_light[a] /= away
        cos_at_x = _dot(n, d)
        direct = 0.0
        if not blocked[q]:
            direct = np.float64(spot[q]) * max(_dot(m, to_light), 0.0) / (away * away)
        base = diffuse[_table_entry(_dot(m, towards_x))] / np.float32(math.pi)
        lobe = _lobe(m, to_light, towards_x, widened_alpha(alpha, cos_at_x), ior, energy, half)
        seen = math.pi * _lobe(n, d, eye, np.float64(alpha), ior, energy, half)
        falloff = distance[q] / clamp
        for c in range(3):
            radiance = np.float64(rho[q, c] * base) * (direct + np.float64(gathered[i, k, c])) + lobe * direct
            contribution = math.pi / rays * radiance * (1.0 - falloff * falloff)
            contributions[q, c] = contribution
            contributions[q, 3 + c] = contribution * seen
    for q in range(len(near)):
        cell = cells[near[q] // rays]
        for c in range(CHANNELS):
            gathered[cell // columns, cell % columns, c] += contributions[q, c]


@numba.njit(nogil=True, cache=True, inline="always")
def _dot(a, b):  # pragma: no cover (compiled)
    """The dot product of two 3-vectors, summed in numpy's order (x, then y, then z)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(nogil=True, cache=True, inline="always")
def _table_entry(mu):  # pragma: no cover (compiled)
    """The material tables' entry of a cosine, as `table_entries` (clipped to [0, 1], rounded half to even)."""
    return np.int64(np.rint(min(max(mu, 0.0), 1.0) * (TABLE_SIZE - 1)))


@numba.njit(nogil=True, cache=True)
def _lobe(normal, a, b, alpha, ior, energy, half):  # pragma: no cover (compiled)
    """The lobe f(a, b) M(cos_b) of a surface of `normal` between unit directions a and b (float64 3-vectors;
    `half`: scratch for their half vector)."""
    for axis in range(3):
        half[axis] = a[axis] + b[axis]
    half /= max(np.sqrt(_dot(half, half)), 1e-12)
    cos_a, cos_b, cos_h, cos_bh = _dot(normal, a), _dot(normal, b), _dot(normal, half), _dot(b, half)
    if not (cos_a > 1e-6 and cos_b > 1e-6 and cos_h > 0 and cos_bh > 0):
        return 0.0
    cos_a, cos_b, cos_bh = max(cos_a, 1e-6), max(cos_b, 1e-6), max(cos_bh, 1e-6)
    return glossy_brdf(cos_h, cos_a, cos_b, cos_bh, alpha, ior) * np.float64(energy[_table_entry(cos_b)])


@numba.njit(nogil=True, cache=True, inline="always")
def _entry(mu):  # pragma: no cover (compiled)
    """The material tables' entry of a cosine in [0, 1]."""
    return np.int32(min(mu, np.float32(1.0)) * np.float32(TABLE_SIZE - 1) + np.float32(0.5))


@numba.njit(nogil=True, cache=True, inline="always")
def _glossy(nx, ny, nz, ax, ay, az, bx, by, bz, cos_a, cos_b, energy, alpha, ior):  # pragma: no cover (compiled)
    """The lobe f(a, b) / E_ss(cos_b) of a surface of normal n between unit directions a and b (0 for IOR 1)."""
    if ior == 1.0:
        return np.float32(0.0)
    hx, hy, hz = ax + bx, ay + by, az + bz
    length = np.sqrt(hx * hx + hy * hy + hz * hz)
    if length <= np.float32(1e-6):
        return np.float32(0.0)
    cos_h = (nx * hx + ny * hy + nz * hz) / length
    cos_bh = (bx * hx + by * hy + bz * hz) / length
    if cos_h <= 0 or cos_bh <= 0:
        return np.float32(0.0)
    return np.float32(glossy_brdf(cos_h, cos_a, cos_b, cos_bh, alpha, ior)) * energy[_entry(cos_b)]


@numba.njit(nogil=True, cache=True)
def _shadow_rays(points, point_normals, eyes, point_depth, row_offset, interleave, positions, normals, incoming, flux,
                 coloured_flux, starts, clamp2, offset, base, energy, alpha, ior, roulette_below,
                 seed):  # pragma: no cover (compiled)
    """Every (gather point, light of its subset) pair that faces each other: the cell, the unshadowed
    contribution (irradiance RGB, glossy term RGB) and the shadow ray (origin off the surface, direction to
    the light: t in [0, 1)). A light at y lit from w_i sends the point x the irradiance
    Phi f_y(w_i, y->x) cos_y cos_x / max(r^2, clamp^2), f = base rho / pi + lobe (material.py); x's own lobe
    reflects pi f_x(x->y, x->eye) times that towards the eye (the glossy term)."""
    rows, columns = point_depth.shape
    largest = 0
    for group in range(len(starts) - 1):
        largest = max(largest, starts[group + 1] - starts[group])
    # Sized by the points with a surface: the grid of orphan blocks (`_fill_orphans`) has few among many cells.
    most = np.count_nonzero(np.isfinite(point_depth)) * largest
    cells = np.empty(most, np.int64)
    contributions = np.empty((most, CHANNELS), np.float32)
    origins = np.empty((most, 3), np.float32)
    directions = np.empty((most, 3), np.float32)
    lights = np.empty(most, np.int64)
    n = 0
    inverse_pi, pi = np.float32(1.0 / math.pi), np.float32(math.pi)
    for i in range(rows):
        for k in range(columns):
            z = point_depth[i, k]
            if not np.isfinite(z):
                continue
            group = ((i + row_offset) % interleave) * interleave + k % interleave
            lift = offset * (np.float32(1.0) + z)
            nx, ny, nz = point_normals[i, k, 0], point_normals[i, k, 1], point_normals[i, k, 2]
            ex, ey, ez = eyes[i, k, 0], eyes[i, k, 1], eyes[i, k, 2]
            cos_eye = nx * ex + ny * ey + nz * ez
            px, py, pz = points[i, k, 0] + nx * lift, points[i, k, 1] + ny * lift, points[i, k, 2] + nz * lift
            first = n
            for j in range(starts[group], starts[group + 1]):
                dx, dy, dz = positions[j, 0] - px, positions[j, 1] - py, positions[j, 2] - pz
                r2 = dx * dx + dy * dy + dz * dz
                if r2 <= np.float32(0.0):
                    continue
                r = np.sqrt(r2)
                dx, dy, dz = dx / r, dy / r, dz / r
                cos_x = nx * dx + ny * dy + nz * dz
                mx, my, mz = normals[j, 0], normals[j, 1], normals[j, 2]
                cos_j = -(mx * dx + my * dy + mz * dz)
                if cos_x <= 0 or cos_j <= 0:
                    continue
                geometry = cos_x * cos_j / max(r2, clamp2)
                wx, wy, wz = incoming[j, 0], incoming[j, 1], incoming[j, 2]
                cos_in = mx * wx + my * wy + mz * wz
                lobe, seen = 0.0, 0.0
                if cos_in > 0:
                    widened = widened_alpha(alpha, cos_x)
                    lobe = _glossy(mx, my, mz, wx, wy, wz, -dx, -dy, -dz, cos_in, cos_j, energy, widened, ior)
                if cos_eye > 0:
                    seen = pi * _glossy(nx, ny, nz, dx, dy, dz, ex, ey, ez, cos_x, cos_eye, energy, alpha, ior)
                diffuse = base[_entry(cos_j)] * inverse_pi
                cells[n] = i * columns + k
                for c in range(3):
                    received = (coloured_flux[j, c] * diffuse + flux[j, c] * lobe) * geometry
                    contributions[n, c] = received
                    contributions[n, 3 + c] = received * seen
                origins[n, 0], origins[n, 1], origins[n, 2] = px, py, pz
                directions[n, 0], directions[n, 1], directions[n, 2] = dx * r, dy * r, dz * r
                lights[n] = j
                n += 1
            n = _roulette(first, n, (i + row_offset) * columns + k, seed, roulette_below, lights, cells, contributions,
                          origins, directions)
    return cells[:n], contributions[:n], origins[:n], directions[:n]


@numba.njit(nogil=True, cache=True)
def _roulette(first, end, cell, seed, roulette_below, lights, cells, contributions, origins,
              directions):  # pragma: no cover (compiled)
    """Russian roulette on the pairs first..end of one gather point: a pair bringing c < roulette_below times the
    point's mean keeps its shadow ray with probability c / (roulette_below mean) and then counts 1 / p times (an
    unbiased estimate); the rest are dropped. The draw hashes (seed, cell, light): a still camera draws alike.
    Returns the new end of the kept pairs (compacted in place)."""
    total = np.float32(0.0)
    for q in range(first, end):
        total += contributions[q, 0] + contributions[q, 1] + contributions[q, 2]
    if total <= 0:
        return first  # nothing to bring: no rays
    if roulette_below <= 0:
        return end
    threshold = roulette_below * total / np.float32(end - first)
    kept = first
    for q in range(first, end):
        value = contributions[q, 0] + contributions[q, 1] + contributions[q, 2]
        weight = np.float32(1.0)
        if value < threshold:
            chance = value / threshold
            if _hash_uniform(seed, cell, lights[q]) >= chance:
                continue
            weight = np.float32(1.0) / chance
        cells[kept] = cells[q]
        for c in range(CHANNELS):
            contributions[kept, c] = contributions[q, c] * weight
        for axis in range(3):
            origins[kept, axis], directions[kept, axis] = origins[q, axis], directions[q, axis]
        kept += 1
    return kept


@numba.njit(nogil=True, cache=True, inline="always")
def _hash_uniform(seed, cell, light):  # pragma: no cover (compiled)
    """A uniform number in [0, 1) from (seed, cell, light) (splitmix64 of their combination)."""
    z = (seed * np.uint64(0x100000001B3)) ^ (np.uint64(cell) << np.uint64(24)) ^ np.uint64(light)
    z += np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z ^= z >> np.uint64(31)
    return np.float32((z >> np.uint64(40)) * np.float64(1.0 / 16777216.0))


@numba.njit(nogil=True, cache=True)
def _accumulate(cells, contributions, blocked, gathered):  # pragma: no cover (compiled)
    """Sum the unshadowed contributions per gather point, in ray order (deterministic)."""
    columns, channels = gathered.shape[1], gathered.shape[2]
    for n in range(len(cells)):
        if blocked[n]:
            continue
        i, k = cells[n] // columns, cells[n] % columns
        for c in range(channels):
            gathered[i, k, c] += contributions[n, c]


@numba.njit(nogil=True, cache=True, inline="always")
def _similarity(px, py, pz, nx, ny, nz, depth, points, point_normals, point_depth, i, k):  # pragma: no cover
    """Geometric weight in [0, 1] of gather point (i, k) for a surface at p with normal n and depth."""
    if not np.isfinite(point_depth[i, k]):
        return np.float32(0.0)
    cosine = nx * point_normals[i, k, 0] + ny * point_normals[i, k, 1] + nz * point_normals[i, k, 2]
    if cosine <= 0:
        return np.float32(0.0)
    plane = abs((px - points[i, k, 0]) * point_normals[i, k, 0] + (py - points[i, k, 1]) * point_normals[i, k, 1]
                + (pz - points[i, k, 2]) * point_normals[i, k, 2])
    tolerance = np.float32(PLANE_TOLERANCE) * depth
    if plane >= tolerance:
        return np.float32(0.0)
    plane /= tolerance
    cosine *= cosine  # cos^8 by squaring (a float power costs more than the rest of the weight)
    cosine *= cosine
    cosine *= cosine
    return cosine * (np.float32(1.0) - plane * plane)


@numba.njit(nogil=True, cache=True)
def _interleave_filter(gathered, points, point_normals, point_depth, interleave, band, out):  # pragma: no cover
    """Each gather point of the rows of `band` (a slice): the geometry-weighted mean of the interleave x
    interleave block around it (points on its plane, within FILTER_REACH of its depth)."""
    rows, columns = point_depth.shape
    low = -((interleave - 1) // 2)
    for i in range(band.start, band.stop):
        for k in range(columns):
            depth = point_depth[i, k]
            if not np.isfinite(depth):
                continue
            px, py, pz = points[i, k, 0], points[i, k, 1], points[i, k, 2]
            nx, ny, nz = point_normals[i, k, 0], point_normals[i, k, 1], point_normals[i, k, 2]
            reach = np.float32(FILTER_REACH) * depth
            total = np.float32(0.0)
            sums = np.zeros(CHANNELS, np.float32)
            # Shift the block inside the grid at its borders, so it still holds every subset once.
            top = min(max(i + low, 0), max(rows - interleave, 0))
            left = min(max(k + low, 0), max(columns - interleave, 0))
            for a in range(top, min(top + interleave, rows)):
                for b in range(left, min(left + interleave, columns)):
                    w = _similarity(px, py, pz, nx, ny, nz, depth, points, point_normals, point_depth, a, b)
                    if w > 0:
                        dx, dy, dz = points[a, b, 0] - px, points[a, b, 1] - py, points[a, b, 2] - pz
                        w *= max(np.float32(1.0) - (dx * dx + dy * dy + dz * dz) / (reach * reach), np.float32(0.0))
                    total += w
                    for c in range(CHANNELS):
                        sums[c] += w * gathered[a, b, c]
            if total > 0:
                for c in range(CHANNELS):
                    out[i, k, c] = sums[c] / total


@numba.njit(nogil=True, cache=True)
def _upsample(combined, points, point_normals, point_depth, depth, direction, normal, origin, stride, block_start,
              out, orphans):  # pragma: no cover (compiled)
    """Blocks of rows block_start.. (out holds those rows; block (R, C) is the surface of pixel (INDIRECT_BLOCK R,
    INDIRECT_BLOCK C)): the bilinear mix of the four nearest gather points, each weighted by geometric similarity.
    A block none of them is alike to (a surface smaller than a cell) is left 0 and marked in `orphans`."""
    height, width = out.shape[0], out.shape[1]
    rows, columns = point_depth.shape
    half = np.float32(stride // 2)
    one = np.float32(1.0)
    for local_row in range(height):
        row = (block_start + local_row) * INDIRECT_BLOCK
        gi = (np.float32(row) - half) / np.float32(stride)
        i0 = min(max(int(np.floor(gi)), 0), rows - 1)
        i1 = min(i0 + 1, rows - 1)
        fi = min(max(gi - np.float32(i0), np.float32(0.0)), one)
        for block_column in range(width):
            column = block_column * INDIRECT_BLOCK
            out[local_row, block_column] = 0.0
            z = depth[row, column]
            if not np.isfinite(z):
                continue
            facing = (normal[row, column, 0] * direction[row, column, 0] + normal[row, column, 1] * direction[row, column, 1]
                      + normal[row, column, 2] * direction[row, column, 2])
            sign = np.float32(-1.0) if facing > 0 else one
            nx, ny, nz = sign * normal[row, column, 0], sign * normal[row, column, 1], sign * normal[row, column, 2]
            px = origin[0] + z * direction[row, column, 0]
            py = origin[1] + z * direction[row, column, 1]
            pz = origin[2] + z * direction[row, column, 2]
            gk = (np.float32(column) - half) / np.float32(stride)
            k0 = min(max(int(np.floor(gk)), 0), columns - 1)
            k1 = min(k0 + 1, columns - 1)
            fk = min(max(gk - np.float32(k0), np.float32(0.0)), one)
            w00 = (one - fi) * (one - fk) * _similarity(px, py, pz, nx, ny, nz, z, points, point_normals, point_depth, i0, k0)
            w01 = (one - fi) * fk * _similarity(px, py, pz, nx, ny, nz, z, points, point_normals, point_depth, i0, k1)
            w10 = fi * (one - fk) * _similarity(px, py, pz, nx, ny, nz, z, points, point_normals, point_depth, i1, k0)
            w11 = fi * fk * _similarity(px, py, pz, nx, ny, nz, z, points, point_normals, point_depth, i1, k1)
            total = w00 + w01 + w10 + w11
            if total > np.float32(1e-6):
                for c in range(CHANNELS):
                    out[local_row, block_column, c] = (w00 * combined[i0, k0, c] + w01 * combined[i0, k1, c]
                                                 + w10 * combined[i1, k0, c] + w11 * combined[i1, k1, c]) / total
                continue
            # None of the four is alike: the most similar of the 4 x 4 around (the same surface a cell further);
            # failing that, an orphan.
            best, best_a, best_b = np.float32(0.0), -1, -1
            for a in range(max(i0 - 1, 0), min(i0 + 3, rows)):
                for b in range(max(k0 - 1, 0), min(k0 + 3, columns)):
                    w = _similarity(px, py, pz, nx, ny, nz, z, points, point_normals, point_depth, a, b)
                    if w > best:
                        best, best_a, best_b = w, a, b
            if best_a < 0:
                orphans[local_row, block_column] = True
                continue
            for c in range(CHANNELS):
                out[local_row, block_column, c] = combined[best_a, best_b, c]
