"""Direct lighting of the G-buffer in one numba pass: for every shading point, its m light samples,
their shadow rays and the BRDF, with no per-sample arrays.

It computes exactly what the NumPy estimator in :mod:`tissuerender.renderer.direct` computes for the same
points (the same Sobol' points rotated per pixel, the same ``A / m`` weights, the same BSDFs of
:mod:`tissuerender.renderer.bsdf`: the tissue's Cook–Torrance terms, the mucosa stack and the rough
plastic; tests compare the two to 1e-9), but:

- parallel loops over pixels: ``light_rays`` writes one shadow ray per sample (zero-length where the
  sample cannot contribute); the ray backend (:mod:`tissuerender.renderer.rays`, Embree or our BVH) answers
  them in one batch; ``shade_direct`` evaluates the BRDF of the visible samples;
- a sample whose light cosine or surface cosine is zero contributes nothing, so its shadow ray has zero
  length (the NumPy path traces it and multiplies by zero).

Materials are looked up per point through the G-buffer's material id in small per-material tables
(``bsdf.kernel_tables``: tissue, mucosa stack, rough plastic with its coating-transmittance table), the
BSDF chosen by its integer code ``KIND_*`` (``bsdf.make_bsdf`` maps names to codes). The reflection-cone
estimator stays on the NumPy path. The ratio estimator of the diffuse lobe (``light.estimator =
"ratio"``, ``rect_cosine_integral``) exists only here.
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
    """Light sample s of m for supersample ``phase[i]`` (light.light_sample)."""
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
def _edge_term(ax, ay, az, bx, by, bz, nx, ny, nz):
    """Lambert's edge term of a polygon seen from the origin: the angle the edge a -> b subtends times
    the normal's component along the unit normal of the plane through the origin, a and b."""
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    c2 = cx * cx + cy * cy + cz * cz
    if c2 <= 0.0:
        return 0.0
    d = ax * bx + ay * by + az * bz
    if d > 0.0 and c2 < 0.0025 * d * d:
        # angle / |a x b| = atan(x) / (x d) with x = |a x b| / d < 0.05: the series of atan(x) / x in
        # y = x^2 to y^5 (truncation below y^6 / 13 < 2e-17), no square root or arctangent; a laparoscope's
        # light subtends a few degrees, so this is the common case
        inv_d = 1.0 / d
        y = c2 * inv_d * inv_d
        g = 1.0 - y * (1.0 / 3.0 - y * (1.0 / 5.0 - y * (1.0 / 7.0 - y * (1.0 / 9.0 - y * (1.0 / 11.0)))))
        return g * inv_d * (nx * cx + ny * cy + nz * cz)
    c = np.sqrt(c2)
    return np.arctan2(c, d) * (nx * cx + ny * cy + nz * cz) / c


