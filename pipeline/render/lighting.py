"""Surface colour and illumination: `ambient` (albedo as is) and `spot` (a light at the camera).

The radiometric model and the exposure mapping are written down in schemas/render.md; in short:

    albedo      rho = srgb_to_linear(colour / 255)            per channel, in [0, 1]
    intensity   I = P / Omega,  Omega = 2 pi (1 - cos(cone / 2))          W/sr (power spread over the cone)
    cone        s(theta) = smoothstep((cos theta - cos(cone/2)) / ((1 - cos(cone/2)) * blend))  (1 if blend = 0
                and theta inside the cone); theta = angle between the ray and the optical axis
    irradiance  E = I s(theta) cos(incidence) / d^2                        W/m^2, d = distance light->point
    radiance    L = rho E / pi                                            W/(m^2 sr), Lambertian
    pixel       255 * linear_to_srgb(min(1, exposure * L)), rounded

The exposure is fixed per job (RenderConfig.exposure, or derived from the job's brightest spot light),
never per frame or per video, so a 200 W render is 10x brighter than a 20 W render before clipping.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from pipeline.config import Illumination, Job
from pipeline.render.raycaster import RayHits
from pipeline.scenes.scene import Scene

# Exposure derived when the job gives none: a white Lambertian surface facing the brightest spot
# light of the job, on its axis at this distance, is exactly full scale.
REFERENCE_DISTANCE_M = 2.0
# Albedo of faces without colour information (neither vertex colours nor a texture).
DEFAULT_GREY = 160


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear reflectance (IEC 61966-2-1)."""
    values = np.asarray(values, np.float32)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """Linear values in [0, 1] -> sRGB encoding in [0, 1] (IEC 61966-2-1)."""
    values = np.clip(np.asarray(values, np.float32), 0.0, 1.0)
    return np.where(values <= 0.0031308, values * 12.92, 1.055 * values ** (1 / 2.4) - 0.055).astype(np.float32)


def cone_solid_angle(cone_degrees: float) -> float:
    """Solid angle (sr) of a cone of full angle `cone_degrees` (2 pi for a 180-degree cone)."""
    return 2.0 * math.pi * (1.0 - math.cos(math.radians(cone_degrees) / 2.0))


def radiant_intensity(illumination: Illumination) -> float:
    """I = P / Omega in W/sr: the light's power spread evenly over its cone."""
    return illumination.power / cone_solid_angle(illumination.cone)


def cone_falloff(cos_theta: np.ndarray, illumination: Illumination) -> np.ndarray:
    """Fraction of the light reaching direction theta off the axis: 1 inside, smooth fade over `blend`."""
    cos_edge = math.cos(math.radians(illumination.cone) / 2.0)
    width = (1.0 - cos_edge) * illumination.blend
    if width <= 0.0:
        return (cos_theta >= cos_edge).astype(np.float32)
    x = np.clip((cos_theta - cos_edge) / width, 0.0, 1.0)
    return (x * x * (3.0 - 2.0 * x)).astype(np.float32)


def job_exposure(job: Job) -> float:
    """The job's exposure (scale from radiance W/(m^2 sr) to full scale): given, or derived.

    Derived from the brightest spot light of the job so that every spot embodiment of a job shares
    one exposure; a job without spot lights gets the exposure a 20 W light would (unused by ambient).
    """
    if job.render.exposure is not None:
        return float(job.render.exposure)
    spots = [e.illumination for e in job.embodiments if e.illumination.kind == "spot"]
    brightest = max(spots, key=radiant_intensity) if spots else Illumination(kind="spot", power=20.0)
    # White (rho = 1) on the axis, facing the light, at the reference distance: L = I / (pi d^2).
    radiance = radiant_intensity(brightest) / (math.pi * REFERENCE_DISTANCE_M**2)
    return 1.0 / radiance


