"""Tissue: Cook–Torrance GGX specular plus a diffuse lobe split into Lambert and the thickness-based
subsurface term (Qian §6.3, eqs. 6.1–6.4 and 6.5–6.10).

==============  ====================  ==========  ==============  =============================================
name            default               unit        range           equation
==============  ====================  ==========  ==============  =============================================
``albedo``      preset                linear RGB  [0, 1]          Lambert ``albedo / pi`` (Qian 6.1–6.4)
``roughness``   preset                --          [1e-3, 1]       GGX ``alpha`` of D (Walter 2007) and G
                                                                  (height-correlated Smith, Heitz 2014)
``ior``         1.40                  --          [1, 3]          ``F0 = ((n - 1)/(n + 1))^2``, Schlick F
                                                                  (Schlick 1994)
``k_sss``       0.3                   --          [0, 1]          weight moved from Lambert to the subsurface
                                                                  term (Qian 6.5)
``sigma``       (400, 1500, 2500)     1/m         > 0             attenuation ``exp(-sigma T)`` over the
                                                                  thickness T (Qian 6.8)
``sss_colour``  (0.8, 0.25, 0.2)      linear RGB  [0, 1]          ``C = sss_colour / pi`` (Qian 6.8)
==============  ====================  ==========  ==============  =============================================

Parameters are the fields of ``materials.optics.OpticalMaterial`` (ranges: the scene schema's
``OpticsOverride``); ``roughness`` is clamped to 1e-3 (a perfect mirror has no finite BRDF value).

Energy split (Qian eq. 6.4 asks for k_d + k_s <= 1): the diffuse part is weighted by the Fresnel
transmission into and out of the surface in the reciprocal form of Ashikhmin & Shirley (2000),
``28/23 (1 - F0) [1 - (1 - n.l/2)^5] [1 - (1 - n.v/2)^5]``, so that diffuse plus specular never
reflect more than arrives, even at grazing angles where the specular lobe takes almost everything
(tested by a white-furnace test). Within the diffuse part ``k_sss`` moves weight from Lambert
``albedo / pi`` to ``C exp(-sigma T)`` (Qian eqs. 6.5 and 6.8).
"""
from __future__ import annotations

import numpy as np

from materials.optics import layered_transmittance

from tissuerender.renderer.bsdf.microfacet import angle_cosines, ggx_D, schlick_F, smith_visibility
from tissuerender.renderer.shade_kernel import KIND_TISSUE


def reflectance_cos(n, wo, wi, albedo, alpha, f0, sss=None):
    """BRDF times cosine, ``f(wi, wo) (n . wi)``, for k shading points.

    n, wo, wi: (k, 3) unit vectors; albedo (k, 3); alpha, f0: (k,); ``sss`` (k, 3) is the
    subsurface term ``k_sss (C exp(-sigma T) - albedo / pi)`` already folded into a diffuse
    correction (:func:`subsurface_term`; None when SSS is off).
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


def subsurface_term(optics, mat, thickness, albedo):
    """The diffuse correction ``k_sss (C exp(-sigma T) - albedo / pi)`` (k, 3) of every point (Qian eqs.
    6.5, 6.8) from the per-material ``optics`` indexed by ``mat``; an infinite thickness transmits nothing.
    Layered materials: C is the layers' ``subsurface_colour`` and ``exp(-sigma T)`` the two layers'
    ``layered_transmittance`` (``materials.optics``; the same value as ``exp(-sigma T)`` when no layer sets its own)."""
    k_sss = np.array([o.k_sss for o in optics], float)[mat]
    att = [o.subsurface_attenuation() for o in optics]
    upper = np.array([a[0] for a in att], float).reshape(-1, 3)[mat]
    deep = np.array([a[1] for a in att], float).reshape(-1, 3)[mat]
    depth = np.array([a[2] for a in att], float)[mat]
    colour = np.array([o.subsurface_colour for o in optics], float).reshape(-1, 3)[mat]
    transmit = layered_transmittance(upper, deep, depth, thickness)
    return k_sss[:, None] * (colour / np.pi * transmit - albedo / np.pi)


class Tissue:
    """The tissue BSDF of one material (see the module's parameter table)."""

    name = "tissue"
    kind = KIND_TISSUE  # the shading kernel's code
    subsurface = True  # the thickness term applies

    def __init__(self, optics):
        self.optics = optics

    def eval_cos(self, points, idx, wi):
        """``f cos`` (k, 3) at the G-buffer points ``idx`` towards the unit directions ``wi``."""
        sss = None if points.sss is None else points.sss[idx]
        return reflectance_cos(points.normal[idx], points.wo[idx], wi, points.albedo[idx], points.alpha[idx],
                               points.f0[idx], sss)

    def kernel_row(self, mid, tables):
        """Nothing beyond the per-material columns every BSDF fills (``f0``, ``k_sss``, ``sigma``, ...)."""