@njit(cache=True)
def rect_cosine_integral(px, py, pz, nx, ny, nz, centre, ln, eu, ev):
    """The unshadowed integral of the cosine over the light seen from point p with unit normal n,
    ``int_light (n.wi) cos(theta_l) / r^2 dA = int_Omega max(n.w, 0) dw`` [sr] (pi times the form
    factor; irradiance per unit radiance), in closed form: the rectangle (corners centre +- eu +- ev,
    one-sided, emitting along ``ln``) is clipped to the upper hemisphere of n and Lambert's polygon
    formula sums, over the edges, the angle each subtends times the normal's component along its
    plane's normal (Arvo 1994; Heitz, Hill & McGuire 2018 use it as the analytic factor of the ratio
    estimator). Zero behind the light or with the light wholly below the horizon."""
    if (px - centre[0]) * ln[0] + (py - centre[1]) * ln[1] + (pz - centre[2]) * ln[2] <= 0.0:
        return 0.0
    # the common case first: the whole light above the horizon, four edges, each corner computed once
    cx, cy, cz = centre[0] - px, centre[1] - py, centre[2] - pz
    x0, y0, z0 = cx - eu[0] - ev[0], cy - eu[1] - ev[1], cz - eu[2] - ev[2]
    x1, y1, z1 = cx + eu[0] - ev[0], cy + eu[1] - ev[1], cz + eu[2] - ev[2]
    x2, y2, z2 = cx + eu[0] + ev[0], cy + eu[1] + ev[1], cz + eu[2] + ev[2]
    x3, y3, z3 = cx - eu[0] + ev[0], cy - eu[1] + ev[1], cz - eu[2] + ev[2]
    if (nx * x0 + ny * y0 + nz * z0 >= 0.0 and nx * x1 + ny * y1 + nz * z1 >= 0.0
            and nx * x2 + ny * y2 + nz * z2 >= 0.0 and nx * x3 + ny * y3 + nz * z3 >= 0.0):
        return 0.5 * abs(_edge_term(x0, y0, z0, x1, y1, z1, nx, ny, nz) + _edge_term(x1, y1, z1, x2, y2, z2, nx, ny, nz)
                         + _edge_term(x2, y2, z2, x3, y3, z3, nx, ny, nz) + _edge_term(x3, y3, z3, x0, y0, z0, nx, ny, nz))
    # corners relative to p, counter-clockwise in (eu, ev)
    total = 0.0
    have_exit = False
    ex, ey, ez = 0.0, 0.0, 0.0  # where the boundary leaves the upper hemisphere
    gx, gy, gz = 0.0, 0.0, 0.0  # where it enters again
    have_entry = False
    for k in range(4):
        su = -1.0 if k == 0 or k == 3 else 1.0
        sv = -1.0 if k < 2 else 1.0
        k1 = (k + 1) % 4
        tu = -1.0 if k1 == 0 or k1 == 3 else 1.0
        tv = -1.0 if k1 < 2 else 1.0
        ax = centre[0] + su * eu[0] + sv * ev[0] - px
        ay = centre[1] + su * eu[1] + sv * ev[1] - py
        az = centre[2] + su * eu[2] + sv * ev[2] - pz
        bx = centre[0] + tu * eu[0] + tv * ev[0] - px
        by = centre[1] + tu * eu[1] + tv * ev[1] - py
        bz = centre[2] + tu * eu[2] + tv * ev[2] - pz
        ha = nx * ax + ny * ay + nz * az
        hb = nx * bx + ny * by + nz * bz
        if ha >= 0.0 and hb >= 0.0:
            total += _edge_term(ax, ay, az, bx, by, bz, nx, ny, nz)
        elif ha >= 0.0:  # leaves: a -> crossing
            t = ha / (ha - hb)
            ex, ey, ez = ax + t * (bx - ax), ay + t * (by - ay), az + t * (bz - az)
            have_exit = True
            total += _edge_term(ax, ay, az, ex, ey, ez, nx, ny, nz)
        elif hb >= 0.0:  # enters: crossing -> b
            t = ha / (ha - hb)
            gx, gy, gz = ax + t * (bx - ax), ay + t * (by - ay), az + t * (bz - az)
            have_entry = True
            total += _edge_term(gx, gy, gz, bx, by, bz, nx, ny, nz)
    if have_exit and have_entry:  # the clipped polygon's edge along the horizon
        total += _edge_term(ex, ey, ez, gx, gy, gz, nx, ny, nz)
    return 0.5 * abs(total)


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
def cosine_integrals(pos, nrm, centre, ln, eu, ev, out):
    """``rect_cosine_integral`` of every point (a pass of its own: inlined in the shading loop it was
    slower, docs/renderer.md, "How fast, and why")."""
    for i in prange(pos.shape[0]):
        out[i] = rect_cosine_integral(pos[i, 0], pos[i, 1], pos[i, 2], nrm[i, 0], nrm[i, 1], nrm[i, 2], centre, ln,
                                      eu, ev)