class SurfaceColors:
    """Looks up the sRGB albedo (uint8) of ray hits on one scene, as channel planes (3, H, W).

    Vertex colours are interpolated barycentrically (in sRGB, like a rasterizer); textures are sampled
    at the nearest texel with wrap-around (u right, v up). Faces with neither get DEFAULT_GREY.
    Per-face tables carry one trailing entry (black) for rays that hit nothing (RayHits.face == F).

    Why planes: the per-pixel arithmetic then runs over long contiguous rows; on interleaved (N, 3) arrays
    numpy broadcasts a per-pixel weight over a 3-long inner axis, which measured 4x slower.
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        self._corners: np.ndarray | None = None
        self._flat = False
        if scene.vertex_colors is not None:
            corners = scene.vertex_colors[scene.faces]  # (F, 3 corners, 3 channels) uint8
            # Flat-coloured faces (every corner alike): one gather per frame, no arithmetic.
            self._flat = bool(np.all(corners == corners[:, :1]))
            self._corners = _face_records(corners)

    def albedo(self, hits: RayHits) -> np.ndarray:
        """(H, W, 3) uint8 sRGB albedo at each hit; 0 where nothing was hit."""
        return interleave(self.planes(hits))

    def planes(self, hits: RayHits) -> np.ndarray:
        """(3, H, W) uint8 sRGB albedo planes (R, G, B) at each hit; 0 where nothing was hit."""
        shape = (3, *hits.depth.shape)
        if self._corners is not None:
            records = _transposed(np.take(self._corners, hits.face.ravel()))  # (16, H*W) uint8: corner-major
            if self._flat:
                return records[0:3].reshape(shape)
            return self._interpolated(records, hits.barycentric.reshape(-1, 2)).reshape(shape)
        out = np.zeros((*hits.depth.shape, 3), np.uint8)
        if self.scene.face_uvs is not None and self.scene.face_material is not None and self.scene.textures:
            out[hits.hit] = self._texture_albedo(hits.face[hits.hit], hits.barycentric[hits.hit])
        else:
            out[hits.hit] = DEFAULT_GREY
        return np.ascontiguousarray(np.moveaxis(out, -1, 0))

    @staticmethod
    def _interpolated(records: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        # colour = c0 + 0.5 + u (c1 - c0) + v (c2 - c0) in float32, truncated (the + 0.5 rounds).
        c0, c1, c2 = records[0:3], records[3:6], records[6:9]
        u, v = barycentric[:, 0], barycentric[:, 1]
        colour = np.add(c0, np.float32(0.5), dtype=np.float32)
        term = np.subtract(c1, c0, dtype=np.float32)
        term *= u
        colour += term
        np.subtract(c2, c0, out=term, dtype=np.float32)
        term *= v
        colour += term
        np.clip(colour, 0.0, 255.0, out=colour)
        return colour.astype(np.uint8)

    def _texture_albedo(self, faces: np.ndarray, bary: np.ndarray) -> np.ndarray:
        uvs = self.scene.face_uvs[faces].astype(np.float32)  # type: ignore[index]
        w0 = (1.0 - bary[:, 0] - bary[:, 1])[:, None]
        uv = w0 * uvs[:, 0] + bary[:, :1] * uvs[:, 1] + bary[:, 1:] * uvs[:, 2]
        materials = self.scene.face_material[faces]  # type: ignore[index]
        colors = np.full((len(faces), 3), DEFAULT_GREY, np.uint8)
        for material in np.unique(materials):
            if material >= len(self.scene.textures):
                continue  # a face naming a missing texture keeps the default grey
            texture = self.scene.textures[int(material)]
            height, width = texture.shape[:2]
            mask = materials == material
            column = np.floor((uv[mask, 0] % 1.0) * width).astype(np.int64) % width
            row = np.floor((1.0 - uv[mask, 1] % 1.0) * height).astype(np.int64) % height
            colors[mask] = texture[row, column, :3]
        return colors


def _face_records(corners: np.ndarray) -> np.ndarray:
    """(F + 1,) 16-byte records of the (F, 3, 3) uint8 corner colours (9 bytes, zero padded), the last
    one zero (the miss entry). One 16-byte gather per pixel is numpy's fast path and touches one cache
    line per face, where three separate (F, 3) tables measured 3x slower."""
    records = np.zeros((len(corners) + 1, 16), np.uint8)
    records[:-1, :9] = corners.reshape(len(corners), 9)
    return records.view("V16").ravel()


def _transposed(records: np.ndarray) -> np.ndarray:
    """(16, N) uint8 byte planes of N gathered 16-byte records (cv2's SIMD transpose: 1 ms per 640x480)."""
    return cv2.transpose(records.view(np.uint8).reshape(-1, 16))


def interleave(planes: np.ndarray) -> np.ndarray:
    """(3, H, W) uint8 channel planes -> (H, W, 3) interleaved image."""
    return cv2.merge([planes[0], planes[1], planes[2]])


class Shader:
    """Turns albedo and hits into the 8-bit RGB frame for one illumination and a job's exposure."""

    def __init__(self, illumination: Illumination, exposure: float, ray_lengths: np.ndarray):
        """`ray_lengths`: (H, W) norms of the camera-frame ray directions (x, y, 1), fixed per camera."""
        self.illumination = illumination
        self.exposure = exposure
        self.ray_lengths = ray_lengths.astype(np.float32)
        # The light sits at the camera looking along the optical axis: theta is the ray's angle off axis.
        self.cone = cone_falloff(1.0 / self.ray_lengths, illumination) if illumination.kind == "spot" else None
        self._encode_steps = 4096
        if self.cone is not None:
            # Everything per pixel that does not depend on the scene: I s(theta) exposure steps / (pi |ray|^3).
            scale = (radiant_intensity(illumination) * exposure / math.pi) * self.cone / self.ray_lengths
            self._spot_scale_steps = (scale / (self.ray_lengths * self.ray_lengths)).astype(np.float32)
            self._spot_scale_steps *= np.float32(self._encode_steps)
        self._decode = srgb_to_linear(np.arange(256) / 255.0)
        self._encode = np.rint(255.0 * linear_to_srgb(np.arange(self._encode_steps + 1) / self._encode_steps))
        self._encode = self._encode.astype(np.uint8)

    def shade(self, albedo: np.ndarray, hits: RayHits) -> np.ndarray:
        """(H, W, 3) uint8 frame from (3, H, W) albedo planes. Ambient is the albedo; spot applies the
        model of schemas/render.md."""
        if self.illumination.kind == "ambient":
            return interleave(albedo)
        return self._spot(albedo, hits)

    def _spot(self, albedo: np.ndarray, hits: RayHits) -> np.ndarray:
        # Whole-frame arithmetic (no masks): a miss or a clipped hit has depth inf, so its irradiance is
        # exactly 0 (the caster's normal of a miss is 0, never NaN).
        normal, direction = hits.normal, hits.direction
        # cos(incidence) = |n . ray| / |ray|: meshes do not always wind consistently, so either side is lit.
        dot = normal[..., 0] * direction[..., 0]
        dot += normal[..., 1] * direction[..., 1]
        dot += normal[..., 2] * direction[..., 2]
        np.abs(dot, out=dot)
        # Radiance rho E / pi, times exposure and the encoder's steps: |n . ray| I s exposure steps /
        # (pi |ray| d^2) with d = z |ray| (the light is at the eye). The factor of steps is a power of two,
        # so folding it in here rounds exactly like scaling the clipped linear value afterwards.
        dot *= self._spot_scale_steps
        with np.errstate(divide="ignore", invalid="ignore"):
            dot /= hits.depth * hits.depth
        linear = cv2.LUT(albedo.reshape(3, -1), self._decode)  # srgb_to_linear per uint8 value
        linear *= dot.reshape(1, -1)
        np.clip(linear, 0.0, float(self._encode_steps), out=linear)  # clip: 3x faster than np.minimum here
        linear += 0.5
        encoded = np.take(self._encode, linear.astype(np.int32))
        return interleave(encoded.reshape(albedo.shape))
