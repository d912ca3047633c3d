"""Layered wet tissue: a dielectric clear coat (mucus / serous fluid) and a granular specular layer over
the tissue's own Cook–Torrance surface and its diffuse and subsurface light (Qian §6.2.3, Figs. 6.8–6.9);
every tissue preset has one (``materials.optics.TissueLayers``).

======================  ================  ======  =========  ===============================================
name                    default           unit    range      equation
======================  ================  ======  =========  ===============================================
``coat_roughness``      0.06              --      [1e-3, 1]  GGX ``alpha_c`` of the coat lobe (Walter 2007)
``coat_ior``            1.34              --      [1, 3]     exact dielectric Fresnel F_c of the coat lobe
``coat_thickness``      150e-6            m       >= 0       absorption path ``d (1/mu_i' + 1/mu_o')``
``coat_absorption``     (5, 8, 15)        1/m     >= 0       ``A = exp(-sigma_c d (1/mu_i' + 1/mu_o'))``
``granular_weight``     0.04              --      [0, 1]     ``w_g``: the granular lobe's share under the coat
``granular_roughness``  0.35              --      [1e-3, 1]  GGX ``alpha_g`` of the granular lobe (F = 1;
                                                             scaled by the texture's roughness map)
======================  ================  ======  =========  ===============================================

The tissue under the coat keeps its ``roughness`` (alpha), ``ior`` (Schlick F0) and subsurface values
(:mod:`.tissue`); its diffuse colour is the stack's ``base_albedo`` (or the bake). The model, with E the
directional albedos of :mod:`.albedo` (``E_c`` the coat lobe's, ``E_s`` the tissue lobe's for its F0,
``E_1`` the F = 1 granular lobe's) and ``E_avg`` their cosine-weighted averages::

    f cos = f_c cos + A [ T_s ((1 - w_g) f_s cos + w_g f_g cos) + (1 - w_g) f_d cos + w_g f_ms cos ]

    T_s  = min(c(mu_i), c(mu_o)),  c(mu) = 1 - E_c(mu)               (the coat over a specular lobe)
    f_d  = (albedo / pi + sss) X(mu_i) X(mu_o) / N_s,   X = c (1 - E_s),  N_s = 2 int X mu dmu
    f_ms = 1 / pi X_1(mu_i) X_1(mu_o) / N_1,   X_1 = c (1 - E_1),  N_1 = 2 int X_1 mu dmu
                                                                 (Kulla & Conty 2017 multiple scattering)

Derivation (white furnace: albedo 1, no absorption, no SSS, uniform unit radiance). The coat reflects
``E_c(mu_o)``, so energy conservation leaves ``1 - E_c(mu_o)`` for the layers under it: the base is
attenuated by (1 - F_coat), where for a rough coat F_coat is its directional albedo E_c (for a smooth
coat E_c(mu) = F(mu), the Fresnel reflectance). The tissue's lobe takes ``E_s(mu_o)`` of that; a diffuse
lobe ``X(mu_i) X(mu_o) / N`` returns ``X(mu_o) int X(mu_i) mu_i / pi dw_i / N = X(mu_o)``, exactly what is
left, ``(1 - E_c(mu_o)) (1 - E_s(mu_o))``; a narrow specular lobe sends light back near ``mu_i = mu_o``,
where T_s = c(mu_o), so it returns ``c(mu_o) E_s(mu_o)`` (rough lobes in between: the furnace test bounds
the difference, < 1 %). The granular lobe (weight w_g, F = 1) pairs with f_ms the same way. In total
``E_c + c [E_s + (1 - E_s)] = 1``: energy preserving, reciprocal (every factor is symmetric in mu_i, mu_o),
and absorption A <= 1 and albedo <= 1 only take energy away. The normalisations N (``albedo.coat_norms``)
are integrals of the product, not products of averages: both albedos rise towards grazing.
"""
from __future__ import annotations

import numpy as np

from materials.optics import TissueLayers
from tissuerender.renderer.bsdf.albedo import (coat_norms, coat_table, lookup_alpha, lookup_alpha_mu, lookup_mu,
                                               schlick_tables)
from tissuerender.renderer.bsdf.microfacet import (angle_cosines, dielectric_F, ggx_D, refracted_cos, schlick_F,
                                                   smith_visibility)
from tissuerender.renderer.shade_kernel import KIND_LAYERED


def tissue_albedo(E, alpha, f0, mu):
    """E_s(mu) of the tissue's Cook–Torrance lobe (Schlick F0 = ``f0``) per point, from the split tables ``E``."""
    return f0 * lookup_alpha_mu(E[0], alpha, mu) + lookup_alpha_mu(E[1], alpha, mu)