@njit(cache=True, parallel=True)
def visibility_bits(pos, nrm, m, rotation, stride, phase, centre, ln, eu, ev, eps, ray_offsets, occluded, bits):
    """Per point, over the samples that can contribute: bit 1 if one is occluded, bit 2 if one is visible
    (3: the point sees part of the light, a penumbra)."""
    for i in prange(pos.shape[0]):
        b = 0
        for s in range(m[i]):
            qx, qy, qz = _sample_point(i, s, m[i], rotation, stride, phase, centre, eu, ev)
            if _segment(pos[i, 0], pos[i, 1], pos[i, 2], nrm[i, 0], nrm[i, 1], nrm[i, 2], qx, qy, qz, ln, eps)[0]:
                b |= 1 if occluded[ray_offsets[i] + s] else 2
        bits[i] = b


@njit(cache=True)
def pixel_or(pixel, bits, out):
    """``out[pixel[i]] |= bits[i]`` (the supersamples of a pixel are few: a serial pass)."""
    for i in range(pixel.shape[0]):
        out[pixel[i]] |= bits[i]


@njit(cache=True, parallel=True)
def light_rays(pos, nrm, m, rotation, stride, phase, centre, ln, eu, ev, eps, ray_offsets, origins, dirs, tfar):
    """The shadow rays of every sample: sample s of point i is ray ``ray_offsets[i] + s`` (the exclusive
    prefix sum of m; float32 origin, unit direction, length: the form the ray backends take). A sample
    that cannot contribute (``_segment``) gets a zero-length ray at the point, cheap to trace, whose
    answer ``shade_direct`` never reads; one pass, with no count of the needed rays first."""
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
            else:
                origins[r, 0], origins[r, 1], origins[r, 2] = pos[i, 0], pos[i, 1], pos[i, 2]
                dirs[r, 0], dirs[r, 1], dirs[r, 2] = 0.0, 0.0, 1.0
                tfar[r] = 0.0
            r += 1


@njit(cache=True, inline="always")
def _smith_G1(c, alpha):
    c = min(max(c, 1e-12), 1.0)
    tan2 = (1.0 - c * c) / (c * c)
    return 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))


@njit(cache=True, inline="always")
def _fresnel(c, eta):
    """Exact unpolarised Fresnel for relative index eta (bsdf.microfacet.fresnel)."""
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
    """Linear interpolation in a 64-entry table over cosines 0 ... 1 (bsdf.plastic.transmittance)."""
    n = t.shape[1]
    x = min(max(mu, 0.0), 1.0) * (n - 1)
    k = min(int(x), n - 2)
    f = x - k
    return t[row, k] * (1.0 - f) + t[row, k + 1] * f


@njit(cache=True, inline="always")
def _table2(t, plane, alpha, mu):
    """Bilinear interpolation in plane ``plane`` of a (2, alphas, cosines) table (bsdf.albedo.lookup_alpha_mu)."""
    na, nm = t.shape[1], t.shape[2]
    xa = min(max(alpha, 0.0), 1.0) * (na - 1)
    ka = min(int(xa), na - 2)
    fa = xa - ka
    xm = min(max(mu, 0.0), 1.0) * (nm - 1)
    km = min(int(xm), nm - 2)
    fm = xm - km
    lo = t[plane, ka, km] * (1.0 - fm) + t[plane, ka, km + 1] * fm
    hi = t[plane, ka + 1, km] * (1.0 - fm) + t[plane, ka + 1, km + 1] * fm
    return lo * (1.0 - fa) + hi * fa


@njit(cache=True, inline="always")
def _table1(t, plane, alpha):
    """Linear interpolation in row ``plane`` of a (2, alphas) table (bsdf.albedo.lookup_alpha)."""
    na = t.shape[1]
    xa = min(max(alpha, 0.0), 1.0) * (na - 1)
    ka = min(int(xa), na - 2)
    fa = xa - ka
    return t[plane, ka] * (1.0 - fa) + t[plane, ka + 1] * fa


