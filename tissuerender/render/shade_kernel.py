"""Direct lighting of the G-buffer in one numba pass: for every shading point, its m light samples,
their shadow rays and the BRDF, with no per-sample arrays.

It computes exactly what the NumPy path in :mod:`tissuerender.render.frame` computes for the same
points (the same Hammersley points rotated per pixel, the same ``A / m`` weights, the same Cook–Torrance
terms of :func:`tissuerender.render.brdf.reflectance_cos` and the same mucosa stack of
:func:`tissuerender.render.brdf.layered_reflectance_cos`; tests compare the two to 1e-9), but:

- two parallel loops over pixels: ``light_rays`` writes every sample's shadow-ray segment, the ray
  backend (:mod:`tissuerender.render.rays`, Embree or our BVH) answers them in one batch, and
  ``shade_direct`` evaluates the BRDF of the visible samples;
- a sample whose light cosine or surface cosine is zero contributes nothing, so its shadow ray is not
  traced (the NumPy path traces it and multiplies by zero).

Rough-plastic points and the reflection-cone estimator stay on the NumPy path.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

INV_PI = 1.0 / np.pi


@njit(cache=True, inline="always")
def _radical_inverse(s):
    out = 0.0
    f = 0.5
    i = s
    while i > 0:
        out += f * (i & 1)
        i >>= 1
        f *= 0.5
    return out


@njit(cache=True, inline="always")
def _ggx_D(n_h, alpha):
    a2 = alpha * alpha
    d = n_h * n_h * (a2 - 1.0) + 1.0
    return a2 / (np.pi * d * d)


@njit(cache=True, inline="always")
def _smith_vis(n_v, n_l, alpha):
    a2 = alpha * alpha
    lam_v = n_l * np.sqrt(n_v * n_v * (1.0 - a2) + a2)
    lam_l = n_v * np.sqrt(n_l * n_l * (1.0 - a2) + a2)
    return 0.5 / max(lam_v + lam_l, 1e-12)


@njit(cache=True, inline="always")
def _dielectric_F(cos_i, ior):
    c = min(max(cos_i, 0.0), 1.0)
    g = np.sqrt(max(ior * ior - 1.0 + c * c, 0.0))
    a = (g - c) / max(g + c, 1e-12)
    b = (c * (g + c) - 1.0) / max(c * (g - c) + 1.0, 1e-12)
    return min(max(0.5 * a * a * (1.0 + b * b), 0.0), 1.0)


@njit(cache=True, inline="always")
def _refracted_cos(mu, ior):
    return np.sqrt(max(1.0 - (1.0 - mu * mu) / (ior * ior), 0.0))


@njit(cache=True, inline="always")
def _sample_point(i, s, mi, rotation, stride, phase, centre, eu, ev):
    index = s * stride + phase[i]
    u = (index / (mi * stride) + rotation[i, 0]) % 1.0
    v = (_radical_inverse(index) + rotation[i, 1]) % 1.0
    return (centre[0] + (2.0 * u - 1.0) * eu[0] + (2.0 * v - 1.0) * ev[0],
            centre[1] + (2.0 * u - 1.0) * eu[1] + (2.0 * v - 1.0) * ev[1],
            centre[2] + (2.0 * u - 1.0) * eu[2] + (2.0 * v - 1.0) * ev[2])


@njit(cache=True, parallel=True)
def light_rays(pos, nrm, m, offsets, rotation, stride, phase, centre, ln, eu, ev, eps, origins, dirs, tfar):
    """Shadow rays of every light sample, in the form the ray backends take (float32 origin, unit
    direction, length): sample s of point i is row ``offsets[i] + s``. The segment runs from the point
    lifted ``2 eps`` along its normal to the light sample, shortened by ``eps`` at both ends (the
    convention of ``BVH.occluded``). ``tfar`` is 0 where the sample cannot contribute (light facing away,
    or the surface facing away from the sample, or a segment shorter than ``2 eps``): that ray is never
    traced."""
    for i in prange(pos.shape[0]):
        px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
        nx, ny, nz = nrm[i, 0], nrm[i, 1], nrm[i, 2]
        ox, oy, oz = px + 2.0 * eps * nx, py + 2.0 * eps * ny, pz + 2.0 * eps * nz
        mi = m[i]
        for s in range(mi):
            j = offsets[i] + s
            qx, qy, qz = _sample_point(i, s, mi, rotation, stride, phase, centre, eu, ev)
            wx, wy, wz = qx - px, qy - py, qz - pz
            cos_l = -(wx * ln[0] + wy * ln[1] + wz * ln[2])
            n_l = nx * wx + ny * wy + nz * wz
            sx, sy, sz = qx - ox, qy - oy, qz - oz
            length = np.sqrt(sx * sx + sy * sy + sz * sz)
            if cos_l > 0.0 and n_l > 0.0 and length > 2.0 * eps:
                sx, sy, sz = sx / length, sy / length, sz / length
                origins[j, 0] = ox + eps * sx
                origins[j, 1] = oy + eps * sy
                origins[j, 2] = oz + eps * sz
                dirs[j, 0] = sx
                dirs[j, 1] = sy
                dirs[j, 2] = sz
                tfar[j] = length - 2.0 * eps
            else:
                tfar[j] = 0.0


@njit(cache=True, parallel=True)
def shade_direct(pos, nrm, wo, albedo, alpha, f0, sss, has_sss, layer, coat, coat_sigma, m, offsets, visible,
                 rotation, stride, phase, centre, ln, eu, ev, out):
    """Add the direct light of the area light to ``out`` (k, 3) (without the light's radiance factor).

    Per point i: ``albedo`` (k, 3), ``alpha``, ``f0``, ``sss`` (k, 3) used where ``has_sss``;
    ``layer[i]`` true applies the mucosa stack with ``coat[i] = (coat_alpha, coat_ior, coat_thickness,
    granular_weight, granular_alpha)`` and ``coat_sigma[i]`` (3,); ``m[i]`` light samples rotated by
    ``rotation[i]``, sample s seen from the point where ``visible[offsets[i] + s]``."""
    k = pos.shape[0]
    area = 4.0 * np.sqrt(eu[0] * eu[0] + eu[1] * eu[1] + eu[2] * eu[2]) * np.sqrt(
        ev[0] * ev[0] + ev[1] * ev[1] + ev[2] * ev[2])
    for i in prange(k):
        px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
        nx, ny, nz = nrm[i, 0], nrm[i, 1], nrm[i, 2]
        vx, vy, vz = wo[i, 0], wo[i, 1], wo[i, 2]
        a = max(alpha[i], 1e-3)
        fr = f0[i]
        n_v = min(max(nx * vx + ny * vy + nz * vz, 0.0), 1.0)
        dr = albedo[i, 0] * INV_PI
        dg = albedo[i, 1] * INV_PI
        db = albedo[i, 2] * INV_PI
        if has_sss:
            dr += sss[i, 0]
            dg += sss[i, 1]
            db += sss[i, 2]
        t_v = 1.0 - (1.0 - 0.5 * n_v) ** 5
        mi = m[i]
        acc_r = 0.0
        acc_g = 0.0
        acc_b = 0.0
        for s in range(mi):
            if not visible[offsets[i] + s]:
                continue
            qx, qy, qz = _sample_point(i, s, mi, rotation, stride, phase, centre, eu, ev)
            wx, wy, wz = qx - px, qy - py, qz - pz
            d2 = max(wx * wx + wy * wy + wz * wz, 1e-12)
            inv_d = 1.0 / np.sqrt(d2)
            wx, wy, wz = wx * inv_d, wy * inv_d, wz * inv_d
            cos_l = max(-(wx * ln[0] + wy * ln[1] + wz * ln[2]), 0.0)
            n_l = min(max(nx * wx + ny * wy + nz * wz, 0.0), 1.0)
            weight = cos_l / d2 * area / mi
            if weight <= 0.0 or n_l <= 0.0:
                continue
            hx, hy, hz = vx + wx, vy + wy, vz + wz
            hn = max(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-12)
            n_h = min(max((nx * hx + ny * hy + nz * hz) / hn, 0.0), 1.0)
            v_h = min(max((vx * hx + vy * hy + vz * hz) / hn, 0.0), 1.0)
            F = fr + (1.0 - fr) * (1.0 - v_h) ** 5
            spec = _ggx_D(n_h, a) * _smith_vis(n_v, n_l, a) * F
            trans = (28.0 / 23.0) * (1.0 - fr) * (1.0 - (1.0 - 0.5 * n_l) ** 5) * t_v
            fr_cos = (dr * trans + spec) * n_l
            fg_cos = (dg * trans + spec) * n_l
            fb_cos = (db * trans + spec) * n_l
            if layer[i]:
                ca = max(coat[i, 0], 1e-3)
                ior = coat[i, 1]
                ga = max(coat[i, 4], 1e-3)
                wg = coat[i, 3]
                spec_coat = _ggx_D(n_h, ca) * _smith_vis(n_v, n_l, ca) * _dielectric_F(v_h, ior) * n_l
                spec_gran = _ggx_D(n_h, ga) * _smith_vis(n_v, n_l, ga) * n_l
                tt = (1.0 - _dielectric_F(n_l, ior)) * (1.0 - _dielectric_F(n_v, ior))
                path = coat[i, 2] * (1.0 / max(_refracted_cos(n_l, ior), 1e-3)
                                     + 1.0 / max(_refracted_cos(n_v, ior), 1e-3))
                fr_cos = spec_coat + tt * np.exp(-coat_sigma[i, 0] * path) * (wg * spec_gran + (1.0 - wg) * fr_cos)
                fg_cos = spec_coat + tt * np.exp(-coat_sigma[i, 1] * path) * (wg * spec_gran + (1.0 - wg) * fg_cos)
                fb_cos = spec_coat + tt * np.exp(-coat_sigma[i, 2] * path) * (wg * spec_gran + (1.0 - wg) * fb_cos)
            acc_r += fr_cos * weight
            acc_g += fg_cos * weight
            acc_b += fb_cos * weight
        out[i, 0] += acc_r
        out[i, 1] += acc_g
        out[i, 2] += acc_b
