"""Direct light of the area light at every G-buffer point (Qian §6.3), with shadows.

Two estimators compute the same sum ``sum f(wi, wo) (n.wi) V cos(theta_l) / r^2 A / m``:

- the numba passes of :mod:`~tissuerender.renderer.shade_kernel` (the default): one shadow ray per sample
  written in one pass, answered in one batch by the ray backend, then the BSDFs looked up per material in
  small tables; they also carry the ratio estimator and penumbra re-shading;
- the vectorised NumPy estimator over the BSDFs' ``eval_cos``, used when the reflection cone is asked
  for (Qian 6.21, made unbiased: docs/design.md, "Qian 6.21: reflection cone") or ``settings.fused`` is off.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tissuerender.renderer.bsdf import kernel_tables
from tissuerender.renderer.light import light_sample, radical_inverse
from tissuerender.renderer.shade_kernel import cosine_integrals, light_rays, pixel_or, shade_direct, visibility_bits


@dataclass
class LightSamples:
    """The light in world space (``centre``, emitting unit normal ``ln``, half-axes ``eu``, ``ev``) and each
    point's sample set: count ``m``, Cranley–Patterson ``rotation`` (k, 2), ``stride`` and ``phase``
    (``light.sample_offsets``)."""

    centre: np.ndarray
    ln: np.ndarray
    eu: np.ndarray
    ev: np.ndarray
    m: np.ndarray
    rotation: np.ndarray
    stride: int
    phase: np.ndarray


def cone_angle(alpha: np.ndarray) -> np.ndarray:
    """Half-angle of the reflection cone from the GGX lobe width: the half-vector angle where D falls
    to a tenth of its peak, tan^2 theta_h = alpha^2 (sqrt(10) - 1), doubled for the reflected direction."""
    return np.minimum(2.0 * np.arctan(np.maximum(alpha, 1e-3) * np.sqrt(np.sqrt(10.0) - 1.0)), np.radians(80.0))


def cone_regions(pos, n, wo, alpha, centre, ln, eu, ev):
    """The rectangle R' of the light (in its local coordinates, edges at -1 and 1) covering the reflection
    cone's footprint: (lo_u, hi_u, lo_v, hi_v, valid). Splitting the light into R' and the rest and
    sampling each with its own weight (area / samples) keeps the estimate unbiased for any R'; a good
    R' only moves samples to where the glossy lobe is."""
    r = 2.0 * np.einsum("ij,ij->i", n, wo)[:, None] * n - wo
    denom = r @ ln
    t = np.einsum("ij,j->i", centre - pos, ln) / np.where(np.abs(denom) > 1e-12, denom, np.inf)
    hit = (denom < 0.0) & (t > 0.0) & np.isfinite(t)
    q = pos + np.where(hit, t, 0.0)[:, None] * r
    eu2, ev2 = float(eu @ eu), float(ev @ ev)
    uc, vc = (q - centre) @ eu / eu2, (q - centre) @ ev / ev2
    rho = np.where(hit, t, 0.0) * np.tan(cone_angle(alpha))
    lo_u, hi_u = np.maximum(-1.0, uc - rho / np.sqrt(eu2)), np.minimum(1.0, uc + rho / np.sqrt(eu2))
    lo_v, hi_v = np.maximum(-1.0, vc - rho / np.sqrt(ev2)), np.minimum(1.0, vc + rho / np.sqrt(ev2))
    valid = hit & (hi_u > lo_u) & (hi_v > lo_v)
    return lo_u, hi_u, lo_v, hi_v, valid


def penumbra_points(bits, pixel, shape):
    """Points to re-shade: every sample of a pixel whose first shadow rays disagree (bits 3 over the pixel's
    supersamples) or of one of its 8 neighbours (a penumbra the first rays happened to miss is often next
    to one they caught)."""
    mixed = np.zeros(shape[0] * shape[1], np.uint8)
    pixel_or(np.ascontiguousarray(pixel, np.int64), bits, mixed)
    grid = (mixed == 3).reshape(shape)
    near = grid.copy()
    near[1:] |= grid[:-1]
    near[:-1] |= grid[1:]
    wide = near.copy()
    wide[:, 1:] |= near[:, :-1]
    wide[:, :-1] |= near[:, 1:]
    return np.flatnonzero(wide.ravel()[pixel])


