"""Direct lighting of the G-buffer in one numba pass: for every shading point, its m light samples,
their shadow rays and the BRDF, with no per-sample arrays.

It computes exactly what the NumPy path in :mod:`tissuerender.render.frame` computes for the same
points (the same Hammersley points rotated per pixel, the same ``A / m`` weights, the same Cook–Torrance
terms of :func:`tissuerender.render.brdf.reflectance_cos` and the same mucosa stack of
:func:`tissuerender.render.brdf.layered_reflectance_cos`; tests compare the two to 1e-9), but:

- parallel loops over pixels: ``count_rays`` and ``light_rays`` write the shadow rays of the samples that
  can contribute, packed; the ray backend (:mod:`tissuerender.render.rays`, Embree or our BVH) answers
  them in one batch; ``shade_direct`` evaluates the BRDF of the visible samples;
- a sample whose light cosine or surface cosine is zero contributes nothing, so its shadow ray is not
  traced (the NumPy path traces it and multiplies by zero).

Materials are looked up per point through the G-buffer's material id in small per-material tables
(tissue, mucosa stack, rough plastic with its coating-transmittance table). The reflection-cone
estimator stays on the NumPy path.
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
def _sobol2(n):
    """Second coordinate of the 2D Sobol' sequence (Kollig & Keller 2002), in [0, 1)."""
    r = 0
    v = 1 << 31
    while n > 0:
        if n & 1:
            r ^= v
        n >>= 1
        v ^= v >> 1
    return r / 4294967296.0


@njit(cache=True, inline="always")
def _sample_point(i, s, mi, rotation, stride, phase, centre, eu, ev):
    """Light sample s of m for supersample ``phase[i]`` (frame.light_sample)."""
    p2 = 1
    while p2 < mi:
        p2 *= 2
    n = phase[i] * p2 + s
    u = (_radical_inverse(n) + rotation[i, 0]) % 1.0
    v = (_sobol2(n) + rotation[i, 1]) % 1.0
    return (centre[0] + (2.0 * u - 1.0) * eu[0] + (2.0 * v - 1.0) * ev[0],
            centre[1] + (2.0 * u - 1.0) * eu[1] + (2.0 * v - 1.0) * ev[1],
            centre[2] + (2.0 * u - 1.0) * eu[2] + (2.0 * v - 1.0) * ev[2])


KIND_TISSUE, KIND_LAYERED, KIND_PLASTIC = 0, 1, 2


@njit(cache=True, inline="always")
def _segment(px, py, pz, nx, ny, nz, qx, qy, qz, ln, eps):
    """The shadow segment of one light sample q seen from point p with normal n: (needed, origin,
    unit direction, length). Not needed when the light faces away, the surface faces away from the
    sample, or the segment is shorter than 2 eps. The origin is lifted 2 eps along n and the segment
    shortened by eps at both ends (the convention of ``BVH.occluded``)."""
    wx, wy, wz = qx - px, qy - py, qz - pz
    cos_l = -(wx * ln[0] + wy * ln[1] + wz * ln[2])
    n_l = nx * wx + ny * wy + nz * wz
    ox, oy, oz = px + 2.0 * eps * nx, py + 2.0 * eps * ny, pz + 2.0 * eps * nz
    sx, sy, sz = qx - ox, qy - oy, qz - oz
    length = np.sqrt(sx * sx + sy * sy + sz * sz)
    needed = cos_l > 0.0 and n_l > 0.0 and length > 2.0 * eps
    if not needed:
        return False, ox, oy, oz, 0.0, 0.0, 0.0, 0.0
    sx, sy, sz = sx / length, sy / length, sz / length
    return True, ox + eps * sx, oy + eps * sy, oz + eps * sz, sx, sy, sz, length - 2.0 * eps


@njit(cache=True, parallel=True)
def count_rays(pos, nrm, m, rotation, stride, phase, centre, ln, eu, ev, eps, counts):
    """Number of shadow rays each point needs (samples that can contribute)."""
    for i in prange(pos.shape[0]):
        c = 0
        for s in range(m[i]):
            qx, qy, qz = _sample_point(i, s, m[i], rotation, stride, phase, centre, eu, ev)
            ok = _segment(pos[i, 0], pos[i, 1], pos[i, 2], nrm[i, 0], nrm[i, 1], nrm[i, 2], qx, qy, qz, ln, eps)[0]
            if ok:
                c += 1
        counts[i] = c


