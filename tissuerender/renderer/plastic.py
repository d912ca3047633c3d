"""The rough-plastic reference material: a GGX dielectric coating over a Lambertian base, as
documented for Mitsuba 3's ``roughplastic`` BSDF (so any scene can be checked against an independent
renderer, ``benchmarks/plastic_vs_mitsuba.py``).

    f cos = F(wo.h) D(h) G1(wi) G1(wo) / (4 cos_o)                                  (coating)
          + rho / (1 - F_dr) * t(cos_i) t(cos_o) / eta^2 * cos_i / pi                 (base)

- D: GGX with alpha; G1: the separable Smith shadowing of GGX; F: exact unpolarised dielectric
  Fresnel for the index ratio eta = n_coat / n_outside (1.49 by default, Mitsuba's polypropylene);
- t(mu): the light the rough coating transmits into the base, the transmission albedo of the GGX
  interface with the refracted direction masked too (Mitsuba 3's ``eval_transmittance``), tabulated
  per (alpha, eta) by quadrature; it is below 1 - E_spec(mu), the masking loss growing with alpha and
  at grazing angles;
- F_dr = 2 int_0^1 E_spec(mu, 1/eta) mu dmu: the rough coating's reflectance for diffuse light from
  inside (total internal reflection included), so the base's repeated internal bounces sum to
  rho / (1 - F_dr).
"""
from __future__ import annotations

import functools

import numpy as np

from tissuerender.renderer.brdf import angle_cosines, ggx_D


def fresnel(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Exact unpolarised Fresnel reflectance for a ray at cosine cos_i hitting an interface of relative
    index eta (transmitted-side / incident-side; eta < 1 allows total internal reflection)."""
    c = np.clip(np.abs(cos_i), 0.0, 1.0)
    sin_t2 = (1.0 - c * c) / (eta * eta)
    tir = sin_t2 >= 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin_t2, 0.0))
    rs = (c - eta * cos_t) / np.maximum(c + eta * cos_t, 1e-300)
    rp = (eta * c - cos_t) / np.maximum(eta * c + cos_t, 1e-300)
    return np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def smith_G1(cos: np.ndarray, alpha) -> np.ndarray:
    """Smith's GGX masking G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta))."""
    c = np.clip(cos, 1e-12, 1.0)
    tan2 = (1.0 - c * c) / (c * c)
    return 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))


def _coating(n_l, n_v, n_h, v_h, alpha, eta):
    return fresnel(v_h, eta) * ggx_D(n_h, alpha) * smith_G1(n_l, alpha) * smith_G1(n_v, alpha) / (4.0 * np.maximum(n_v, 1e-12))


TABLE_SIZE = 64  # cosines 0 ... 1, evenly spaced (Mitsuba's grid for the same tables)


def _table_cosines():
    return np.maximum(np.arange(TABLE_SIZE) / (TABLE_SIZE - 1.0), 1e-6)


def visible_normals(wi: np.ndarray, alpha: float, n_samples: int) -> np.ndarray:
    """n_samples^2 GGX microfacet normals drawn from the distribution of normals visible from ``wi``,
    D_wi(m) = G1(wi) max(0, wi.m) D(m) / cos(theta_i), on a stratified grid (Heitz 2018: stretch the
    view direction, sample the projected hemisphere, unstretch). Estimators over these normals stay
    bounded; drawing from D(m)(n.m) instead weighs grazing facets by (wi.m)/(n.m), a heavy tail that a
    65k-point grid under-samples (it read the transmission 0.5-0.9 % low)."""
    vh = np.array([alpha * wi[0], alpha * wi[1], wi[2]])
    vh /= np.linalg.norm(vh)
    lensq = vh[0] * vh[0] + vh[1] * vh[1]
    t1 = np.array([-vh[1], vh[0], 0.0]) / np.sqrt(lensq) if lensq > 0.0 else np.array([1.0, 0.0, 0.0])
    t2 = np.cross(vh, t1)
    g = (np.arange(n_samples) + 0.5) / n_samples
    u1, u2 = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + vh[2])
    p2 = (1.0 - s) * np.sqrt(1.0 - p1 * p1) + s * p2
    nh = p1[:, None] * t1 + p2[:, None] * t2 + np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))[:, None] * vh
    m = np.stack([alpha * nh[:, 0], alpha * nh[:, 1], np.maximum(nh[:, 2], 0.0)], axis=1)
    return m / np.linalg.norm(m, axis=1, keepdims=True)


