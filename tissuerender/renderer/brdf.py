"""Surface reflection: Cook–Torrance GGX specular plus a diffuse lobe split into Lambert and the
thickness-based subsurface term (Qian §6.3, eqs. 6.1–6.6; Walter et al. 2007 for GGX D, Heitz 2014
for the height-correlated Smith G, Schlick 1994 for F).

Energy split (Qian eq. 6.4 asks for k_d + k_s <= 1): the diffuse part is weighted by the Fresnel
transmission into and out of the surface in the reciprocal form of Ashikhmin & Shirley (2000),
``28/23 (1 - F0) [1 - (1 - n.l/2)^5] [1 - (1 - n.v/2)^5]``, so that diffuse plus specular never
reflect more than arrives, even at grazing angles where the specular lobe takes almost everything
(tested by a white-furnace test). Within the diffuse part ``k_sss`` moves weight from Lambert
``albedo / pi`` to ``C exp(-sigma T)`` (Qian eqs. 6.5 and 6.8) with ``C = sss_colour / pi``.
"""
from __future__ import annotations

import numpy as np


def ggx_D(n_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    a2 = alpha * alpha
    return a2 / (np.pi * (n_h * n_h * (a2 - 1.0) + 1.0) ** 2)


def smith_visibility(n_v: np.ndarray, n_l: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Height-correlated Smith G divided by ``4 (n.l)(n.v)`` (Heitz 2014, eq. 99)."""
    a2 = alpha * alpha
    lam_v = n_l * np.sqrt(n_v * n_v * (1.0 - a2) + a2)
    lam_l = n_v * np.sqrt(n_l * n_l * (1.0 - a2) + a2)
    return 0.5 / np.maximum(lam_v + lam_l, 1e-12)  # finite as n.v -> 0 (then lam_l -> 0 too)


def schlick_F(v_h: np.ndarray, f0: np.ndarray) -> np.ndarray:
    return f0 + (1.0 - f0) * (1.0 - v_h) ** 5


def angle_cosines(n, wo, wi):
    """(n.wi, n.wo, n.h, wo.h) clamped to [0, 1], h the half-vector, for (k, 3) unit vectors."""
    h = wo + wi
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    return (np.clip(np.einsum("ij,ij->i", n, wi), 0.0, 1.0), np.clip(np.einsum("ij,ij->i", n, wo), 0.0, 1.0),
            np.clip(np.einsum("ij,ij->i", n, h), 0.0, 1.0), np.clip(np.einsum("ij,ij->i", wo, h), 0.0, 1.0))


def reflectance_cos(n, wo, wi, albedo, alpha, f0, sss=None):
    """BRDF times cosine, ``f(wi, wo) (n . wi)``, for k shading points.

    n, wo, wi: (k, 3) unit vectors; albedo (k, 3); alpha, f0: (k,); ``sss`` (k, 3) is the
    subsurface term ``k_sss (C exp(-sigma T) - albedo / pi)`` already folded into a diffuse
    correction (None when SSS is off). Roughness is clamped to alpha >= 1e-3 (a perfect mirror has
    no finite BRDF value).
    """
    alpha = np.maximum(alpha, 1e-3)
    n_l, n_v, n_h, v_h = angle_cosines(n, wo, wi)
    F = schlick_F(v_h, f0)
    spec = ggx_D(n_h, alpha) * smith_visibility(n_v, n_l, alpha) * F
    transmission = (28.0 / 23.0) * (1.0 - f0) * (1.0 - (1.0 - 0.5 * n_l) ** 5) * (1.0 - (1.0 - 0.5 * n_v) ** 5)
    diffuse = albedo / np.pi
    if sss is not None:
        diffuse = diffuse + sss
    return (diffuse * transmission[:, None] + spec[:, None]) * n_l[:, None]


def refracted_cos(mu: np.ndarray, ior: np.ndarray) -> np.ndarray:
    """Cosine inside a layer of index ``ior`` of a ray arriving from air at cosine ``mu`` (Snell)."""
    return np.sqrt(np.maximum(1.0 - (1.0 - mu * mu) / (ior * ior), 0.0))


def dielectric_F(cos_i: np.ndarray, ior: np.ndarray) -> np.ndarray:
    """Exact unpolarised Fresnel reflectance from air into a dielectric of index ``ior`` (>= 1);
    zero for ior = 1, where Schlick's approximation is not."""
    c = np.clip(cos_i, 0.0, 1.0)
    g = np.sqrt(np.maximum(ior * ior - 1.0 + c * c, 0.0))
    a = (g - c) / np.maximum(g + c, 1e-12)
    b = (c * (g + c) - 1.0) / np.maximum(c * (g - c) + 1.0, 1e-12)
    return np.clip(0.5 * a * a * (1.0 + b * b), 0.0, 1.0)


def layered_reflectance_cos(n, wo, wi, base_f_cos, coat_alpha, coat_ior, coat_thickness, coat_sigma,
                            granular_weight, granular_alpha):
    """The mucosa stack (Qian §6.2.3) times cosine, for k shading points.

    ``base_f_cos`` (k, 3) is the base layers' ``f cos`` (diffuse connective/submucosa colour with the
    tissue's specular and subsurface terms, :func:`reflectance_cos`). On top of it:

        f cos = spec_coat + t(mu_i) t(mu_o) A [ w_g spec_gran + (1 - w_g) base_f_cos ]

    with the coat's GGX lobe ``spec_coat`` (exact dielectric Fresnel for ``coat_ior``), its directional Fresnel
    transmission ``t(mu) = 1 - F(mu)`` into and out of the stack, the coat's absorption along the
    refracted paths ``A = exp(-sigma d (1/mu_i' + 1/mu_o'))``, and the granular layer's GGX lobe (no
    Fresnel factor: ``w_g`` is its reflectance) taking ``w_g`` of the light that reaches it. Every term
    is bounded by the light the layer above lets through, so the stack conserves energy.
    """
    coat_alpha = np.maximum(coat_alpha, 1e-3)
    granular_alpha = np.maximum(granular_alpha, 1e-3)
    n_l, n_v, n_h, v_h = angle_cosines(n, wo, wi)
    spec_coat = ggx_D(n_h, coat_alpha) * smith_visibility(n_v, n_l, coat_alpha) * dielectric_F(v_h, coat_ior) * n_l
    spec_gran = ggx_D(n_h, granular_alpha) * smith_visibility(n_v, n_l, granular_alpha) * n_l
    t_in = 1.0 - dielectric_F(n_l, coat_ior)
    t_out = 1.0 - dielectric_F(n_v, coat_ior)
    path = 1.0 / np.maximum(refracted_cos(n_l, coat_ior), 1e-3) + 1.0 / np.maximum(refracted_cos(n_v, coat_ior), 1e-3)
    absorb = np.exp(-coat_sigma * (coat_thickness * path)[:, None])
    inner = granular_weight[:, None] * spec_gran[:, None] + (1.0 - granular_weight)[:, None] * base_f_cos
    return spec_coat[:, None] + (t_in * t_out)[:, None] * absorb * inner