@njit(cache=True, parallel=True)
def light_rays(pos, nrm, m, rotation, stride, phase, centre, ln, eu, ev, eps, ray_offsets, origins, dirs, tfar):
    """The needed shadow rays, packed: point i's rays start at ``ray_offsets[i]``, in sample order
    (float32 origin, unit direction, length: the form the ray backends take)."""
    for i in prange(pos.shape[0]):
        r = ray_offsets[i]
        for s in range(m[i]):
            qx, qy, qz = _sample_point(i, s, m[i], rotation, stride, phase, centre, eu, ev)
            ok, ox, oy, oz, dx, dy, dz, length = _segment(pos[i, 0], pos[i, 1], pos[i, 2], nrm[i, 0], nrm[i, 1],
                                                          nrm[i, 2], qx, qy, qz, ln, eps)
            if ok:
                origins[r, 0], origins[r, 1], origins[r, 2] = ox, oy, oz
                dirs[r, 0], dirs[r, 1], dirs[r, 2] = dx, dy, dz
                tfar[r] = length
                r += 1


@njit(cache=True, inline="always")
def _smith_G1(c, alpha):
    c = min(max(c, 1e-12), 1.0)
    tan2 = (1.0 - c * c) / (c * c)
    return 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))


@njit(cache=True, inline="always")
def _fresnel(c, eta):
    """Exact unpolarised Fresnel for relative index eta (plastic.fresnel)."""
    c = min(max(abs(c), 0.0), 1.0)
    sin_t2 = (1.0 - c * c) / (eta * eta)
    if sin_t2 >= 1.0:
        return 1.0
    cos_t = np.sqrt(max(1.0 - sin_t2, 0.0))
    rs = (c - eta * cos_t) / max(c + eta * cos_t, 1e-300)
    rp = (eta * c - cos_t) / max(eta * c + cos_t, 1e-300)
    return 0.5 * (rs * rs + rp * rp)


@njit(cache=True, inline="always")
def _table(t, row, mu):
    """Linear interpolation in a 64-entry table over cosines 0 ... 1 (plastic.transmittance)."""
    n = t.shape[1]
    x = min(max(mu, 0.0), 1.0) * (n - 1)
    k = min(int(x), n - 2)
    f = x - k
    return t[row, k] * (1.0 - f) + t[row, k + 1] * f


