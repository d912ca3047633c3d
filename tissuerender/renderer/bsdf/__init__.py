"""BSDFs by name: one module per BSDF, the shared microfacet pieces in :mod:`.microfacet`.

``make_bsdf(name, optics)`` builds the BSDF ``name`` for one material (``materials.optics.OpticalMaterial``);
``bsdf_for(optics)`` picks the name the material asks for. Every BSDF has

- ``name``, and ``kind``: the integer code of the numba shading pass (``shade_kernel.KIND_*``);
- ``subsurface``: whether the thickness term ``C exp(-sigma T)`` applies;
- ``eval_cos(points, idx, wi)``: ``f(wi, wo) (n.wi)`` (k, 3) at G-buffer points ``idx`` (the NumPy
  estimator); ``points`` has ``normal``, ``wo``, ``albedo``, ``alpha``, ``f0``, ``sss`` and ``layers``;
- ``kernel_row(mid, tables)``: its parameters in the per-material tables of the numba pass.
"""
from __future__ import annotations

import numpy as np

from tissuerender.renderer.bsdf.albedo import ALPHA_SIZE, MU_SIZE, schlick_tables
from tissuerender.renderer.bsdf.mucosa import LayeredMucosa
from tissuerender.renderer.bsdf.plastic import RoughPlastic
from tissuerender.renderer.bsdf.tissue import Tissue
from tissuerender.renderer.shade_kernel import KIND_LAYERED

BSDFS = {cls.name: cls for cls in (Tissue, LayeredMucosa, RoughPlastic)}


def bsdf_name(optics) -> str:
    """The BSDF a material asks for: ``optics.bsdf`` ("tissue" or "roughplastic"), where a tissue with a
    layer stack (``optics.layers``) is the layered mucosa."""
    if optics.bsdf == "roughplastic":
        return "roughplastic"
    if optics.bsdf == "tissue":
        return "mucosa" if optics.layers is not None else "tissue"
    raise ValueError(f"bsdf must be 'tissue' or 'roughplastic', found {optics.bsdf!r}")


def make_bsdf(name: str, optics):
    """The BSDF ``name`` (one of :data:`BSDFS`) with the parameters of the material ``optics``."""
    try:
        cls = BSDFS[name]
    except KeyError:
        raise ValueError(f"unknown BSDF {name!r}; expected one of {', '.join(BSDFS)}") from None
    return cls(optics)


def bsdf_for(optics):
    """The BSDF of the material ``optics``."""
    return make_bsdf(bsdf_name(optics), optics)


_NO_SCHLICK = np.zeros((2, 2, 2))
_NO_SCHLICK.setflags(write=False)


def kernel_tables(bsdfs, optics):
    """Per-material parameters for the numba shading pass (``shade_kernel.shade_direct``), indexed by the
    G-buffer's material id."""
    k = max(len(optics), 1)
    tables = dict(kind=np.zeros(k, np.int64), coat=np.zeros((k, 5)), coat_sigma=np.zeros((k, 3)),
                  coat_E=np.zeros((k, MU_SIZE)), coat_norm=np.ones((k, 3, ALPHA_SIZE)), plastic=np.zeros((k, 3)), plastic_t=[np.ones(64)])
    for mid, bsdf in enumerate(bsdfs):
        tables["kind"][mid] = bsdf.kind
        bsdf.kernel_row(mid, tables)

    def column(attr, width=None):
        values = np.array([getattr(o, attr) for o in optics], float) if optics else np.zeros(0)
        if width:
            values = values.reshape(-1, width)
        out = np.zeros((k, width) if width else k)
        out[:len(optics)] = values
        return out

    tables["plastic_t"] = np.ascontiguousarray(np.stack(tables["plastic_t"]))
    # the tissue lobe's albedo tables, needed (and computed, once per process) only under a wet coat
    # (the placeholder is read-only like the cached table, so shade_direct has one numba signature: one compile)
    E = schlick_tables()[0] if any(b.kind == KIND_LAYERED for b in bsdfs) else _NO_SCHLICK
    # the thickness term per material: C, and the attenuations above and below the connective layer's depth
    # (optics.subsurface_attenuation; depth 0 and equal sigmas for a single-layer term)
    att = [o.subsurface_attenuation() for o in optics]
    sss = dict(sigma=np.zeros((k, 3)), sigma_deep=np.zeros((k, 3)), sss_depth=np.zeros(k), sss_colour=np.zeros((k, 3)))
    for mid, (o, (upper, deep, depth)) in enumerate(zip(optics, att)):
        sss["sigma"][mid], sss["sigma_deep"][mid], sss["sss_depth"][mid] = upper, deep, depth
        sss["sss_colour"][mid] = o.subsurface_colour
    return dict(tables, schlick_E=E, f0=column("f0"), k_sss=column("k_sss"), **sss)
