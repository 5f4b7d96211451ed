"""Virtual lights: the spot's light where it lands, bounce after bounce (the light paths of instant radiosity).

Rays leave the spot (the camera centre) in a stratified pattern distributed like the spot's intensity
I s(theta) over its cone (`sampling.spot_pattern`), each carrying an equal share of the spot's flux. Where a ray
lands, the surface reflects its share as a virtual light with the surface's material (diffuse base and GGX lobe
about the direction the light came from); for each further bounce the light sends its flux on along a direction
sampled from that material, and where that lands a new virtual light shines what that surface reflects. Camera
pixels are where the spot's light first lands, so the first-bounce lights are spread over the visible surfaces
and those beside, below and above the view that the 180-degree cone also lights.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.config import Illumination
from pipeline.render.embree import EmbreeMesh
from pipeline.render.indirect.sampling import normal_frame, spot_pattern, table_entries, table_entry, widened_alpha
from pipeline.render.lighting import LINEAR_OF_LEVEL, SurfaceColors
from pipeline.render.material import glossy_brdf, reflection_tables

# Offset of shadow and bounce rays off their surface, relative to the distance from the camera (float32
# hits are accurate to ~1e-7 of that distance).
SURFACE_OFFSET = 1e-4
# Ratio of successive bounces used for the untraced ones at most (a white closed room would give 1).
MAX_BOUNCE_RATIO = 0.95


class VirtualLights:
    """The virtual point lights of one frame: positions (n, 3), normals (n, 3) facing the side lit, unit
    directions back to where their light came from (n, 3), the flux that arrived (n, 3) watts per channel,
    that flux times the surface's albedo (n, 3), and the interleaving group of each (n,). A light shines
    as its surface reflects what arrived: diffuse base and GGX lobe (material.py)."""

    def __init__(self, positions: np.ndarray, normals: np.ndarray, incoming: np.ndarray, flux: np.ndarray,
                 coloured_flux: np.ndarray, groups: np.ndarray):
        self.positions, self.normals, self.incoming = positions, normals, incoming
        self.flux, self.coloured_flux, self.groups = flux, coloured_flux, groups


class LightPaths:
    """The spot's light paths for one job: a pattern of rays from the spot, drawn once from `rng`, traced from
    any pose through `illumination.indirect.traced_bounces` bounces into virtual lights.

    Args:
        mesh: the scene's BVH.
        colors: the scene's albedo lookup.
        illumination: the spot (its `indirect` settings).
        rng: the job's generator for the pattern (the spot's rays, then the numbers of every further bounce).
    """

    def __init__(self, mesh: EmbreeMesh, colors: SurfaceColors, illumination: Illumination, rng: np.random.Generator):
        self.mesh, self.colors, self.settings = mesh, colors, illumination.indirect
        self.tables = reflection_tables(illumination)
        self.directions, self.ray_flux, self.ray_groups = spot_pattern(illumination, self.settings.virtual_lights,
                                                                       self.settings.interleave, rng)
        # Three uniform numbers per light and further bounce: the lobe (diffuse or glossy), then its direction.
        self.traced = min(self.settings.bounces, self.settings.traced_bounces)
        self._bounce_numbers = rng.random((max(0, self.traced - 1), len(self.directions), 3))

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
        positions, incoming = _landed(origins, directions, t, face, normal)
        keep = face >= 0
        rho = np.zeros((count, 3), np.float32)
        rho[keep] = LINEAR_OF_LEVEL[self.colors.albedo_at(face[keep], barycentric[keep])]
        return positions, normal, incoming, rho, keep

    def _reflectance(self, normals: np.ndarray, incoming: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """(n, 3) fraction of the light arriving from `incoming` that a surface reflects (base and lobe)."""
        lobe = self.tables.albedo[table_entries(np.sum(normals * incoming, axis=1))][:, None]
        return rho * (1.0 - lobe) + lobe

    def _scatter(self, normals: np.ndarray, incoming: np.ndarray, rho: np.ndarray, numbers: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The next direction of each path (n, 3) and the factor (n, 3) of its flux, f cos / pdf: the lobe
        is picked by numbers[:, 0] in proportion to what it reflects, then sampled (cosine or GGX)."""
        tables = self.tables
        return _scatter_paths(normals, incoming, rho, numbers, tables.albedo, tables.energy,
                              float(widened_alpha(tables.alpha, 1.0, np.float64)), tables.ior)


