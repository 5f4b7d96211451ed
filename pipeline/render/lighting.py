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
import numba
import numpy as np

from pipeline.config import Illumination, Job
from pipeline.render.material import reflection_tables
from pipeline.render.raycaster import RayHits
from pipeline.scenes.scene import Scene

# Exposure derived when the job gives none: a white Lambertian surface facing the brightest spot
# light of the job, on its axis at this distance, is exactly full scale.
REFERENCE_DISTANCE_M = 2.0
# Pixels per side of the blocks that share one value of indirect light (indirect/upsample.py): 1, every pixel
# its own. 2 x 2 blocks took their first pixel's surface, wrong for the other pixels where the block straddles
# two surfaces: 1-3 % of the pixels carried 17-30 % of the squared error against the reference.
INDIRECT_BLOCK = 1
# Albedo of faces without colour information (neither vertex colours nor a texture).
DEFAULT_GREY = 160


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear reflectance (IEC 61966-2-1)."""
    values = np.asarray(values, np.float32)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4).astype(np.float32)


# The linear reflectance of each 8-bit sRGB level: a lookup where albedos are decoded per pixel, light or bounce.
LINEAR_OF_LEVEL = srgb_to_linear(np.arange(256) / 255.0)


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
    """Looks up the sRGB albedo (uint8) of ray hits on one scene.

    Vertex colours are interpolated barycentrically (in sRGB, like a rasterizer); textures are sampled
    at the nearest texel with wrap-around (u right, v up). Faces with neither get DEFAULT_GREY.
    Per-face tables carry one trailing entry (black) for rays that hit nothing (RayHits.face == F).

    Vertex-coloured scenes (generated houses) keep one 16-byte record of corner colours per face, which
    the compiled shading loop reads directly (`Shader.shade_surfaces`); other scenes give albedo planes.
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        self.records: np.ndarray | None = None
        self.flat = False
        if scene.vertex_colors is not None:
            corners = scene.vertex_colors[scene.faces]  # (F, 3 corners, 3 channels) uint8
            # Flat-coloured faces (every corner alike): no interpolation at all.
            self.flat = bool(np.all(corners == corners[:, :1]))
            self.records = _face_records(corners)

    def albedo(self, hits: RayHits) -> np.ndarray:
        """(H, W, 3) uint8 sRGB albedo at each hit; 0 where nothing was hit."""
        if self.records is not None:
            return _shade(hits, records=self.records, interpolate=not self.flat)
        return interleave(self.planes(hits))

    def planes(self, hits: RayHits) -> np.ndarray:
        """(3, H, W) uint8 sRGB albedo planes (R, G, B) at each hit; 0 where nothing was hit."""
        if self.records is not None:
            return np.ascontiguousarray(np.moveaxis(self.albedo(hits), -1, 0))
        out = np.zeros((*hits.depth.shape, 3), np.uint8)
        if self.scene.face_uvs is not None and self.scene.face_material is not None and self.scene.textures:
            out[hits.hit] = self._texture_albedo(hits.face[hits.hit], hits.barycentric[hits.hit])
        else:
            out[hits.hit] = DEFAULT_GREY
        return np.ascontiguousarray(np.moveaxis(out, -1, 0))

    def albedo_at(self, faces: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(n, 3) uint8 sRGB albedo at points given by triangle and Embree barycentrics (u, v), as `albedo`
        computes it for pixels; for the bounces of indirect light."""
        if self.records is None:
            if self.scene.face_uvs is not None and self.scene.face_material is not None and self.scene.textures:
                return self._texture_albedo(faces, barycentric)
            return np.full((len(faces), 3), DEFAULT_GREY, np.uint8)
        corners = self.records[faces, :9].reshape(-1, 3, 3).astype(np.float32)
        if not self.flat:
            u, v = barycentric[:, :1].astype(np.float32), barycentric[:, 1:].astype(np.float32)
            colour = corners[:, 0] + np.float32(0.5) + u * (corners[:, 1] - corners[:, 0]) + v * (corners[:, 2] - corners[:, 0])
            return np.clip(colour, 0, 255).astype(np.uint8)
        return corners[:, 0].astype(np.uint8)

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
    """(F + 1, 16) uint8: the (F, 3, 3) corner colours (9 bytes, zero padded to one 16-byte record per
    face, so a pixel's lookup touches one cache line), then the miss entry (black)."""
    records = np.zeros((len(corners) + 1, 16), np.uint8)
    records[:-1, :9] = corners.reshape(len(corners), 9)
    return records


def interleave(planes: np.ndarray) -> np.ndarray:
    """(3, H, W) uint8 channel planes -> (H, W, 3) interleaved image."""
    return cv2.merge([planes[0], planes[1], planes[2]])


class Shader:
    """Turns albedo and hits into the 8-bit RGB frame for one illumination and a job's exposure."""

    def __init__(self, illumination: Illumination, exposure: float, ray_lengths: np.ndarray, first_row: int = 0):
        """`ray_lengths`: (H, W) norms of the camera-frame ray directions (x, y, 1), fixed per camera;
        `first_row`: the frame row of their first row (a shader of a band of rows)."""
        self.first_row = first_row
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
        self._decode = LINEAR_OF_LEVEL
        self._encode = np.rint(255.0 * linear_to_srgb(np.arange(self._encode_steps + 1) / self._encode_steps))
        self._encode = self._encode.astype(np.uint8)
        self.tables = reflection_tables(illumination)
        # Indirect irradiance (W/m^2) -> the same units as the direct term: exposure * steps / pi.
        self.indirect_scale = np.float32(exposure * self._encode_steps / math.pi)
        self._material = (self.tables.diffuse, self.tables.specular)

    def shade(self, albedo: np.ndarray, hits: RayHits, indirect: np.ndarray | None = None) -> np.ndarray:
        """(H, W, 3) uint8 frame from (3, H, W) albedo planes. Ambient is the albedo; spot applies the
        model of schemas/render.md, plus `indirect` light of the whole frame when given, one value per
        INDIRECT_BLOCK x INDIRECT_BLOCK pixels (IndirectGather.irradiance: irradiance and glossy term)."""
        if self.illumination.kind == "ambient":
            return interleave(albedo)
        return _shade(hits, planes=albedo, scale_steps=self._spot_scale_steps, decode=self._decode, encode=self._encode,
                      material=self._lit_material(), indirect=indirect, indirect_scale=self.indirect_scale,
                      first_row=self.first_row)

    def shade_surfaces(self, colors: SurfaceColors, hits: RayHits, out: np.ndarray | None = None,
                       indirect: np.ndarray | None = None, indirect_scale: float = 1.0, first_row: int = 0) -> np.ndarray:
        """The same frame as `shade(colors.planes(hits), hits, indirect)` (into `out` when given); for
        vertex-coloured scenes in one pass over the pixels (albedo, light and encoding per pixel: 2.4x faster
        than whole-array passes)."""
        if colors.records is None:
            frame = self.shade(colors.planes(hits), hits, indirect)
            if out is not None:
                out[...] = frame
            return frame if out is None else out
        spot = self.illumination.kind == "spot"
        return _shade(hits, records=colors.records, interpolate=not colors.flat, out=out,
                      scale_steps=self._spot_scale_steps if spot else None, decode=self._decode, encode=self._encode,
                      material=self._lit_material() if spot else None, indirect=indirect if spot else None,
                      indirect_scale=self.indirect_scale, first_row=self.first_row)

    def spot_terms(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(scale_steps, decode, encode) of a spot on diffuse surfaces: all a pixel lit by the spot alone needs of
        the shader besides its albedo, normal, ray and depth (`_shade_pixels`' docstring), for fused.FramePass."""
        if self.cone is None or self.illumination.material != "diffuse":
            raise ValueError(f"spot_terms light diffuse surfaces by a spot, not {self.illumination.kind} light on "
                             f"{self.illumination.material} ones: shade those with Shader.shade_surfaces")
        return self._spot_scale_steps, self._decode, self._encode

    def _lit_material(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The principled tables, or None for a diffuse surface (its frames keep today's exact arithmetic)."""
        return self._material if self.illumination.material == "principled" else None



# Placeholders of the right types for the inputs a call of the shading loop does not use, so that it is
# compiled once per process (the arrays' types, not their sizes, pick the compiled version).
_NO_RECORDS, _NO_PLANES = np.zeros((1, 16), np.uint8), np.zeros((3, 1, 1), np.uint8)
_NO_SCALE, _NO_DECODE, _NO_ENCODE = np.zeros((1, 1), np.float32), np.zeros(1, np.float32), np.zeros(1, np.uint8)
_NO_TABLE, _NO_INDIRECT = np.zeros(1, np.float32), np.zeros((1, 1, 6), np.float32)


def _shade(hits: RayHits, records: np.ndarray | None = None, planes: np.ndarray | None = None,
           interpolate: bool = False, scale_steps: np.ndarray | None = None, decode: np.ndarray = _NO_DECODE,
           encode: np.ndarray = _NO_ENCODE, out: np.ndarray | None = None,
           material: tuple[np.ndarray, np.ndarray] | None = None,
           indirect: np.ndarray | None = None, indirect_scale: float = 1.0, first_row: int = 0) -> np.ndarray:
    """(H, W, 3) uint8 frame (into `out` when given): albedo from per-face `records` or from `planes`, lit
    by the spot model when `scale_steps` is given (with `decode` and `encode`), else the albedo itself;
    `material` = the principled (diffuse, specular) tables; `indirect` irradiance and glossy term (RGB each) of
    the whole frame per INDIRECT_BLOCK x INDIRECT_BLOCK pixels, times `indirect_scale` in encoder steps;
    `first_row`: frame row of hits' row 0."""
    out = np.empty((*hits.depth.shape, 3), np.uint8) if out is None else out
    if records is not None and interpolate and material is None and indirect is None:
        # The two common frames (vertex-coloured scans under ambient or direct diffuse spot light) in a loop
        # of their own: the general loop's per-pixel mode tests cost ~15 % (ambient) to ~30 % (spot) of it.
        _vertex_colour_pixels(records, hits.face, hits.barycentric, out, scale_steps is not None, hits.normal,
                              hits.direction, hits.depth, _NO_SCALE if scale_steps is None else scale_steps, decode,
                              encode)
        return out
    diffuse, specular = material if material is not None else (_NO_TABLE, _NO_TABLE)
    _shade_pixels(_NO_RECORDS if records is None else records, _NO_PLANES if planes is None else planes,
                  records is not None, interpolate, scale_steps is not None, hits.face, hits.barycentric,
                  hits.normal, hits.direction, hits.depth, _NO_SCALE if scale_steps is None else scale_steps,
                  decode, encode, out, material is not None, diffuse, specular,
                  indirect is not None, _NO_INDIRECT if indirect is None else indirect, np.float32(indirect_scale),
                  first_row, INDIRECT_BLOCK)
    return out


@numba.njit(nogil=True, cache=True)
def _shade_pixels(records, planes, from_records, interpolate, spot, face, barycentric, normal, direction, depth,
                  scale_steps, decode, encode, out, principled, diffuse_table, specular_table,
                  lit_indirectly, indirect, indirect_scale, first_row, block):  # pragma: no cover (compiled)
    """Every pixel in float32 with a fixed order of operations (no fast-math), so runs are bit-identical:

    albedo  a = c0 + 0.5 + u (c1 - c0) + v (c2 - c0), clipped to [0, 255], truncated (the + 0.5 rounds)
    spot    s = |n . ray| scale_steps / z^2: the radiance rho E / pi of schemas/render.md times exposure and
            the encoder's steps, with d = z |ray| (the light is at the eye) and |n . ray| / |ray| the
            cosine of incidence, either side lit (meshes do not always wind consistently); a miss has
            z = inf and n = 0, so it is black. The steps are a power of two: folding them in rounds
            exactly like scaling the clipped linear value afterwards.
            out = encode[trunc(clip(decode[a] s, 0, steps) + 0.5)]
    principled / indirect (material.py; m = table entry of mu = |n . ray| / |ray|, i and g = indirect
            irradiance and glossy term of the pixel's block times indirect_scale: the same units as s):
            out = encode[trunc(clip(decode[a] (s + i) diffuse[m] + s specular[m] + g, 0, steps) + 0.5)]
            (a diffuse surface: diffuse = 1, specular = g = 0)
    """
    height, width = face.shape
    steps = np.float32(len(encode) - 1)
    half, low = np.float32(0.5), np.float32(0.0)
    last_entry = np.float32(len(diffuse_table) - 1)
    for row in range(height):
        # The block of indirect light, out of the channel loop (its integer divisions there took ~40 % of the time).
        block_row = (first_row + row) // block
        for column in range(width):
            block_column = column // block
            f = face[row, column]
            light = np.float32(0.0)
            base, gloss = np.float32(1.0), np.float32(0.0)
            if spot:
                facing, light = _spot_light(normal, direction, depth, scale_steps, row, column)
                if principled:
                    length = direction[row, column, 0] * direction[row, column, 0]
                    length += direction[row, column, 1] * direction[row, column, 1]
                    length += direction[row, column, 2] * direction[row, column, 2]
                    entry = np.int32(min(abs(facing) / np.sqrt(length), np.float32(1.0)) * last_entry + half)
                    base, gloss = diffuse_table[entry], specular_table[entry]
            u, v = barycentric[row, column, 0], barycentric[row, column, 1]
            for channel in range(3):
                if not from_records:
                    albedo = planes[channel, row, column]
                elif interpolate:
                    albedo = _interpolated_albedo(records, f, channel, u, v)
                else:
                    albedo = records[f, channel]
                if spot and (principled or lit_indirectly):
                    received, glossy = np.float32(0.0), np.float32(0.0)
                    if lit_indirectly:
                        received = indirect[block_row, block_column, channel] * indirect_scale
                        glossy = indirect[block_row, block_column, 3 + channel] * indirect_scale
                    linear = decode[albedo] * (light + received) * base + light * gloss + glossy
                    out[row, column, channel] = encode[np.int32(min(max(linear, low), steps) + half)]
                elif spot:
                    linear = min(max(decode[albedo] * light, low), steps) + half
                    out[row, column, channel] = encode[np.int32(linear)]
                else:
                    out[row, column, channel] = albedo


@numba.njit(nogil=True, cache=True, inline="always")
def _interpolated_albedo(records, f, channel, u, v):  # pragma: no cover (compiled)
    """Channel `channel` of face `f`'s vertex colours at barycentrics (u, v): c0 + 0.5 + u (c1 - c0) + v (c2 - c0)
    in float32, clipped to [0, 255] and truncated (the + 0.5 rounds); every shading loop's albedo."""
    c0 = np.float32(records[f, channel])
    colour = c0 + np.float32(0.5)
    colour += (np.float32(records[f, 3 + channel]) - c0) * u
    colour += (np.float32(records[f, 6 + channel]) - c0) * v
    return np.uint8(min(max(colour, np.float32(0.0)), np.float32(255.0)))


@numba.njit(nogil=True, cache=True, inline="always")
def _spot_light(normal, direction, depth, scale_steps, row, column):  # pragma: no cover (compiled)
    """(n . ray, s) of a pixel: s = |n . ray| scale_steps / z^2, the spot's radiance in encoder steps per unit
    of linear albedo (`_shade_pixels`' docstring)."""
    return _spot_of(normal[row, column, 0], normal[row, column, 1], normal[row, column, 2], direction[row, column, 0],
                    direction[row, column, 1], direction[row, column, 2], scale_steps[row, column], depth[row, column])


@numba.njit(nogil=True, cache=True, inline="always")
def _spot_of(nx, ny, nz, dx, dy, dz, scale, z):  # pragma: no cover (compiled)
    """`_spot_light` of a pixel's normal n, ray d, scale_steps and depth z, given as float32 scalars (the fused pass
    has them in registers): (n . d, |n . d| scale / z^2), in that order of operations."""
    facing = nx * dx
    facing += ny * dy
    facing += nz * dz
    light = abs(facing) * scale
    light /= z * z
    return facing, light


@numba.njit(nogil=True, cache=True, inline="always")
def _lit_albedo(decode, encode, albedo, light, steps):  # pragma: no cover (compiled)
    """A channel of a pixel lit by the spot alone on a diffuse surface: encode[trunc(clip(decode[a] s, 0, steps) +
    0.5)] (`_shade_pixels`' docstring). An unsigned index (the value is >= 0.5) spares Numba's negative-index test:
    ~11 % of the loop."""
    return encode[np.uintp(min(max(decode[albedo] * light, np.float32(0.0)), steps) + np.float32(0.5))]


@numba.njit(nogil=True, cache=True, inline="always")
def _face_terms(records, f, terms):  # pragma: no cover (compiled)
    """Face `f`'s terms of `_interpolated_albedo` into `terms` (3 channels x (c0 + 0.5, c1 - c0, c2 - c0))."""
    for channel in range(3):
        c0 = np.float32(records[f, channel])
        terms[channel, 0] = c0 + np.float32(0.5)
        terms[channel, 1] = np.float32(records[f, 3 + channel]) - c0
        terms[channel, 2] = np.float32(records[f, 6 + channel]) - c0


@numba.njit(nogil=True, cache=True, inline="always")
def _albedo_of_terms(terms, channel, u, v):  # pragma: no cover (compiled)
    """`_interpolated_albedo` from the face's `_face_terms`: the same float32 operations in the same order."""
    colour = terms[channel, 0]
    colour += terms[channel, 1] * u
    colour += terms[channel, 2] * v
    return np.uint8(min(max(colour, np.float32(0.0)), np.float32(255.0)))


@numba.njit(nogil=True, cache=True)
def _vertex_colour_pixels(records, face, barycentric, out, spot, normal, direction, depth, scale_steps, decode,
                          encode):  # pragma: no cover (compiled)
    """`_shade_pixels` for interpolated vertex colours under ambient light (the albedo itself) or, with `spot`,
    on a diffuse surface lit by the spot alone: the same float32 operations in the same order (see its
    docstring), without the tests of the modes it does not use, and a face's colour terms taken once per run
    of pixels on it along a row (a bench frame shows ~9 k faces in 307 k pixels: ~30 % of an ambient frame's
    shading). Two loops of their own would save another ~7 % of the ambient one."""
    height, width = face.shape
    steps = np.float32(len(encode) - 1)
    terms = np.empty((3, 3), np.float32)
    for row in range(height):
        last = -1
        for column in range(width):
            f = face[row, column]
            if f != last:
                _face_terms(records, f, terms)
                last = f
            u, v = barycentric[row, column, 0], barycentric[row, column, 1]
            if not spot:
                for channel in range(3):
                    out[row, column, channel] = _albedo_of_terms(terms, channel, u, v)
                continue
            light = _spot_light(normal, direction, depth, scale_steps, row, column)[1]
            for channel in range(3):
                out[row, column, channel] = _lit_albedo(decode, encode, _albedo_of_terms(terms, channel, u, v), light, steps)
