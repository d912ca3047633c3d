"""The thickness map of the subsurface term: the distance T through the tissue along -n (Qian §6.3.1:
"casting rays in the opposite direction of the surface normal"), recomputed every frame from the
deformed surface; it drives ``C exp(-sigma T)`` (Qian eq. 6.8).
"""
from __future__ import annotations

import numpy as np

from tissuerender.renderer.raster import interpolate_vertex_scalar


def thickness_reach(optics, bsdfs) -> float:
    """How far the thickness rays need to go: exp(-sigma T) < 1e-4 beyond T = ln(1e4) / sigma, so the rays
    stop there (thickness inf), which prunes most of the traversal through a large organ and changes no
    visible value. 0 when no material scatters below its surface."""
    sigmas = [min(min(o.subsurface_attenuation()[0]), min(o.subsurface_attenuation()[1]))
              for o, bsdf in zip(optics, bsdfs) if o.k_sss > 0.0 and bsdf.subsurface]
    return np.log(1e4) / max(min(sigmas), 1e-9) if sigmas else 0.0


def thickness_map(rays, surface, raster, points, reach: float, per_vertex: bool, scale: float) -> np.ndarray:
    """T (k,) at every shading point [m] (inf where the inward ray leaves nothing within ``reach``).

    ``per_vertex``: one ray per render-surface vertex along its inward normal, interpolated over each
    triangle with the raster's barycentrics (a thickness map on the surface; only the vertices of
    triangles in view, since the interpolation reads no other); otherwise one ray per shading point.
    ``scale`` is the scene's extent [m]."""
    if reach <= 0.0:
        return np.full(points.position.shape[0], np.inf)  # no material scatters below its surface
    # inward rays start just below the surface (a small offset: a self-hit of the front face is at t ~ 0,
    # while a thin layer's back face may be closer than the shadow-ray offset)
    inward = 1e-6 * max(scale, 1e-9)
    if not per_vertex:
        return rays.closest_hit(points.position - inward * points.normal, -points.normal, reach) + inward
    P, N, T = surface.points, surface.normals, surface.triangles
    seen = np.zeros(T.shape[0], bool)
    seen[points.tri] = True
    used = np.zeros(P.shape[0], bool)
    used[T[seen]] = True
    idx = np.flatnonzero(used)
    nv = N[idx] / np.maximum(np.linalg.norm(N[idx], axis=1, keepdims=True), 1e-12)
    at_vertex = np.full(P.shape[0], np.nan)
    at_vertex[idx] = rays.closest_hit(P[idx] - inward * nv, -nv, reach) + inward
    return interpolate_vertex_scalar(at_vertex, T, raster.tri_id, raster.bary, points.rows, points.cols)
