"""Rough plastic, the reference material: a GGX dielectric coating over a Lambertian base, as documented
for Mitsuba 3's ``roughplastic`` BSDF (so any scene can be checked against an independent renderer,
``benchmarks/plastic_vs_mitsuba.py``).

=============  ==================  ==========  =========  ===================================================
name           default             unit        range      equation
=============  ==================  ==========  =========  ===================================================
``albedo``     (0.55, 0.55, 0.58)  linear RGB  [0, 1]     ``rho`` of the Lambertian base
``roughness``  0.25                --          [1e-3, 1]  GGX ``alpha`` of D (Walter 2007) and separable
                                                          Smith G1 of the coating
``ior``        1.49                --          [1, 3]     ``eta`` of the exact dielectric Fresnel F, of
                                                          ``t(mu)`` and of ``F_dr``
=============  ==================  ==========  =========  ===================================================

Defaults are the ``plastic`` preset's (``materials.optics``; Mitsuba's polypropylene); the subsurface
fields of the material are not used. The model::

    f cos = F(wo.h) D(h) G1(wi) G1(wo) / (4 cos_o)                                  (coating)
          + rho / (1 - F_dr) * t(cos_i) t(cos_o) / eta^2 * cos_i / pi                 (base)

- D: GGX with alpha; G1: the separable Smith shadowing of GGX; F: exact unpolarised dielectric
  Fresnel for the index ratio eta = n_coat / n_outside;
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

from tissuerender.renderer.bsdf.microfacet import (angle_cosines, fresnel, ggx_D, smith_G1, smith_G1_oriented,
                                                   visible_normals)
from tissuerender.renderer.shade_kernel import KIND_PLASTIC


def _coating(n_l, n_v, n_h, v_h, alpha, eta):
    return fresnel(v_h, eta) * ggx_D(n_h, alpha) * smith_G1(n_l, alpha) * smith_G1(n_v, alpha) / (4.0 * np.maximum(n_v, 1e-12))


TABLE_SIZE = 64  # cosines 0 ... 1, evenly spaced (Mitsuba's grid for the same tables)


def _table_cosines():
    return np.maximum(np.arange(TABLE_SIZE) / (TABLE_SIZE - 1.0), 1e-6)


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


class RoughPlastic:
    """The rough-plastic BSDF of one material (see the module's parameter table)."""

    name = "roughplastic"
    kind = KIND_PLASTIC  # the shading kernel's code
    subsurface = False  # no thickness term

    def __init__(self, optics):
        self.optics = optics

    def eval_cos(self, points, idx, wi):
        """``f cos`` (k, 3) at the G-buffer points ``idx`` towards the unit directions ``wi``."""
        return roughplastic_cos(points.normal[idx], points.wo[idx], wi, points.albedo[idx], self.optics.roughness,
                                self.optics.ior)

    def kernel_row(self, mid, tables):
        """The kernel's ``plastic`` row (eta, 1 / (1 - F_dr), row of its transmittance table) and the table."""
        a, eta = max(float(self.optics.roughness), 1e-3), float(self.optics.ior)
        tables["plastic"][mid] = (eta, 1.0 / (1.0 - internal_diffuse_reflectance(eta, a)), len(tables["plastic_t"]))
        tables["plastic_t"].append(_coating_transmittance(a, eta)[1])