def layered_reflectance_cos(n, wo, wi, albedo, alpha, f0, sss, coat_alpha, coat_ior, coat_thickness, coat_sigma,
                            granular_weight, granular_alpha):
    """The layered stack times cosine, ``f(wi, wo) (n.wi)`` (k, 3), for k points of one material.

    Per point: ``albedo`` (k, 3), tissue ``alpha`` and ``f0`` (k,), the subsurface correction ``sss``
    (k, 3) or None, ``coat_sigma`` (k, 3), ``granular_alpha`` and ``granular_weight`` (k,); the coat's
    ``coat_alpha``, ``coat_ior`` and ``coat_thickness`` are the material's scalars (its albedo tables).
    """
    E_c, _ = coat_table(float(coat_alpha), float(coat_ior))
    norms = coat_norms(float(coat_alpha), float(coat_ior))
    E, _ = schlick_tables()
    a = np.maximum(alpha, 1e-3)
    ga = np.maximum(granular_alpha, 1e-3)
    ca = max(float(coat_alpha), 1e-3)
    n_l, n_v, n_h, v_h = angle_cosines(n, wo, wi)
    f_c = ggx_D(n_h, ca) * smith_visibility(n_v, n_l, ca) * dielectric_F(v_h, coat_ior) * n_l
    c_i, c_o = 1.0 - lookup_mu(E_c, n_l), 1.0 - lookup_mu(E_c, n_v)
    T_s = np.minimum(c_i, c_o)
    path = 1.0 / np.maximum(refracted_cos(n_l, coat_ior), 1e-3) + 1.0 / np.maximum(refracted_cos(n_v, coat_ior), 1e-3)
    A = np.exp(-coat_sigma * (coat_thickness * path)[:, None])
    f_s = ggx_D(n_h, a) * smith_visibility(n_v, n_l, a) * schlick_F(v_h, f0) * n_l
    X_o = c_o * (1.0 - tissue_albedo(E, a, f0, n_v))
    N_s = lookup_alpha(norms[0], a) - f0 * lookup_alpha(norms[1], a)
    diffuse = albedo / np.pi if sss is None else albedo / np.pi + sss
    f_d = diffuse * (c_i * (1.0 - tissue_albedo(E, a, f0, n_l)) * (X_o / N_s) * n_l)[:, None]
    f_g = ggx_D(n_h, ga) * smith_visibility(n_v, n_l, ga) * n_l
    X1_o = c_o * (1.0 - tissue_albedo(E, ga, 1.0, n_v))
    N_1 = lookup_alpha(norms[2], ga)
    f_ms = c_i * (1.0 - tissue_albedo(E, ga, 1.0, n_l)) * (X1_o / np.maximum(np.pi * N_1, 1e-12)) * n_l
    wg = granular_weight
    spec = T_s * ((1.0 - wg) * f_s + wg * f_g)
    return f_c[:, None] + A * (spec[:, None] + (1.0 - wg)[:, None] * f_d + (wg * f_ms)[:, None])


def layer_arrays(optics, mat, rough_factor=None):
    """Per-shading-point parameters of the mucosa layer stack, or None when no material has layers.
    ``rough_factor`` (the texture's roughness map, None where untextured) scales the granular alpha."""
    if not any(o.layers is not None for o in optics):
        return None
    neutral = TissueLayers(coat_ior=1.0, coat_thickness=0.0, granular_weight=0.0)
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
    """The layered (wet) tissue BSDF of one material (see the module's parameter table)."""

    name = "mucosa"
    kind = KIND_LAYERED  # the shading kernel's code
    subsurface = True  # the base's thickness term applies

    def __init__(self, optics):
        self.optics = optics

    def eval_cos(self, points, idx, wi):
        """``f cos`` (k, 3) at the G-buffer points ``idx`` towards the unit directions ``wi``."""
        sss = None if points.sss is None else points.sss[idx]
        n, wo, lay = points.normal[idx], points.wo[idx], points.layers
        st = self.optics.layers
        return layered_reflectance_cos(n, wo, wi, points.albedo[idx], points.alpha[idx], points.f0[idx], sss,
                                       st.coat_roughness, st.coat_ior, st.coat_thickness, lay["coat_sigma"][idx],
                                       lay["granular_weight"][idx], lay["granular_alpha"][idx])

    def kernel_row(self, mid, tables):
        """The stack's row of the kernel's ``coat`` and ``coat_sigma`` tables, of the coat albedo table
        ``coat_E`` and of the diffuse normalisations ``coat_norm`` (``albedo.coat_norms``)."""
        st = self.optics.layers
        tables["coat"][mid] = (st.coat_roughness, st.coat_ior, st.coat_thickness, st.granular_weight,
                               st.granular_roughness)
        tables["coat_sigma"][mid] = st.coat_absorption
        tables["coat_E"][mid] = coat_table(st.coat_roughness, st.coat_ior)[0]
        tables["coat_norm"][mid] = coat_norms(st.coat_roughness, st.coat_ior)
