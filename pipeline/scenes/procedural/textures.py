"""Procedural surface colour baked into vertex colours: paint, wood grain, fabric, tiles, stone, ...

Patterns are functions of the vertex position, so finer tessellation (higher `detail`) shows finer
texture. Noise is an integer hash of the quantised position (no trigonometry), so colours are
bit-identical on every platform.
"""

from __future__ import annotations

import numpy as np

MATERIALS = ("paint", "wood", "fabric", "tile", "stone", "metal", "plastic", "glass", "leaf", "carpet", "ceramic")


def hash_noise(points: np.ndarray, scale: float, salt: int = 0) -> np.ndarray:
    """Per-point value in [0, 1) from the cell of size `scale` (metres) it falls in."""
    cells = np.floor(points / scale).astype(np.int64)
    h = (cells[:, 0] * 73856093) ^ (cells[:, 1] * 19349663) ^ (cells[:, 2] * 83492791) ^ salt
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF).astype(np.float64) / 65536.0


def _triangle_wave(t: np.ndarray) -> np.ndarray:
    return np.abs(2.0 * (t - np.floor(t)) - 1.0)


def _factor(material: str, p: np.ndarray) -> np.ndarray:
    """Brightness factor per point for one material."""
    if material == "wood":
        grain = _triangle_wave((p[:, 0] + p[:, 2]) * 9.0 + 0.35 * hash_noise(p, 0.15, 1))
        return 0.78 + 0.22 * grain
    if material in ("fabric", "carpet"):
        return 0.82 + 0.18 * hash_noise(p, 0.04 if material == "fabric" else 0.02, 2)
    if material == "tile":
        gu = (p[:, 0] / 0.3) % 1.0
        gv = (p[:, 2] / 0.3) % 1.0
        gw = (p[:, 1] / 0.3) % 1.0
        grout = (np.minimum(gu, gv) < 0.06) | ((np.minimum(gu, gw) < 0.06) & (np.minimum(gv, gw) < 0.06))
        return np.where(grout, 0.62, 0.93 + 0.07 * hash_noise(p, 0.3, 3))
    if material == "stone":
        return 0.8 + 0.2 * hash_noise(p, 0.08, 4) * hash_noise(p, 0.3, 5)
    if material == "leaf":
        return 0.6 + 0.4 * hash_noise(p, 0.03, 6)
    if material in ("metal", "glass", "ceramic"):
        return 0.9 + 0.1 * hash_noise(p, 0.1, 7)
    return 0.93 + 0.07 * hash_noise(p, 0.4, 8)  # paint, plastic


def shade(points: np.ndarray, materials: np.ndarray, base_colors: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 vertex colours from positions, per-vertex material names and base colours."""
    factor = np.ones(len(points))
    for material in np.unique(materials):
        select = materials == material
        factor[select] = _factor(str(material), points[select])
    return np.clip(np.rint(base_colors * factor[:, None]), 0, 255).astype(np.uint8)
