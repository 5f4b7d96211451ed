"""Depth sensor models: `ideal` (the clean planar depth) and `structured_light` (a Kinect-v1-like sensor).

Clean depth is planar z in metres from the ray caster; the sensor turns it into what a real depth camera
would report, and both are stored (the clean one as `depth_clean`). Parameters and their sources are in
schemas/render.md:

- working range: returns outside [min_range, max_range] are dropped (0);
- grazing angles: a return whose incidence angle exceeds `max_incidence_deg` is dropped;
- axial noise: z + N(0, sigma(z)) with sigma(z) = a + b (z - z0)^2 (Nguyen, Izadi & Lovell, 3DIMPVT 2012);
- quantisation: the sensor measures disparity d = f b / z in steps of 1/subpixel pixel, so the reported
  depth is f b / (round(d * subpixel) / subpixel): steps grow with z^2 like the real device's.

Every draw comes from the generator the caller passes (seeded per job, unit and frame).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from pipeline.render.raycaster import RayHits

UINT16_MAX_MM = 65535


@dataclass(frozen=True)
class StructuredLightModel:
    """Parameters of the `structured_light` depth model (defaults: Kinect v1, see schemas/render.md)."""

    min_range_m: float = 0.4
    max_range_m: float = 4.5
    max_incidence_deg: float = 75.0
    noise_a_m: float = 0.0012
    noise_b_per_m: float = 0.0019
    noise_z0_m: float = 0.4
    focal_px: float = 580.0
    baseline_m: float = 0.075
    subpixel: int = 8

    def as_dict(self) -> dict[str, float]:
        """JSON-able parameters (stored in the Zarr attributes of a noisy video)."""
        return asdict(self)

    def apply(self, depth_m: np.ndarray, hits: RayHits, ray_lengths: np.ndarray,
              rng: np.random.Generator) -> np.ndarray:
        """Noisy float32 depth in metres (0 where the sensor returns nothing) from clean planar depth."""
        valid = hits.hit & (depth_m >= self.min_range_m) & (depth_m <= self.max_range_m)
        cos_incidence = np.abs(np.einsum("hwk,hwk->hw", hits.normal, hits.direction)) / ray_lengths
        valid &= cos_incidence >= math.cos(math.radians(self.max_incidence_deg))
        z = depth_m[valid].astype(np.float64)
        # Noise drawn for valid pixels only, in row-major order: the draw count depends on the scene,
        # not on memory layout, so the same job gives the same noise.
        sigma = self.noise_a_m + self.noise_b_per_m * (z - self.noise_z0_m) ** 2
        noisy = z + sigma * rng.standard_normal(z.shape)
        disparity = self.focal_px * self.baseline_m / np.maximum(noisy, 1e-6)
        steps = np.maximum(np.rint(disparity * self.subpixel), 1.0)
        out = np.zeros(depth_m.shape, np.float32)
        out[valid] = (self.focal_px * self.baseline_m * self.subpixel / steps).astype(np.float32)
        return out


def sensor_model(name: str) -> StructuredLightModel | None:
    """The noise model of a `Sensor.model` name; None for `ideal`."""
    if name == "ideal":
        return None
    if name == "structured_light":
        return StructuredLightModel()
    raise ValueError(f"sensor.model: unknown depth model {name!r}; use 'ideal' or 'structured_light'")


def depth_to_millimetres(depth_m: np.ndarray, near: float, far: float) -> np.ndarray:
    """uint16 millimetres, rounded; 0 where there is no return, nearer than `near`, beyond `far`,
    or at/above 65.535 m (uint16 cannot hold it; saturating would fake a surface)."""
    depth_m = np.asarray(depth_m)
    millimetres = np.rint(depth_m * 1000.0)  # inf and NaN stay non-finite and fail every test below
    keep = depth_m >= near
    keep &= depth_m <= far
    keep &= millimetres > 0
    keep &= millimetres <= UINT16_MAX_MM
    out = np.zeros(depth_m.shape, np.uint16)
    np.copyto(out, millimetres, casting="unsafe", where=keep)
    return out


@numba.njit(nogil=True, cache=True, inline="always")
def millimetres_of(z, near, far):  # pragma: no cover (compiled)
    """One float32 depth as `depth_to_millimetres` stores it, with its float32 arithmetic and comparisons
    exactly (NumPy compares float32 depths with near and far as float32: pass them as float32). The tests are
    combined by `&` (no branches), so a loop of them is vectorised."""
    value = np.rint(z * np.float32(1000.0))  # inf and NaN stay non-finite and fail every test below
    keep = (z >= near) & (z <= far) & (value > np.float32(0.0)) & (value <= np.float32(UINT16_MAX_MM))
    return np.uint16(value) if keep else np.uint16(0)