@numba.njit(nogil=True, cache=True)
def _landed(origins, directions, t, face, normal):  # pragma: no cover (compiled)
    """Where float32 rays land (n, 3) (their origin when they hit nothing) and the unit directions back along
    them (n, 3); turns `normal` to the side each ray came from. The float32 arithmetic of the numpy code it
    replaced, in its order (the same bytes)."""
    count = len(origins)
    positions = np.empty((count, 3), np.float32)
    incoming = np.empty((count, 3), np.float32)
    for p in range(count):
        reach = t[p] if face[p] >= 0 else np.float32(0.0)
        facing = np.float32(0.0)
        squared = np.float32(0.0)
        for a in range(3):
            positions[p, a] = origins[p, a] + directions[p, a] * reach
            facing += normal[p, a] * directions[p, a]
            squared += directions[p, a] * directions[p, a]
        sign = np.float32(-1.0) if facing > 0 else np.float32(1.0)
        length = max(np.sqrt(squared), np.float32(1e-12))
        for a in range(3):
            normal[p, a] *= sign
            incoming[p, a] = -directions[p, a] / length
    return positions, incoming


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _scatter_paths(normals, incoming, rho, numbers, albedo, energy, alpha, ior):  # pragma: no cover (compiled)
    """`LightPaths._scatter`, path by path (float64): the lobe is glossy when numbers[p, 0] < its share of what
    the surface reflects; the direction comes from numbers[p, 1:] (a cosine direction about the normal, or the
    mirror of w_i about a GGX half vector sampled by D cos_h); the factor is f cos_o / pdf, per channel for the
    base, G2 F (w_o . h) / (mu_i cos_h) M(mu_o) for the lobe, each divided by the lobe's chance."""
    count = len(normals)
    directions = np.empty((count, 3), np.float32)
    weights = np.empty((count, 3), np.float64)
    a2 = alpha * alpha
    for p in range(count):
        nx, ny, nz = np.float64(normals[p, 0]), np.float64(normals[p, 1]), np.float64(normals[p, 2])
        wx, wy, wz = np.float64(incoming[p, 0]), np.float64(incoming[p, 1]), np.float64(incoming[p, 2])
        cos_i = nx * wx + ny * wy + nz * wz
        lobe = np.float64(albedo[table_entry(cos_i)])
        glossy_share = lobe / max(lobe + (rho[p, 0] + rho[p, 1] + rho[p, 2]) / 3.0 * (1.0 - lobe), 1e-12)
        u, turn = numbers[p, 1], numbers[p, 2]
        glossy = numbers[p, 0] < glossy_share
        # The sampled direction (the half vector for the lobe) at cos_theta to the normal, azimuth 2 pi turn.
        cos_theta = math.sqrt((1.0 - u) / (1.0 + (a2 - 1.0) * u)) if glossy else math.sqrt(max(0.0, 1.0 - u))
        sx, sy, sz = _about_normal(cos_theta, turn, nx, ny, nz)
        if glossy:
            cos_oh = wx * sx + wy * sy + wz * sz
            dx, dy, dz = 2.0 * cos_oh * sx - wx, 2.0 * cos_oh * sy - wy, 2.0 * cos_oh * sz - wz
            cos_o, cos_h = nx * dx + ny * dy + nz * dz, nx * sx + ny * sy + nz * sz
            weight = 0.0
            if cos_o > 0:
                # f cos_o / pdf with f = D G2 F / (4 mu_i mu_o) and pdf = D cos_h / (4 w_o . h).
                d = cos_h * cos_h * (a2 - 1.0) + 1.0
                distribution = a2 / (math.pi * d * d)
                weight = (glossy_brdf(cos_h, cos_i, cos_o, cos_oh, alpha, ior, np.float64) * 4.0 * cos_o * cos_oh
                          / (distribution * cos_h) * energy[table_entry(cos_o)] / glossy_share)
            for c in range(3):
                weights[p, c] = weight
        else:
            dx, dy, dz = sx, sy, sz
            cos_o = nx * dx + ny * dy + nz * dz
            base = 1.0 - albedo[table_entry(cos_o)]
            for c in range(3):
                weights[p, c] = rho[p, c] * base / (1.0 - glossy_share)
        directions[p, 0], directions[p, 1], directions[p, 2] = dx, dy, dz
    return directions, weights


@numba.njit(nogil=True, cache=True, inline="always")
def _about_normal(cos_theta, turn, nx, ny, nz):  # pragma: no cover (compiled)
    """The unit direction at cos_theta to the normal n, at azimuth 2 pi turn about it (in `normal_frame`)."""
    tx, ty, tz, bx, by, bz = normal_frame(nx, ny, nz, np.float64)
    radius, phi = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta)), 2.0 * math.pi * turn
    a, b = radius * math.cos(phi), radius * math.sin(phi)
    return a * tx + b * bx + cos_theta * nx, a * ty + b * by + cos_theta * ny, a * tz + b * bz + cos_theta * nz