@njit(cache=True, parallel=True)
def shade_direct(pos, nrm, wo, albedo, alpha, mat, thickness, has_sss, granular_scale, m, rotation, stride, phase,
                 centre, ln, eu, ev, eps, shadows, ray_offsets, occluded, kind, f0, k_sss, sigma, sigma_deep,
                 sss_depth, sss_colour, coat, coat_sigma, coat_E, coat_norm, schlick_E, plastic, plastic_t, ratio,
                 unshadowed, out):
    """Direct light of the area light at every point, into ``out`` (k, 3) (without the light's radiance).

    Per point: ``albedo`` (k, 3) and ``alpha`` (textured where the material has a bake), material id
    ``mat``, SSS ``thickness`` (used when ``has_sss``), ``granular_scale`` (the roughness map's factor
    on the granular layer), ``m`` light samples with their rotation and stride/phase. Per material:
    ``kind`` (tissue / layered / plastic), ``f0``, ``k_sss``, ``sigma`` (3) and ``sigma_deep`` (3) the
    thickness term's attenuations above and below the depth ``sss_depth`` (``OpticalMaterial.
    subsurface_attenuation``), ``sss_colour`` (3) its colour C, ``coat``
    (coat alpha, coat ior, coat thickness, granular weight, granular alpha), ``coat_sigma`` (3), ``coat_E``
    the coat lobe's albedo table, ``coat_norm`` (3, alphas) the normalisations of the lobes under it and
    ``schlick_E`` (2, alphas, cosines) the tissue lobe's Schlick split albedo tables (``bsdf.albedo``),
    ``plastic`` (eta, 1 / (1 - F_dr), row in ``plastic_t``) and ``plastic_t`` the coating transmittance
    tables. With ``shadows``, sample s of point i that can contribute is visible unless ray
    ``ray_offsets[i] + s`` is ``occluded``.

    ``ratio`` (``light.estimator = "ratio"``): the diffuse lobe (including the SSS term and, under a coat
    or a plastic coating, the base) is estimated as ``U sum(f V w) / sum((n.wi) w)`` with U the closed
    form of the unshadowed cosine integral (``unshadowed``, from ``cosine_integrals``); the specular lobes stay plain
    Monte Carlo. Without ``ratio`` every lobe is ``sum(f V w)``."""
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
            # materials.optics.layered_transmittance: sigma over min(T, depth), sigma_deep beyond
            # (depth 0: exp(-sigma T) to the bit)
            upper = min(th, sss_depth[mt])
            lower = max(th - sss_depth[mt], 0.0)
            tr = np.exp(-(sigma[mt, 0] * upper + sigma_deep[mt, 0] * lower)) if np.isfinite(th) else 0.0
            tg = np.exp(-(sigma[mt, 1] * upper + sigma_deep[mt, 1] * lower)) if np.isfinite(th) else 0.0
            tb = np.exp(-(sigma[mt, 2] * upper + sigma_deep[mt, 2] * lower)) if np.isfinite(th) else 0.0
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
        ca, ior, ga, wg, c_o, ds_o, ms_o = 1e-3, 1.0, 1e-3, 0.0, 1.0, 0.0, 0.0
        if kd == KIND_LAYERED:
            ca = max(coat[mt, 0], 1e-3)
            ior = coat[mt, 1]
            ga = max(coat[mt, 4] * granular_scale[i], 1e-3)
            wg = coat[mt, 3]
            c_o = 1.0 - _table(coat_E, mt, n_v)
            # X(mu_o) / N of the diffuse lobe under the tissue lobe (F0 = fr) and, over pi, of the granular one
            Es_o = fr * _table2(schlick_E, 0, a, n_v) + _table2(schlick_E, 1, a, n_v)
            ds_o = c_o * (1.0 - Es_o) / (_table1(coat_norm[mt], 0, a) - fr * _table1(coat_norm[mt], 1, a))
            g_o = _table2(schlick_E, 0, ga, n_v) + _table2(schlick_E, 1, ga, n_v)
            ms_o = c_o * (1.0 - g_o) / max(np.pi * _table1(coat_norm[mt], 2, ga), 1e-12)
        mi = m[i]
        r = ray_offsets[i]
        acc_r = 0.0  # specular (and everything not diffuse): plain Monte Carlo
        acc_g = 0.0
        acc_b = 0.0
        dif_r = 0.0  # the diffuse lobe (Lambert / Ashikhmin-Shirley, SSS; the base under a coat)
        dif_g = 0.0
        dif_b = 0.0
        den = 0.0  # ratio estimator: sum of the unshadowed cosine terms (n.wi) w
        for s in range(mi):
            qx, qy, qz = _sample_point(i, s, mi, rotation, stride, phase, centre, eu, ev)
            hidden = False
            if shadows:
                if _segment(px, py, pz, nx, ny, nz, qx, qy, qz, ln, eps)[0]:
                    hidden = occluded[r + s]
                    if hidden and not ratio:
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
            den += n_l * weight
            if hidden:
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
                b = base * _table(plastic_t, row, n_l) * n_l * weight
                dif_r += albedo[i, 0] * b
                dif_g += albedo[i, 1] * b
                dif_b += albedo[i, 2] * b
                acc_r += spec * weight
                acc_g += spec * weight
                acc_b += spec * weight
            else:
                F = fr + (1.0 - fr) * (1.0 - v_h) ** 5
                spec = _ggx_D(n_h, a) * _smith_vis(n_v, n_l, a) * F * n_l
                trans = (28.0 / 23.0) * (1.0 - fr) * (1.0 - (1.0 - 0.5 * n_l) ** 5) * t_v * n_l
                if kd == KIND_LAYERED:
                    # the wet stack (bsdf.mucosa): coat lobe, T_s over the specular lobes, the diffuse lobes
                    # scaled by what the coat and the lobe above them leave, X(mu_i) X(mu_o) / N
                    spec_coat = _ggx_D(n_h, ca) * _smith_vis(n_v, n_l, ca) * _dielectric_F(v_h, ior) * n_l
                    c_i = 1.0 - _table(coat_E, mt, n_l)
                    T_s = min(c_i, c_o)
                    path = coat[mt, 2] * (1.0 / max(_refracted_cos(n_l, ior), 1e-3)
                                          + 1.0 / max(_refracted_cos(n_v, ior), 1e-3))
                    f_s = _ggx_D(n_h, a) * _smith_vis(n_v, n_l, a) * F * n_l
                    f_g = _ggx_D(n_h, ga) * _smith_vis(n_v, n_l, ga) * n_l
                    s_A = _table2(schlick_E, 0, a, n_l)
                    s_B = _table2(schlick_E, 1, a, n_l)
                    Es_i = fr * s_A + s_B
                    g_i = _table2(schlick_E, 0, ga, n_l) + _table2(schlick_E, 1, ga, n_l)
                    f_ms = c_i * (1.0 - g_i) * ms_o * n_l
                    sdiff = c_i * (1.0 - Es_i) * ds_o * n_l
                    under = T_s * ((1.0 - wg) * f_s + wg * f_g)
                    t0 = np.exp(-coat_sigma[mt, 0] * path) * weight
                    t1 = np.exp(-coat_sigma[mt, 1] * path) * weight
                    t2 = np.exp(-coat_sigma[mt, 2] * path) * weight
                    acc_r += spec_coat * weight + t0 * under
                    acc_g += spec_coat * weight + t1 * under
                    acc_b += spec_coat * weight + t2 * under
                    dif_r += t0 * ((1.0 - wg) * dr * sdiff + wg * f_ms)
                    dif_g += t1 * ((1.0 - wg) * dg * sdiff + wg * f_ms)
                    dif_b += t2 * ((1.0 - wg) * db * sdiff + wg * f_ms)
                else:
                    acc_r += spec * weight
                    acc_g += spec * weight
                    acc_b += spec * weight
                    dif_r += dr * trans * weight
                    dif_g += dg * trans * weight
                    dif_b += db * trans * weight
        if ratio:
            # Heitz, Hill & McGuire 2018: the closed-form unshadowed cosine integral times the sampled
            # (f V) / (n.wi) ratio; exact where the light is unoccluded and f is Lambertian
            scale = 0.0
            if den > 0.0:
                scale = unshadowed[i] / den
            dif_r *= scale
            dif_g *= scale
            dif_b *= scale
        out[i, 0] += acc_r + dif_r
        out[i, 1] += acc_g + dif_g
        out[i, 2] += acc_b + dif_b