def trace_shadow_rays(rays, pos, n, m, rotation, stride, phase, ls: LightSamples, eps, offsets):
    """Occlusion (float32 rays, ``shade_kernel.light_rays``) of sample s of point i at ``offsets[i] + s``;
    ``offsets`` is filled with the exclusive prefix sum of ``m``."""
    np.cumsum(m[:-1], out=offsets[1:])
    total = int(offsets[-1] + m[-1])
    origins, dirs, tfar = (np.empty((total, 3), np.float32), np.empty((total, 3), np.float32),
                           np.empty(total, np.float32))
    light_rays(pos, n, m, rotation, int(stride), phase, ls.centre, ls.ln, ls.eu, ls.ev, float(eps), offsets, origins,
               dirs, tfar)
    return np.ascontiguousarray(rays.occluded_rays(origins, dirs, tfar), dtype=np.bool_)


def shade_fused(points, bsdfs, optics, ls: LightSamples, rays, eps, radiance, rec, ratio=False, penumbra_samples=0,
                pixel=None, shape=None):
    """Direct light of every point through the numba passes of ``shade_kernel``, added to ``radiance``;
    ``rays`` (the frame's ray scene) None means no shadows. ``penumbra_samples`` > 0 (with shadows): points
    of pixels (``pixel``: each point's index in the output image of ``shape``) whose shadow rays disagree,
    and of their neighbours, are shaded again with that many samples, which replace the first ones."""
    k = points.position.shape[0]
    if k == 0:
        return
    f64 = np.float64
    pos, n, wo, rotation = (np.ascontiguousarray(a, dtype=f64) for a in (points.position, points.normal, points.wo,
                                                                        ls.rotation))
    m, phase, mat = (np.ascontiguousarray(a, dtype=np.int64) for a in (ls.m, ls.phase, points.material))
    ls = LightSamples(*(np.asarray(c, f64) for c in (ls.centre, ls.ln, ls.eu, ls.ev)), m, rotation, ls.stride, phase)
    ray_offsets = np.zeros(k, np.int64)
    occluded = np.zeros(0, np.bool_)
    if rays is not None:
        with rec.run("shadow_rays"):
            occluded = trace_shadow_rays(rays, pos, n, m, rotation, ls.stride, phase, ls, eps, ray_offsets)
    t = kernel_tables(bsdfs, optics)
    unshadowed = np.zeros(k if ratio else 0)
    if ratio:
        cosine_integrals(pos, n, ls.centre, ls.ln, ls.eu, ls.ev, unshadowed)
    has_sss = points.thickness is not None
    albedo = np.ascontiguousarray(points.albedo, dtype=f64)
    alpha = np.ascontiguousarray(points.alpha, dtype=f64)
    thickness = np.ascontiguousarray(points.thickness, dtype=f64) if has_sss else np.zeros(1)
    rough_factor = (np.ascontiguousarray(points.rough_factor, dtype=f64) if points.rough_factor is not None
                    else np.ones(k))
    redo = np.zeros(0, np.int64)
    if rays is not None and penumbra_samples > 0:
        with rec.run("shadow_rays"):
            bits = np.empty(k, np.uint8)
            visibility_bits(pos, n, m, rotation, int(ls.stride), phase, ls.centre, ls.ln, ls.eu, ls.ev, float(eps),
                            ray_offsets, occluded, bits)
            redo = penumbra_points(bits, pixel, shape)

    def shade(sel, m_sel, offsets, occ, out):
        shade_direct(pos[sel], n[sel], wo[sel], albedo[sel], alpha[sel], mat[sel],
                     thickness[sel] if has_sss else thickness, has_sss, rough_factor[sel], m_sel, rotation[sel],
                     int(ls.stride), phase[sel], ls.centre, ls.ln, ls.eu, ls.ev, float(eps), rays is not None, offsets,
                     occ, t["kind"], t["f0"], t["k_sss"], t["sigma"], t["sigma_deep"], t["sss_depth"],
                     t["sss_colour"], t["coat"], t["coat_sigma"],
                     t["coat_E"], t["coat_norm"], t["schlick_E"], t["plastic"], t["plastic_t"], bool(ratio),
                     unshadowed[sel] if ratio else unshadowed, out)

    before = radiance[redo]  # (a copy) what the penumbra points held before their first estimate
    shade(slice(None), m, ray_offsets, occluded, radiance)
    if redo.size == 0:
        return
    # the penumbra points again, with their own sample sets of penumbra_samples (at least m) each
    m_redo = np.maximum(m[redo], int(penumbra_samples))
    offsets = np.zeros(redo.size, np.int64)
    with rec.run("shadow_rays"):
        occ = trace_shadow_rays(rays, pos[redo], n[redo], m_redo, rotation[redo], ls.stride, phase[redo], ls, eps,
                                offsets)
    out = before.copy()
    shade(redo, m_redo, offsets, occ, out)
    radiance[redo] = out


