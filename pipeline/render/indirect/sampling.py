"""Directions drawn from uniform numbers: the spot's rays over its cone, and bounces off the material's lobes.

The pattern of the spot's rays is drawn once per job (`SEED_STREAM` of the job's seed), so a still camera
gives the same frame every time (no flicker) and the same job the same bytes. Cycles' Filter Glossy widens a
lobe met after a diffuse bounce (`widened_alpha`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pipeline.config import Illumination
from pipeline.render.lighting import cone_falloff, radiant_intensity
from pipeline.render.material import TABLE_SIZE

# Cycles' Filter Glossy (its default 1.0, which the authors' and the reference renders kept): on a path that
# already bounced with direction pdf p < 1, every lobe is widened to alpha >= 0.5 sqrt(1 - FILTER_GLOSSY p).
# A virtual light is such a vertex: seen from a gather point x, p is x's cosine pdf cos_x / pi; further back
# along the light's path p is below 1 / pi, so the lights' own bounces take cos_x = 1 (`widened_alpha`).
FILTER_GLOSSY = 1.0
SEED_STREAM = 0x1D1EC7  # separates the pattern's draws from every other use of the job seed


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
def widened_alpha(alpha, cos_x, real):  # pragma: no cover (compiled)
    """GGX alpha of a lobe after a cosine bounce at cos_x, as Cycles' Filter Glossy widens it (scalars or arrays),
    in the float type `real` (np.float32 or np.float64, as `material.glossy_brdf`)."""
    return np.maximum(alpha, real(0.5) * np.sqrt(np.maximum(real(0.0), real(1.0) - real(FILTER_GLOSSY) * cos_x
                                                                      / real(math.pi))))


def table_entries(mu: np.ndarray) -> np.ndarray:
    """Entries of the material tables for cosines `mu` (clipped to [0, 1])."""
    return np.rint(np.clip(mu, 0.0, 1.0) * (TABLE_SIZE - 1)).astype(np.int64)


@numba.njit(nogil=True, cache=True, inline="always")
def table_entry(mu):  # pragma: no cover (compiled)
    """The material tables' entry of a cosine, as `table_entries` (clipped to [0, 1], rounded half to even)."""
    return np.int64(np.rint(min(max(mu, 0.0), 1.0) * (TABLE_SIZE - 1)))


@numba.njit(nogil=True, cache=True, inline="always")
def normal_frame(nx, ny, nz, real):  # pragma: no cover (compiled)
    """A unit tangent and bitangent (tx, ty, tz, bx, by, bz) about the unit normal n: the tangent from the x axis,
    or the y axis for a normal near x (the frame every sampled direction of the light, and the filter's plane fit,
    is turned into), in the float type `real` (np.float32 or np.float64, as `material.glossy_brdf`)."""
    zero, one = real(0.0), real(1.0)
    hx, hy, hz = (zero, one, zero) if abs(nx) > 0.9 else (one, zero, zero)
    tx, ty, tz = hy * nz - hz * ny, hz * nx - hx * nz, hx * ny - hy * nx
    length = np.sqrt(tx * tx + ty * ty + tz * tz)
    tx, ty, tz = tx / length, ty / length, tz / length
    return tx, ty, tz, ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx


def local_directions(cos_theta: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Unit directions (n, 3) at cos_theta (n,) to the z axis, at azimuth 2 pi turn (n,) about it."""
    radius, phi = np.sqrt(np.maximum(0.0, 1.0 - cos_theta**2)), 2.0 * math.pi * turn
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), cos_theta], 1)
