"""Numba kernels of the XPBD tet solve (Qian eqs. 4.42–4.44), written in scalars: no array is allocated
per tet, so the parallel colour loop runs at memory speed.

Per tet with ``F = Ds Dm^-1`` and ``B = Dm^-1`` (rows ``b_k``), a constraint ``C(F)`` with
``G = dC/dF`` has node gradients ``g_k = G b_k`` (k = 1..3) and ``g_0 = -(g_1 + g_2 + g_3)``.
Constraints per tet (Macklin & Müller 2021):

- deviatoric ``C_D = ||F||_F``, ``G_D = F / ||F||``, compliance ``alpha_D = 1 / (mu V)``;
- hydrostatic ``C_H = det F - gamma``, ``G_H = cof F``, compliance ``alpha_H = 1 / (lam V)``.

``mode`` 0 solves them in turn (Gauss–Seidel within the tet, F refreshed in between); mode 1 solves
the 2×2 system for both multipliers at once (coupled), as Macklin & Müller recommend for nu -> 0.5.

``project_tet`` is the straightforward per-tet form (used by the Jacobi sweep and the reference
``gauss_seidel``); ``sim.integrators.xpbd.blocked.gauss_seidel_blocked`` (the default solve) projects the tets of
a colour in blocks with a vectorised lane loop and gives the same positions up to rounding
(tests/sim/integrators/xpbd/test_kernels.py: within 5e-15 m after eight steps).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from sim.constitutive.kernels import cofactor, defgrad, node_gradients

PARALLEL_MIN_TETS = 64  # colours smaller than this are projected serially


@njit(cache=True, inline="always")
def weighted_dot(g, h, w0, w1, w2, w3):
    """sum_k w_k g_k . h_k over the four nodes (g_0 = -(g_1+g_2+g_3))."""
    g0x = -(g[0] + g[3] + g[6])
    g0y = -(g[1] + g[4] + g[7])
    g0z = -(g[2] + g[5] + g[8])
    h0x = -(h[0] + h[3] + h[6])
    h0y = -(h[1] + h[4] + h[7])
    h0z = -(h[2] + h[5] + h[8])
    return (w0 * (g0x * h0x + g0y * h0y + g0z * h0z)
            + w1 * (g[0] * h[0] + g[1] * h[1] + g[2] * h[2])
            + w2 * (g[3] * h[3] + g[4] * h[4] + g[5] * h[5])
            + w3 * (g[6] * h[6] + g[7] * h[7] + g[8] * h[8]))


@njit(cache=True, inline="always")
def apply_correction(x, i0, i1, i2, i3, w0, w1, w2, w3, g, s):
    """x_k += w_k g_k s."""
    x[i0, 0] -= w0 * (g[0] + g[3] + g[6]) * s
    x[i0, 1] -= w0 * (g[1] + g[4] + g[7]) * s
    x[i0, 2] -= w0 * (g[2] + g[5] + g[8]) * s
    x[i1, 0] += w1 * g[0] * s
    x[i1, 1] += w1 * g[1] * s
    x[i1, 2] += w1 * g[2] * s
    x[i2, 0] += w2 * g[3] * s
    x[i2, 1] += w2 * g[4] * s
    x[i2, 2] += w2 * g[5] * s
    x[i3, 0] += w3 * g[6] * s
    x[i3, 1] += w3 * g[7] * s
    x[i3, 2] += w3 * g[8] * s


@njit(cache=True, inline="always")
def project_tet(t, x, out, in_place, tets, B, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, inv_dt2, mode,
                scale):
    """Project tet ``t``'s two constraints; corrections go to ``out`` (``x`` itself, ``in_place``, for
    Gauss–Seidel)."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    w0, w1, w2, w3 = w[i0], w[i1], w[i2], w[i3]
    F = defgrad(x, i0, i1, i2, i3, B, t)
    a_d = alpha_dev[t] * inv_dt2
    a_h = alpha_hyd[t] * inv_dt2
    norm = np.sqrt(F[0] * F[0] + F[1] * F[1] + F[2] * F[2] + F[3] * F[3] + F[4] * F[4]
                   + F[5] * F[5] + F[6] * F[6] + F[7] * F[7] + F[8] * F[8])
    if norm < 1e-12:
        return
    inv = 1.0 / norm
    gd = node_gradients((F[0] * inv, F[1] * inv, F[2] * inv, F[3] * inv, F[4] * inv, F[5] * inv,
                      F[6] * inv, F[7] * inv, F[8] * inv), B, t)
    if mode == 1:
        cof = cofactor(F)
        gh = node_gradients(cof, B, t)
        c_h = F[0] * cof[0] + F[3] * cof[3] + F[6] * cof[6] - gamma[t]
        a11 = weighted_dot(gd, gd, w0, w1, w2, w3) + a_d
        a22 = weighted_dot(gh, gh, w0, w1, w2, w3) + a_h
        a12 = weighted_dot(gd, gh, w0, w1, w2, w3)
        r1 = -norm - a_d * lam_dev[t]
        r2 = -c_h - a_h * lam_hyd[t]
        det = a11 * a22 - a12 * a12
        if det < 1e-300:
            return
        d1 = scale * (a22 * r1 - a12 * r2) / det
        d2 = scale * (a11 * r2 - a12 * r1) / det
        lam_dev[t] += d1
        lam_hyd[t] += d2
        apply_correction(out, i0, i1, i2, i3, w0, w1, w2, w3, gd, d1)
        apply_correction(out, i0, i1, i2, i3, w0, w1, w2, w3, gh, d2)
        return
    denom = weighted_dot(gd, gd, w0, w1, w2, w3) + a_d
    if denom < 1e-300:
        return
    d1 = scale * (-norm - a_d * lam_dev[t]) / denom
    lam_dev[t] += d1
    apply_correction(out, i0, i1, i2, i3, w0, w1, w2, w3, gd, d1)
    if in_place:
        F = defgrad(x, i0, i1, i2, i3, B, t)
    cof = cofactor(F)
    gh = node_gradients(cof, B, t)
    c_h = F[0] * cof[0] + F[3] * cof[3] + F[6] * cof[6] - gamma[t]
    denom = weighted_dot(gh, gh, w0, w1, w2, w3) + a_h
    if denom < 1e-300:
        return
    d2 = scale * (-c_h - a_h * lam_hyd[t]) / denom
    lam_hyd[t] += d2
    apply_correction(out, i0, i1, i2, i3, w0, w1, w2, w3, gh, d2)


