"""How a surface reflects the spot light: `diffuse` (Lambertian) or `principled` (MVPd's Principled BSDF).

MVPd's Cycles renders used Blender's Principled BSDF with specular 1.0 and roughness 0.5 on the scan's
colour. As Cycles (4.x and later) evaluates it for a dielectric, that is a Lambertian base of albedo rho
under a GGX microfacet lobe (alpha = roughness^2, height-correlated Smith masking, real dielectric Fresnel
of the IOR whose normal-incidence reflectance is F0 = 0.08 * specular, multiple scattering between the
microfacets added by the factor M(mu) of `multiscatter_energy`); the base is weighted by 1 - A(mu), A being
the lobe's albedo with Fresnel for the view direction (Cycles' albedo scaling of layered closures).

The light sits at the eye, so light and view directions coincide: the half vector is the view vector,
v.h = 1 and the Fresnel term is F0 for every pixel. What the spot adds to a pixel then depends on one
number, mu = cos(incidence), and tables of mu (`ReflectionTables`) serve every frame:

    L_direct   = E_direct / pi * (rho * diffuse(mu) + specular(mu))
    diffuse    = 1 - A(mu)                            (1 for `diffuse`)
    specular   = pi * D(mu) G2(mu, mu) F0 / (4 mu^2) * M(mu)        (0 for `diffuse`)

Bounced light arrives from other directions than the eye, so it meets the full lobe, f(w_i, w_o) =
rho (1 - A(mu_o)) / pi + D(h) G2 F(w_o . h) / (4 mu_i mu_o) M(mu_o) (`glossy_brdf` and the tables'
`energy` = M; w_o is the direction the light leaves towards, as Cycles weighs by the view side).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from pipeline.config import Illumination

TABLE_SIZE = 1024  # entries over mu in [0, 1]: the shading loop reads entry round(mu * (TABLE_SIZE - 1))
_QUADRATURE = 192  # incoming directions per axis when integrating the lobe's albedo


@dataclass(frozen=True)
class ReflectionTables:
    """float32 (TABLE_SIZE,) tables over mu = cos(incidence): weights of the diffuse base and the specular
    lobe under the coincident spot, the lobe's albedo (what it reflects of uniform incident light) and its
    multiple-scattering factor M; the lobe's GGX alpha and IOR (IOR 1 reflects nothing: `diffuse`)."""

    diffuse: np.ndarray
    specular: np.ndarray
    albedo: np.ndarray
    energy: np.ndarray
    alpha: float = 1.0
    ior: float = 1.0


def reflection_tables(illumination: Illumination) -> ReflectionTables:
    """The tables of an illumination's material (cached per material parameters)."""
    if illumination.material == "diffuse":
        return _diffuse_tables()
    return _principled_tables(illumination.specular, illumination.roughness)


@functools.cache
def _diffuse_tables() -> ReflectionTables:
    ones, zeros = np.ones(TABLE_SIZE, np.float32), np.zeros(TABLE_SIZE, np.float32)
    return ReflectionTables(ones, zeros, zeros, ones)


@functools.cache
def _principled_tables(specular: float, roughness: float) -> ReflectionTables:
    alpha = roughness * roughness
    f0 = 0.08 * specular
    ior = (1.0 + math.sqrt(f0)) / (1.0 - math.sqrt(f0))  # the IOR whose normal-incidence Fresnel is f0
    mu = np.linspace(0.0, 1.0, TABLE_SIZE)
    mu_safe = np.maximum(mu, 1e-4)
    # Albedos vary slowly with mu: integrate at 65 points and interpolate.
    coarse = np.linspace(1e-3, 1.0, 65)
    coarse_single, coarse_fresnel = lobe_albedos(coarse, alpha, ior)
    single, with_fresnel = (np.interp(mu_safe, coarse, values) for values in (coarse_single, coarse_fresnel))
    lobe = ggx_distribution(mu_safe, alpha) * smith_g2(mu_safe, mu_safe, alpha) * f0 / (4.0 * mu_safe**2)
    energy = multiscatter_energy(single, cosine_average(coarse, coarse_single),
                                 cosine_average(coarse, fresnel_dielectric(coarse, ior)))
    albedo = np.clip(with_fresnel * energy, 0.0, 1.0)
    lobe[0] = 0.0  # mu = 0: a grazing hit (or a miss, whose light is 0 anyway) shows no highlight
    return ReflectionTables(diffuse=(1.0 - albedo).astype(np.float32),
                            specular=(math.pi * lobe * energy).astype(np.float32),
                            albedo=albedo.astype(np.float32), energy=energy.astype(np.float32), alpha=alpha, ior=ior)


def multiscatter_energy(single: np.ndarray, single_average: float, fresnel_average: float) -> np.ndarray:
    """Cycles' multiple-scattering factor of a dielectric GGX lobe (`microfacet_ggx_preserve_energy`, after
    Kulla and Conty 2017): 1 + F_ms (1 - E) / E, F_ms = F_avg E_avg / (1 - F_avg (1 - E_avg)), with E the
    single-scattering albedo for the view direction and the averages over the hemisphere. The light the lobe's
    microfacets bounce between each other meets the Fresnel term again at each bounce, so a dielectric gets back
    only the F_ms share of what single scattering misses (1 / E would assume a perfect mirror: 5 % too bright
    at roughness 0.5, measured against Cycles' principled direct light)."""
    fresnel_ms = fresnel_average * single_average / (1.0 - fresnel_average * (1.0 - single_average))
    return 1.0 + fresnel_ms * (1.0 - single) / single


