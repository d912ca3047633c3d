"""Layered mucosa: a wet dielectric clear coat and a granular specular layer over the tissue BSDF of the
connective tissue and submucosa (Qian §6.2.3, Figs. 6.8–6.9).

======================  ================  ======  =========  ===============================================
name                    default           unit    range      equation
======================  ================  ======  =========  ===============================================
``coat_roughness``      0.06              --      [1e-3, 1]  GGX ``alpha`` of the coat lobe (Walter 2007)
``coat_ior``            1.34              --      >= 1       exact dielectric Fresnel of the coat and its
                                                             transmission ``t(mu) = 1 - F(mu)``
``coat_thickness``      150e-6            m       >= 0       absorption path ``d (1/mu_i' + 1/mu_o')``
``coat_absorption``     (5, 8, 15)        1/m     >= 0       ``A = exp(-sigma d (1/mu_i' + 1/mu_o'))``
``granular_weight``     0.04              --      [0, 1]     ``w_g``: the granular lobe's share of the light
                                                             reaching it
``granular_roughness``  0.35              --      [1e-3, 1]  GGX ``alpha`` of the granular lobe (scaled by
                                                             the texture's roughness map)
======================  ================  ======  =========  ===============================================

Parameters are the fields of ``materials.optics.MucosaLayers`` (the preset's ``layers``); the base is
the tissue BSDF (:mod:`tissuerender.renderer.bsdf.tissue`) with the stack's ``base_albedo``::

    f cos = spec_coat + t(mu_i) t(mu_o) A [ w_g spec_gran + (1 - w_g) base_f_cos ]

Every term is bounded by the light the layer above lets through, so the stack conserves energy
(white-furnace test).
"""
from __future__ import annotations

import numpy as np

from materials.optics import MucosaLayers
from tissuerender.renderer.bsdf.microfacet import angle_cosines, dielectric_F, ggx_D, refracted_cos, smith_visibility
from tissuerender.renderer.bsdf.tissue import reflectance_cos
from tissuerender.renderer.shade_kernel import KIND_LAYERED


def layered_reflectance_cos(n, wo, wi, base_f_cos, coat_alpha, coat_ior, coat_thickness, coat_sigma,
                            granular_weight, granular_alpha):
    """The mucosa stack times cosine, for k shading points.

    ``base_f_cos`` (k, 3) is the base layers' ``f cos`` (diffuse connective/submucosa colour with the
    tissue's specular and subsurface terms, :func:`~tissuerender.renderer.bsdf.tissue.reflectance_cos`).
    On top of it the coat's GGX lobe ``spec_coat`` (exact dielectric Fresnel for ``coat_ior``), its
    directional Fresnel transmission into and out of the stack, the coat's absorption along the
    refracted paths, and the granular layer's GGX lobe (no Fresnel factor: ``w_g`` is its reflectance).
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


def layer_arrays(optics, mat, rough_factor=None):
    """Per-shading-point parameters of the mucosa layer stack, or None when no material has layers.
    ``rough_factor`` (the texture's roughness map, None where untextured) scales the granular alpha."""
    if not any(o.layers is not None for o in optics):
        return None
    neutral = MucosaLayers(coat_ior=1.0, coat_thickness=0.0, granular_weight=0.0)
    stacks = [o.layers if o.layers is not None else neutral for o in optics]
    layers = {
        "mask": np.array([o.layers is not None for o in optics])[mat],
        "coat_alpha": np.array([st.coat_roughness for st in stacks])[mat],
        "coat_ior": np.array([st.coat_ior for st in stacks])[mat],
        "coat_thickness": np.array([st.coat_thickness for st in stacks])[mat],
        "coat_sigma": np.array([st.coat_absorption for st in stacks], float).reshape(-1, 3)[mat],
        "granular_weight": np.array([st.granular_weight for st in stacks])[mat],
        "granular_alpha": np.array([st.granular_roughness for st in stacks])[mat],
    }
    if rough_factor is not None:
        layers["granular_alpha"] = layers["granular_alpha"] * rough_factor
    return layers


def layer_channels(optics, mat, layers, n, wo):
    """The G-buffer channels of a layered material in view: each point's connective and submucosa colours
    (k, 2, 3), and the weight of the wet (mucus) reflection, the coat's Fresnel reflectance at the viewing
    angle (0 off the mucosa)."""
    colours = np.array([[o.layers.connective_colour, o.layers.submucosa_colour] if o.layers is not None
                        else [[0.0] * 3] * 2 for o in optics], float)
    nv = np.clip(np.einsum("ij,ij->i", n, wo), 0.0, 1.0)
    return {"layer_albedo": colours[mat],
            "mucus_weight": np.where(layers["mask"], dielectric_F(nv, layers["coat_ior"]), 0.0)}


class LayeredMucosa:
    """The layered mucosa BSDF of one material (see the module's parameter table)."""

    name = "mucosa"
    kind = KIND_LAYERED  # the shading kernel's code
    subsurface = True  # the base's thickness term applies

    def __init__(self, optics):
        self.optics = optics

    def eval_cos(self, points, idx, wi):
        """``f cos`` (k, 3) at the G-buffer points ``idx`` towards the unit directions ``wi``."""
        sss = None if points.sss is None else points.sss[idx]
        n, wo, lay = points.normal[idx], points.wo[idx], points.layers
        base = reflectance_cos(n, wo, wi, points.albedo[idx], points.alpha[idx], points.f0[idx], sss)
        return layered_reflectance_cos(n, wo, wi, base, lay["coat_alpha"][idx], lay["coat_ior"][idx],
                                       lay["coat_thickness"][idx], lay["coat_sigma"][idx],
                                       lay["granular_weight"][idx], lay["granular_alpha"][idx])

    def kernel_row(self, mid, tables):
        """The stack's row of the kernel's ``coat`` and ``coat_sigma`` tables."""
        st = self.optics.layers
        tables["coat"][mid] = (st.coat_roughness, st.coat_ior, st.coat_thickness, st.granular_weight,
                               st.granular_roughness)
        tables["coat_sigma"][mid] = st.coat_absorption