@njit(cache=True, parallel=True)
def gauss_seidel(x, tets, B, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, inv_dt2, mode,
                 colour_start, iterations):
    """``iterations`` coloured Gauss–Seidel sweeps over tets stored in colour order: colour c is the range
    ``colour_start[c]:colour_start[c+1]``.
    Tets of one colour share no node, so they are projected in parallel without races."""
    n_colours = colour_start.shape[0] - 1
    for _ in range(iterations):
        for c in range(n_colours):
            lo = colour_start[c]
            hi = colour_start[c + 1]
            if hi - lo < PARALLEL_MIN_TETS:  # a parallel launch costs more than a small colour
                for j in range(lo, hi):
                    project_tet(j, x, x, True, tets, B, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd,
                                inv_dt2, mode, 1.0)
            else:
                for j in prange(lo, hi):
                    project_tet(j, x, x, True, tets, B, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd,
                                inv_dt2, mode, 1.0)


@njit(cache=True)
def jacobi(x, tets, B, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, inv_dt2, mode, tet_scale, iterations):
    """Jacobi sweeps: every tet sees the same positions; its step (and its multiplier's) is scaled by
    relaxation / (most tets sharing one of its nodes), which keeps lambda consistent with x."""
    out = np.zeros_like(x)
    for _ in range(iterations):
        out[:] = 0.0
        for t in range(tets.shape[0]):
            project_tet(t, x, out, False, tets, B, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, inv_dt2, mode,
                        tet_scale[t])
        x += out


@njit(cache=True, inline="always")
def _limit_axis(t, x, tets, b, w, smin, smax):
    """Project one tet's stretch |F a| along a material axis into [smin, smax] (a zero-compliance
    unilateral constraint, Qian 4.21): F a = sum_k (x_k - x_0) b_k with b = Dm^-1 a."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    b1, b2, b3 = b[0], b[1], b[2]
    fx = (x[i1, 0] - x[i0, 0]) * b1 + (x[i2, 0] - x[i0, 0]) * b2 + (x[i3, 0] - x[i0, 0]) * b3
    fy = (x[i1, 1] - x[i0, 1]) * b1 + (x[i2, 1] - x[i0, 1]) * b2 + (x[i3, 1] - x[i0, 1]) * b3
    fz = (x[i1, 2] - x[i0, 2]) * b1 + (x[i2, 2] - x[i0, 2]) * b2 + (x[i3, 2] - x[i0, 2]) * b3
    stretch = np.sqrt(fx * fx + fy * fy + fz * fz)
    if stretch < 1e-12:
        return
    if stretch > smax:
        c = stretch - smax
    elif stretch < smin:
        c = stretch - smin
    else:
        return
    nx, ny, nz = fx / stretch, fy / stretch, fz / stretch
    b0 = -(b1 + b2 + b3)
    w0, w1, w2, w3 = w[i0], w[i1], w[i2], w[i3]
    denom = w0 * b0 * b0 + w1 * b1 * b1 + w2 * b2 * b2 + w3 * b3 * b3  # |n| = 1
    if denom < 1e-300:
        return
    s = -c / denom
    for i, wi, bi in ((i0, w0, b0), (i1, w1, b1), (i2, w2, b2), (i3, w3, b3)):
        x[i, 0] += wi * bi * s * nx
        x[i, 1] += wi * bi * s * ny
        x[i, 2] += wi * bi * s * nz


@njit(cache=True, parallel=True)
def strain_limit(x, tets, axes, w, smin, smax, colour_start):
    """One coloured sweep of the strain-limit constraints; ``axes`` (m, k, 3) holds Dm^-1 a for each
    limited material axis a of each tet (stored in colour order like the other per-tet data)."""
    for c in range(colour_start.shape[0] - 1):
        lo = colour_start[c]
        hi = colour_start[c + 1]
        if hi - lo < PARALLEL_MIN_TETS:
            for j in range(lo, hi):
                for k in range(axes.shape[1]):
                    _limit_axis(j, x, tets, axes[j, k], w, smin, smax)
        else:
            for j in prange(lo, hi):
                for k in range(axes.shape[1]):
                    _limit_axis(j, x, tets, axes[j, k], w, smin, smax)