def cosine_average(mu: np.ndarray, values: np.ndarray) -> float:
    """2 * integral of values(mu) mu dmu over [0, 1] (the hemispherical average of a function of mu),
    trapezoidal on the samples `mu` (extended to mu = 0 with the first value)."""
    mu, values = np.concatenate([[0.0], mu]), np.concatenate([values[:1], values])
    return float(2.0 * np.trapezoid(values * mu, mu))


def ggx_distribution(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """GGX (Trowbridge-Reitz) normal distribution D at cos(theta_h)."""
    a2 = alpha * alpha
    denominator = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (math.pi * denominator * denominator)


def smith_lambda(cos: np.ndarray, alpha: float) -> np.ndarray:
    """Smith's Lambda of GGX for a direction at cos(theta) to the normal."""
    cos2 = np.clip(cos * cos, 1e-12, 1.0)
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 - cos2) / cos2) - 1.0)


def smith_g2(cos_in: np.ndarray, cos_out: np.ndarray, alpha: float) -> np.ndarray:
    """Height-correlated masking-shadowing G2 (as Cycles uses it)."""
    return 1.0 / (1.0 + smith_lambda(cos_in, alpha) + smith_lambda(cos_out, alpha))


def fresnel_dielectric(cos: np.ndarray, ior: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a dielectric of relative index `ior` (from outside)."""
    g2 = ior * ior - 1.0 + cos * cos
    g = np.sqrt(np.maximum(g2, 0.0))
    a = (g - cos) / (g + cos)
    b = (cos * (g + cos) - 1.0) / (cos * (g - cos) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


def lobe_albedos(mu: np.ndarray, alpha: float, ior: float) -> tuple[np.ndarray, np.ndarray]:
    """Directional albedos of the single-scattering GGX lobe seen from cos(theta_o) = mu: without Fresnel
    (E_ss, for the energy compensation) and with dielectric Fresnel. Midpoint quadrature over the
    incoming hemisphere in (cos theta_i, phi), vectorised; exact enough for 8-bit output (< 1e-3)."""
    n = _QUADRATURE
    cos_i = (np.arange(n) + 0.5) / n
    phi = (np.arange(n) + 0.5) / n * 2.0 * math.pi
    sin_i = np.sqrt(1.0 - cos_i**2)
    wi = np.stack([np.outer(sin_i, np.cos(phi)), np.outer(sin_i, np.sin(phi)), np.repeat(cos_i[:, None], n, 1)], -1)
    weight = (1.0 / n) * (2.0 * math.pi / n)  # d(cos theta) d(phi)
    single, fresnel = np.empty_like(mu), np.empty_like(mu)
    for k, cos_o in enumerate(mu):
        wo = np.array([math.sqrt(max(0.0, 1.0 - cos_o * cos_o)), 0.0, cos_o])
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        brdf = ggx_distribution(h[..., 2], alpha) * smith_g2(wi[..., 2], cos_o, alpha) / (4.0 * cos_o)
        # brdf * cos_i already folds the cos_i of the integrand against the 4 cos_i cos_o denominator
        single[k] = np.sum(brdf) * weight
        fresnel[k] = np.sum(brdf * fresnel_dielectric(np.sum(h * wo, -1), ior)) * weight
    return single, fresnel


@numba.njit(nogil=True, cache=True, error_model="numpy")
def glossy_brdf(cos_h, cos_i, cos_o, cos_oh, alpha, ior, real):  # pragma: no cover (compiled)
    """The single-scattering GGX lobe D G2 F / (4 mu_i mu_o) for unit directions at cosines cos_i, cos_o to
    the normal, cos_h between normal and half vector, cos_oh between w_o and the half vector, computed in the
    float type `real` (np.float32 or np.float64: its constants take that type, so float32 arguments stay float32;
    the gather's pairs are float32, which vectorises). Compiled callers pass scalars; outside the domain (a
    cosine <= 0) the value is meaningless and must be masked by the caller (no error is raised)."""
    one = real(1.0)
    a2 = alpha * alpha
    d = cos_h * cos_h * (a2 - one) + one
    distribution = a2 / (real(math.pi) * d * d)
    lambda_i = real(0.5) * (np.sqrt(one + a2 * (one / (cos_i * cos_i) - one)) - one)
    lambda_o = real(0.5) * (np.sqrt(one + a2 * (one / (cos_o * cos_o) - one)) - one)
    g = np.sqrt(max(ior * ior - one + cos_oh * cos_oh, real(0.0)))
    a = (g - cos_oh) / (g + cos_oh)
    b = (cos_oh * (g + cos_oh) - one) / (cos_oh * (g - cos_oh) + one)
    fresnel = real(0.5) * a * a * (one + b * b)
    return distribution * fresnel / ((one + lambda_i + lambda_o) * real(4.0) * cos_i * cos_o)