def shade_numpy(points, bsdfs, ls: LightSamples, cone, cone_samples, rays, eps, radiance, rec):
    """Direct light of every point with the NumPy estimator, added to ``radiance``; ``rays`` None means no
    shadows. ``cone`` (:func:`cone_regions`, or None): uniform samples landing in the reflection cone's
    rectangle R' are dropped and ``cone_samples`` stratified samples of R' taken instead."""
    pos, n, mat = points.position, points.normal, points.material
    centre, ln, eu, ev = ls.centre, ls.ln, ls.eu, ls.ev
    eu2, ev2 = float(eu @ eu), float(ev @ ev)

    def contribute(act, q, wi, weight):
        if rays is not None:
            with rec.run("shadow_rays"):
                weight = weight * ~rays.occluded(pos[act] + 2 * eps * n[act], q)
        f_cos = np.empty((act.size, 3))
        for mid, bsdf in enumerate(bsdfs):
            sel = np.flatnonzero(mat[act] == mid)
            if sel.size:
                f_cos[sel] = bsdf.eval_cos(points, act[sel], wi[sel])
        radiance[act] += f_cos * weight[:, None]

    m = ls.m
    for s in range(int(m.max()) if m.size else 0):
        act = np.flatnonzero(s < m)
        q, wi, weight = light_sample(s, m[act], ls.rotation[act], pos[act], centre, ln, eu, ev, ls.stride,
                                     ls.phase[act])
        if cone is not None:
            # uniform samples landing in R' are replaced by the cone samples below (stratification)
            u, v = (q - centre) @ eu / eu2, (q - centre) @ ev / ev2
            inside = (cone[4][act] & (u >= cone[0][act]) & (u < cone[1][act]) & (v >= cone[2][act])
                      & (v < cone[3][act]))
            weight = np.where(inside, 0.0, weight)
        contribute(act, q, wi, weight)
    if cone is None:
        return
    act = np.flatnonzero(cone[4])
    mc = int(cone_samples)
    lo_u, hi_u, lo_v, hi_v = (c[act] for c in cone[:4])
    area = (hi_u - lo_u) * (hi_v - lo_v) * np.sqrt(eu2 * ev2)  # of R' [m^2]
    for s in range(mc):
        u = lo_u + (hi_u - lo_u) * np.mod((s + 0.5) / mc + ls.rotation[act, 0], 1.0)
        v = lo_v + (hi_v - lo_v) * np.mod(radical_inverse(np.full(act.size, s)) + ls.rotation[act, 1], 1.0)
        q = centre + u[:, None] * eu + v[:, None] * ev
        wi = q - pos[act]
        d2 = np.maximum(np.einsum("ij,ij->i", wi, wi), 1e-12)
        wi /= np.sqrt(d2)[:, None]
        cos_l = np.clip(-(wi @ ln), 0.0, None)
        contribute(act, q, wi, cos_l / d2 * area / mc)
