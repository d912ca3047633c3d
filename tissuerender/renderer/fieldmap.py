"""Surfaces coloured by a per-vertex field through a colormap (the validation cases' displacement maps).

A render object may carry ``vertex_albedo`` (n, 3): a linear-RGB diffuse albedo per vertex, interpolated over the
triangle like the UVs; it replaces the material's albedo (and texture) at that object's shading points, and the
material's specular lobe stays. :func:`colormap_albedo` turns field values into such albedos: the colormap's
display (sRGB) colour converted to linear reflectance (IEC 61966-2-1), so that a white-balanced, unit-exposure
render of a surface facing the light shows the colormap's own colours.
"""
from __future__ import annotations

import numpy as np


def srgb_to_linear(c):
    """IEC 61966-2-1 decoding: display value in [0, 1] -> linear value."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def colormap_albedo(values, low: float, high: float, colormap: str = "viridis") -> np.ndarray:
    """Linear-RGB albedo (n, 3) of ``values`` (n,) mapped linearly from ``[low, high]`` onto ``colormap``'s
    ends (clamped outside); ``low < high``."""
    import matplotlib  # only scenes with a field colour map need it

    if not high > low:
        raise ValueError(f"colour map range must have low < high, found [{low}, {high}]")
    u = np.clip((np.asarray(values, dtype=np.float64) - low) / (high - low), 0.0, 1.0)
    return srgb_to_linear(matplotlib.colormaps[colormap](u)[:, :3])


def colormap_parameter(albedo, colormap: str = "viridis", samples: int = 1024) -> np.ndarray:
    """The inverse of :func:`colormap_albedo` for ``[0, 1]``: each albedo's nearest colour among ``samples``
    points of the colormap, as its position u in [0, 1] (to the colormap's own lookup-table step: matplotlib's
    listed colormaps, viridis among them, hold 256 colours, so 1/255)."""
    u = np.linspace(0.0, 1.0, samples)
    table = colormap_albedo(u, 0.0, 1.0, colormap)
    d = ((np.asarray(albedo, float)[:, None, :] - table[None]) ** 2).sum(axis=2)
    return u[np.argmin(d, axis=1)]


def apply_vertex_albedo(albedo, vertex_albedo, triangles, tri, bary) -> np.ndarray:
    """``albedo`` (k, 3) with the interpolated ``vertex_albedo`` (n, 3; NaN rows: objects without one) at the
    shading points that have one (``tri`` (k,) their triangles, ``bary`` (k, 3) their barycentrics)."""
    c = np.einsum("kc,kcd->kd", bary, vertex_albedo[triangles[tri]])
    has = np.isfinite(c).all(axis=1)
    out = albedo.copy()
    out[has] = c[has]
    return out