@njit(cache=True, parallel=True)
def shade_direct(pos, nrm, wo, albedo, alpha, mat, thickness, has_sss, granular_scale, m, rotation, stride, phase,
                 centre, ln, eu, ev, eps, shadows, ray_offsets, occluded, kind, f0, k_sss, sigma, sss_colour, coat,
                 coat_sigma, plastic, plastic_t, out):
    """Direct light of the area light at every point, into ``out`` (k, 3) (without the light's radiance).

    Per point: ``albedo`` (k, 3) and ``alpha`` (textured where the material has a bake), material id
    ``mat``, SSS ``thickness`` (used when ``has_sss``), ``granular_scale`` (the roughness map's factor
    on the granular layer), ``m`` light samples with their rotation and stride/phase. Per material:
    ``kind`` (tissue / layered / plastic), ``f0``, ``k_sss``, ``sigma`` (3), ``sss_colour`` (3), ``coat``
    (coat alpha, coat ior, coat thickness, granular weight, granular alpha), ``coat_sigma`` (3),
    ``plastic`` (eta, 1 / (1 - F_dr), row in ``plastic_t``) and ``plastic_t`` the coating transmittance
    tables. With ``shadows``, sample s of point i is visible unless its packed ray (``ray_offsets[i]``
    onwards, needed samples only) is ``occluded``."""
    area = 4.0 * np.sqrt(eu[0] * eu[0] + eu[1] * eu[1] + eu[2] * eu[2]) * np.sqrt(
        ev[0] * ev[0] + ev[1] * ev[1] + ev[2] * ev[2])
    for i in prange(pos.shape[0]):
        px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
        nx, ny, nz = nrm[i, 0], nrm[i, 1], nrm[i, 2]
        vx, vy, vz = wo[i, 0], wo[i, 1], wo[i, 2]
        mt = mat[i]
        kd = kind[mt]
        a = max(alpha[i], 1e-3)
        fr = f0[mt]
        n_v = min(max(nx * vx + ny * vy + nz * vz, 0.0), 1.0)
        dr = albedo[i, 0] * INV_PI
        dg = albedo[i, 1] * INV_PI
        db = albedo[i, 2] * INV_PI
        if has_sss and kd != KIND_PLASTIC:
            th = thickness[i]
            ks = k_sss[mt]
            tr = np.exp(-sigma[mt, 0] * th) if np.isfinite(th) else 0.0
            tg = np.exp(-sigma[mt, 1] * th) if np.isfinite(th) else 0.0
            tb = np.exp(-sigma[mt, 2] * th) if np.isfinite(th) else 0.0
            dr += ks * (sss_colour[mt, 0] * INV_PI * tr - albedo[i, 0] * INV_PI)
            dg += ks * (sss_colour[mt, 1] * INV_PI * tg - albedo[i, 1] * INV_PI)
            db += ks * (sss_colour[mt, 2] * INV_PI * tb - albedo[i, 2] * INV_PI)
        t_v = 1.0 - (1.0 - 0.5 * n_v) ** 5
        eta = 1.0
        row = 0
        base = 0.0
        if kd == KIND_PLASTIC:
            eta = plastic[mt, 0]
            row = int(plastic[mt, 2])
            t_view = _table(plastic_t, row, n_v)
            base = plastic[mt, 1] * t_view / (np.pi * eta * eta)
        mi = m[i]
        r = ray_offsets[i]
        acc_r = 0.0
        acc_g = 0.0
        acc_b = 0.0
        for s in range(mi):
            qx, qy, qz = _sample_point(i, s, mi, rotation, stride, phase, centre, eu, ev)
            if shadows:
                ok = _segment(px, py, pz, nx, ny, nz, qx, qy, qz, ln, eps)[0]
                if ok:
                    hidden = occluded[r]
                    r += 1
                    if hidden:
                        continue
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
            if kd == KIND_PLASTIC:
                spec = 0.0
                if n_v > 0.0:
                    spec = (_fresnel(v_h, eta) * _ggx_D(n_h, a) * _smith_G1(n_l, a) * _smith_G1(n_v, a)
                            / (4.0 * max(n_v, 1e-12)))
                b = base * _table(plastic_t, row, n_l) * n_l
                fr_cos = spec + albedo[i, 0] * b
                fg_cos = spec + albedo[i, 1] * b
                fb_cos = spec + albedo[i, 2] * b
            else:
                F = fr + (1.0 - fr) * (1.0 - v_h) ** 5
                spec = _ggx_D(n_h, a) * _smith_vis(n_v, n_l, a) * F
                trans = (28.0 / 23.0) * (1.0 - fr) * (1.0 - (1.0 - 0.5 * n_l) ** 5) * t_v
                fr_cos = (dr * trans + spec) * n_l
                fg_cos = (dg * trans + spec) * n_l
                fb_cos = (db * trans + spec) * n_l
                if kd == KIND_LAYERED:
                    ca = max(coat[mt, 0], 1e-3)
                    ior = coat[mt, 1]
                    ga = max(coat[mt, 4] * granular_scale[i], 1e-3)
                    wg = coat[mt, 3]
                    spec_coat = _ggx_D(n_h, ca) * _smith_vis(n_v, n_l, ca) * _dielectric_F(v_h, ior) * n_l
                    spec_gran = _ggx_D(n_h, ga) * _smith_vis(n_v, n_l, ga) * n_l
                    tt = (1.0 - _dielectric_F(n_l, ior)) * (1.0 - _dielectric_F(n_v, ior))
                    path = coat[mt, 2] * (1.0 / max(_refracted_cos(n_l, ior), 1e-3)
                                          + 1.0 / max(_refracted_cos(n_v, ior), 1e-3))
                    fr_cos = spec_coat + tt * np.exp(-coat_sigma[mt, 0] * path) * (wg * spec_gran + (1.0 - wg) * fr_cos)
                    fg_cos = spec_coat + tt * np.exp(-coat_sigma[mt, 1] * path) * (wg * spec_gran + (1.0 - wg) * fg_cos)
                    fb_cos = spec_coat + tt * np.exp(-coat_sigma[mt, 2] * path) * (wg * spec_gran + (1.0 - wg) * fb_cos)
            acc_r += fr_cos * weight
            acc_g += fg_cos * weight
            acc_b += fb_cos * weight
        out[i, 0] += acc_r
        out[i, 1] += acc_g
        out[i, 2] += acc_b