def smith_G1_oriented(v: np.ndarray, m: np.ndarray, alpha: float) -> np.ndarray:
    """Smith GGX masking of direction ``v`` (either side of the surface) by microfacet ``m``: zero when
    v sees the back of the facet, ``(v.m) v_z <= 0``."""
    vz2 = np.maximum(v[:, 2] * v[:, 2], 1e-300)
    tan2 = np.maximum(1.0 - vz2, 0.0) / vz2
    g = 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))
    return np.where(np.einsum("ij,ij->i", v, m) * v[:, 2] > 0.0, g, 0.0)


@functools.lru_cache(maxsize=32)
def _coating_albedo(alpha: float, eta: float, n_samples: int = 256):
    """(mu grid, E_spec(mu)): the rough coating's directional albedo, E = E_vis[F(wi.m) G1(wo)] over the
    visible normals with wo the mirror direction (eta < 1 includes total internal reflection)."""
    mus = _table_cosines()
    albedo = np.empty(TABLE_SIZE)
    for k, mu in enumerate(mus):
        wi = np.array([np.sqrt(1.0 - mu * mu), 0.0, mu])
        m = visible_normals(wi, alpha, n_samples)
        c = m @ wi
        wo = 2.0 * c[:, None] * m - wi
        est = fresnel(c, eta) * smith_G1_oriented(wo, m, alpha)
        albedo[k] = np.mean(np.where((wo[:, 2] > 0.0) & (c > 0.0), est, 0.0))
    return mus, np.clip(albedo, 0.0, 1.0)


@functools.lru_cache(maxsize=32)
def _coating_transmittance(alpha: float, eta: float, n_samples: int = 256):
    """(mu grid, T(mu)): the light a rough dielectric interface transmits into the layer for light
    arriving at cosine mu, T = int (1 - F(wi.m)) G1(wi) G1(wt) D(m) (wi.m) / mu dm = E_vis[(1 - F) G1(wt)]
    with wt the direction refracted through the facet m (as Mitsuba 3's ``eval_transmittance``). The
    masking of the refracted direction makes it smaller than 1 - E_spec(mu): light the coating neither
    reflects nor transmits is the energy the single-scattering microfacet model loses."""
    mus = _table_cosines()
    out = np.empty(TABLE_SIZE)
    for k, mu in enumerate(mus):
        wi = np.array([np.sqrt(1.0 - mu * mu), 0.0, mu])
        m = visible_normals(wi, alpha, n_samples)
        c = m @ wi
        sin_t2 = (1.0 - c * c) / (eta * eta)
        cos_t = np.sqrt(np.maximum(1.0 - sin_t2, 0.0))
        wt = -wi[None, :] / eta + (c / eta - cos_t)[:, None] * m
        est = (1.0 - fresnel(c, eta)) * smith_G1_oriented(wt, m, alpha)
        out[k] = np.mean(np.where((c > 0.0) & (sin_t2 < 1.0) & (wt[:, 2] < 0.0), est, 0.0))
    return mus, np.clip(out, 0.0, 1.0)


def transmittance(mu: np.ndarray, alpha: float, eta: float) -> np.ndarray:
    """t(mu): the coating's transmission into the base (``_coating_transmittance``), linearly
    interpolated in the table."""
    mus, t = _coating_transmittance(float(alpha), float(eta))
    return np.interp(np.clip(mu, 0.0, 1.0), mus, t)


def smooth_internal_reflectance(eta: float, n: int = 4096) -> float:
    """2 int_0^1 F(mu, 1/eta) mu dmu for a smooth interface (midpoint rule), for comparison."""
    mu = (np.arange(n) + 0.5) / n
    return float(2.0 * np.mean(fresnel(mu, 1.0 / eta) * mu))


@functools.lru_cache(maxsize=32)
def internal_diffuse_reflectance(eta: float, alpha: float) -> float:
    """F_dr: the rough coating's reflectance for diffuse light from inside, 2 <E_spec(mu, 1/eta) mu> over
    the table's cosines (as Mitsuba computes it; the rough interface reflects less than a smooth one)."""
    mus, albedo = _coating_albedo(float(alpha), 1.0 / float(eta))
    return float(2.0 * np.mean(albedo * mus))


def roughplastic_cos(n, wo, wi, albedo, alpha: float, eta: float):
    """f(wi, wo) (n . wi) for k points of one rough-plastic material (albedo (k, 3))."""
    alpha = max(float(alpha), 1e-3)
    n_l, n_v, n_h, v_h = angle_cosines(n, wo, wi)
    spec = np.where((n_l > 0) & (n_v > 0), _coating(n_l, n_v, n_h, v_h, alpha, eta), 0.0)
    t = transmittance(n_l, alpha, eta) * transmittance(n_v, alpha, eta)
    base = albedo / (1.0 - internal_diffuse_reflectance(eta, alpha)) * (t * n_l / (np.pi * eta * eta))[:, None]
    return spec[:, None] + base
