"""Numba kernels of the XPBD tet solve (Qian eqs. 4.42–4.44), written in scalars: no array is allocated
per tet, so the parallel colour loop runs at memory speed.

Per tet with ``F = Ds Dm^-1`` and ``B = Dm^-1`` (rows ``b_k``), a constraint ``C(F)`` with
``G = dC/dF`` has node gradients ``g_k = G b_k`` (k = 1..3) and ``g_0 = -(g_1 + g_2 + g_3)``.
Constraints per tet (Macklin & Müller 2021):

- deviatoric ``C_D = ||F||_F``, ``G_D = F / ||F||``, compliance ``alpha_D = 1 / (mu V)``;
- hydrostatic ``C_H = det F - gamma``, ``G_H = cof F``, compliance ``alpha_H = 1 / (lam V)``.

``mode`` 0 solves them in turn (Gauss–Seidel within the tet, F refreshed in between); mode 1 solves
the 2×2 system for both multipliers at once (coupled), as Macklin & Müller recommend for nu -> 0.5.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

PARALLEL_MIN_TETS = 64  # colours smaller than this are projected serially


@njit(cache=True, inline="always")
def _defgrad(x, i0, i1, i2, i3, B, t):
    ax = x[i1, 0] - x[i0, 0]
    ay = x[i1, 1] - x[i0, 1]
    az = x[i1, 2] - x[i0, 2]
    bx = x[i2, 0] - x[i0, 0]
    by = x[i2, 1] - x[i0, 1]
    bz = x[i2, 2] - x[i0, 2]
    cx = x[i3, 0] - x[i0, 0]
    cy = x[i3, 1] - x[i0, 1]
    cz = x[i3, 2] - x[i0, 2]
    b00, b01, b02 = B[t, 0, 0], B[t, 0, 1], B[t, 0, 2]
    b10, b11, b12 = B[t, 1, 0], B[t, 1, 1], B[t, 1, 2]
    b20, b21, b22 = B[t, 2, 0], B[t, 2, 1], B[t, 2, 2]
    return (ax * b00 + bx * b10 + cx * b20, ax * b01 + bx * b11 + cx * b21, ax * b02 + bx * b12 + cx * b22,
            ay * b00 + by * b10 + cy * b20, ay * b01 + by * b11 + cy * b21, ay * b02 + by * b12 + cy * b22,
            az * b00 + bz * b10 + cz * b20, az * b01 + bz * b11 + cz * b21, az * b02 + bz * b12 + cz * b22)


@njit(cache=True, inline="always")
def _cofactor(F):
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    return (f11 * f22 - f21 * f12, f12 * f20 - f22 * f10, f10 * f21 - f20 * f11,
            f21 * f02 - f01 * f22, f22 * f00 - f02 * f20, f20 * f01 - f00 * f21,
            f01 * f12 - f11 * f02, f02 * f10 - f12 * f00, f00 * f11 - f10 * f01)


@njit(cache=True, inline="always")
def _node_grads(G, B, t):
    """(g1, g2, g3) as a 9-tuple: g_k[r] = sum_c G[r, c] B[k, c]."""
    g00, g01, g02, g10, g11, g12, g20, g21, g22 = G
    b00, b01, b02 = B[t, 0, 0], B[t, 0, 1], B[t, 0, 2]
    b10, b11, b12 = B[t, 1, 0], B[t, 1, 1], B[t, 1, 2]
    b20, b21, b22 = B[t, 2, 0], B[t, 2, 1], B[t, 2, 2]
    return (g00 * b00 + g01 * b01 + g02 * b02, g10 * b00 + g11 * b01 + g12 * b02, g20 * b00 + g21 * b01 + g22 * b02,
            g00 * b10 + g01 * b11 + g02 * b12, g10 * b10 + g11 * b11 + g12 * b12, g20 * b10 + g21 * b11 + g22 * b12,
            g00 * b20 + g01 * b21 + g02 * b22, g10 * b20 + g11 * b21 + g12 * b22, g20 * b20 + g21 * b21 + g22 * b22)


@njit(cache=True, inline="always")
def _weighted_dot(g, h, w0, w1, w2, w3):
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
def _apply(x, i0, i1, i2, i3, w0, w1, w2, w3, g, s):
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
    F = _defgrad(x, i0, i1, i2, i3, B, t)
    a_d = alpha_dev[t] * inv_dt2
    a_h = alpha_hyd[t] * inv_dt2
    norm = np.sqrt(F[0] * F[0] + F[1] * F[1] + F[2] * F[2] + F[3] * F[3] + F[4] * F[4]
                   + F[5] * F[5] + F[6] * F[6] + F[7] * F[7] + F[8] * F[8])
    if norm < 1e-12:
        return
    inv = 1.0 / norm
    gd = _node_grads((F[0] * inv, F[1] * inv, F[2] * inv, F[3] * inv, F[4] * inv, F[5] * inv,
                      F[6] * inv, F[7] * inv, F[8] * inv), B, t)
    if mode == 1:
        cof = _cofactor(F)
        gh = _node_grads(cof, B, t)
        c_h = F[0] * cof[0] + F[3] * cof[3] + F[6] * cof[6] - gamma[t]
        a11 = _weighted_dot(gd, gd, w0, w1, w2, w3) + a_d
        a22 = _weighted_dot(gh, gh, w0, w1, w2, w3) + a_h
        a12 = _weighted_dot(gd, gh, w0, w1, w2, w3)
        r1 = -norm - a_d * lam_dev[t]
        r2 = -c_h - a_h * lam_hyd[t]
        det = a11 * a22 - a12 * a12
        if det < 1e-300:
            return
        d1 = scale * (a22 * r1 - a12 * r2) / det
        d2 = scale * (a11 * r2 - a12 * r1) / det
        lam_dev[t] += d1
        lam_hyd[t] += d2
        _apply(out, i0, i1, i2, i3, w0, w1, w2, w3, gd, d1)
        _apply(out, i0, i1, i2, i3, w0, w1, w2, w3, gh, d2)
        return
    denom = _weighted_dot(gd, gd, w0, w1, w2, w3) + a_d
    if denom < 1e-300:
        return
    d1 = scale * (-norm - a_d * lam_dev[t]) / denom
    lam_dev[t] += d1
    _apply(out, i0, i1, i2, i3, w0, w1, w2, w3, gd, d1)
    if in_place:
        F = _defgrad(x, i0, i1, i2, i3, B, t)
    cof = _cofactor(F)
    gh = _node_grads(cof, B, t)
    c_h = F[0] * cof[0] + F[3] * cof[3] + F[6] * cof[6] - gamma[t]
    denom = _weighted_dot(gh, gh, w0, w1, w2, w3) + a_h
    if denom < 1e-300:
        return
    d2 = scale * (-c_h - a_h * lam_hyd[t]) / denom
    lam_hyd[t] += d2
    _apply(out, i0, i1, i2, i3, w0, w1, w2, w3, gh, d2)


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


# ---------------------------------------------------------------------------------------------------
# Blocked Gauss–Seidel: the tets of one colour in blocks of LANES, each block gathered into a small
# structure-of-arrays scratch, projected by a branch-free loop over its lanes that LLVM vectorises
# (AVX-512 / AVX2), and scattered back. Tets of one colour share no node, so the lanes of a block are
# independent and the result is the per-tet scalar projection above up to rounding.
#
# Per tet the solve only needs B = Dm^-1 (rows b_1..b_3, b_0 = -(b_1 + b_2 + b_3)), the inverse masses
# w_k of its nodes and M = sum_k w_k b_k b_k^T (constant within a solve): with node gradients
# g_k = G b_k, sum_k w_k g_k . h_k = <G M, H>, so a11 = <F M, F> / |F|^2, a12 = <F M, cof F> / |F|,
# a22 = <cof F M, cof F>; the combined correction K = d1 F / |F| + d2 cof F moves node k by
# w_k K b_k. In turn (mode 0) the deviatoric step changes F to F + d1 (F M) / |F|, exactly what
# recomputing F from the moved nodes gives.
# ---------------------------------------------------------------------------------------------------

LANES = 16  # tets per block; LLVM vectorises the lane loop with 8-wide zmm (4-wide ymm on AVX2)
VECTOR = 8  # the lane loop of a colour's last, partly filled block stops at a multiple of this
# rows of a block's parameter array (each row holds LANES values)
ROW_B = 0  # 9 rows: b_k[c] at ROW_B + 3 (k - 1) + c, k = 1..3
ROW_M = 9  # 6 rows: M00 M01 M02 M11 M12 M22
ROW_W = 15  # 4 rows: w_0..w_3
ROW_ALPHA_DEV = 19
ROW_ALPHA_HYD = 20
ROW_GAMMA = 21
ROW_LAM_DEV = 22  # the multipliers, reset every substep
ROW_LAM_HYD = 23
N_ROWS = 24
# rows of the scratch: gathered edges e_k = x_k - x_0 (9), node corrections dx_0..dx_3 (12)
SCR_E = 0
SCR_DX = 9
N_SCRATCH = 21
MIN_BLOCKS_PER_THREAD = 4  # colours with fewer blocks per thread run serially (a parallel launch costs more)


def pack_blocks(tets, Dm_inv, w, alpha_dev, alpha_hyd, gamma, colour_start):
    """Block layout of per-tet data stored in colour order: each colour padded to whole blocks of
    ``LANES`` tets. Returns ``(node_index (nb, 4 LANES) int32, params (nb, N_ROWS LANES) float64,
    lanes_used (nb,) int64, colour_block (n_colours + 1,) int64)``; padding lanes have zero B, w and M,
    so their correction is zero, and are neither gathered nor scattered."""
    sizes = np.diff(colour_start)
    blocks_per_colour = (sizes + LANES - 1) // LANES
    colour_block = np.concatenate([[0], np.cumsum(blocks_per_colour)]).astype(np.int64)
    n_blocks = int(colour_block[-1])
    # slot of each tet in the padded sequence
    slot = np.concatenate([colour_block[c] * LANES + np.arange(sizes[c]) for c in range(sizes.size)]
                          ).astype(np.int64) if sizes.size else np.zeros(0, np.int64)
    blk, lane = slot // LANES, slot % LANES
    node_index = np.zeros((n_blocks, 4, LANES), np.uint32)
    node_index[blk, :, lane] = 3 * tets
    params = np.zeros((n_blocks, N_ROWS, LANES))
    b = Dm_inv  # b_k[c] = Dm_inv[k - 1, c]
    params[blk, ROW_B:ROW_B + 9, lane] = b.reshape(-1, 9)
    b_all = np.concatenate([-b.sum(axis=1, keepdims=True), b], axis=1)  # (m, 4, 3): b_0..b_3
    wk = w[tets]  # (m, 4)
    M = np.einsum("mk,mki,mkj->mij", wk, b_all, b_all)
    params[blk, ROW_M:ROW_M + 6, lane] = M[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    params[blk, ROW_W:ROW_W + 4, lane] = wk
    params[blk, ROW_ALPHA_DEV, lane] = alpha_dev
    params[blk, ROW_ALPHA_HYD, lane] = alpha_hyd
    params[blk, ROW_GAMMA, lane] = gamma
    lanes_used = np.zeros(n_blocks, np.int64)
    np.add.at(lanes_used, blk, 1)
    return (node_index.reshape(n_blocks, 4 * LANES), params.reshape(n_blocks, N_ROWS * LANES), lanes_used,
            colour_block)


@njit(cache=True)
def reset_multipliers(params):
    for b in range(params.shape[0]):
        for j in range(ROW_LAM_DEV * LANES, (ROW_LAM_HYD + 1) * LANES):
            params[b, j] = 0.0


_Y = np.uint32(1)  # unsigned offsets keep the coordinate index unsigned: no negative-index wraparound
_Z = np.uint32(2)


@njit(cache=True, inline="always")
def _gather(xf, node_index, n, scratch):
    """Edges e_k = x_k - x_0 of the block's first ``n`` tets into the scratch (``xf``: positions
    flattened, ``node_index``: 3 x node number, unsigned)."""
    for l in range(n):
        i0 = node_index[l]
        i1 = node_index[LANES + l]
        i2 = node_index[2 * LANES + l]
        i3 = node_index[3 * LANES + l]
        x0, y0, z0 = xf[i0], xf[i0 + _Y], xf[i0 + _Z]
        scratch[(SCR_E + 0) * LANES + l] = xf[i1] - x0
        scratch[(SCR_E + 1) * LANES + l] = xf[i1 + _Y] - y0
        scratch[(SCR_E + 2) * LANES + l] = xf[i1 + _Z] - z0
        scratch[(SCR_E + 3) * LANES + l] = xf[i2] - x0
        scratch[(SCR_E + 4) * LANES + l] = xf[i2 + _Y] - y0
        scratch[(SCR_E + 5) * LANES + l] = xf[i2 + _Z] - z0
        scratch[(SCR_E + 6) * LANES + l] = xf[i3] - x0
        scratch[(SCR_E + 7) * LANES + l] = xf[i3 + _Y] - y0
        scratch[(SCR_E + 8) * LANES + l] = xf[i3 + _Z] - z0


@njit(cache=True, inline="always")
def _scatter(xf, node_index, n, scratch):
    for l in range(n):
        for k in range(4):
            i = node_index[k * LANES + l]
            xf[i] += scratch[(SCR_DX + 3 * k) * LANES + l]
            xf[i + _Y] += scratch[(SCR_DX + 3 * k + 1) * LANES + l]
            xf[i + _Z] += scratch[(SCR_DX + 3 * k + 2) * LANES + l]


@njit(cache=True, inline="always")
def _lane_b(p, l):
    return (p[(ROW_B + 0) * LANES + l], p[(ROW_B + 1) * LANES + l], p[(ROW_B + 2) * LANES + l],
            p[(ROW_B + 3) * LANES + l], p[(ROW_B + 4) * LANES + l], p[(ROW_B + 5) * LANES + l],
            p[(ROW_B + 6) * LANES + l], p[(ROW_B + 7) * LANES + l], p[(ROW_B + 8) * LANES + l])


@njit(cache=True, inline="always")
def _lane_defgrad(s, b, l):
    """F = sum_k e_k b_k^T (row-major 9-tuple)."""
    e1x, e1y, e1z = s[(SCR_E + 0) * LANES + l], s[(SCR_E + 1) * LANES + l], s[(SCR_E + 2) * LANES + l]
    e2x, e2y, e2z = s[(SCR_E + 3) * LANES + l], s[(SCR_E + 4) * LANES + l], s[(SCR_E + 5) * LANES + l]
    e3x, e3y, e3z = s[(SCR_E + 6) * LANES + l], s[(SCR_E + 7) * LANES + l], s[(SCR_E + 8) * LANES + l]
    b10, b11, b12, b20, b21, b22, b30, b31, b32 = b
    return (e1x * b10 + e2x * b20 + e3x * b30, e1x * b11 + e2x * b21 + e3x * b31, e1x * b12 + e2x * b22 + e3x * b32,
            e1y * b10 + e2y * b20 + e3y * b30, e1y * b11 + e2y * b21 + e3y * b31, e1y * b12 + e2y * b22 + e3y * b32,
            e1z * b10 + e2z * b20 + e3z * b30, e1z * b11 + e2z * b21 + e3z * b31, e1z * b12 + e2z * b22 + e3z * b32)


@njit(cache=True, inline="always")
def _lane_M(p, l):
    return (p[(ROW_M + 0) * LANES + l], p[(ROW_M + 1) * LANES + l], p[(ROW_M + 2) * LANES + l],
            p[(ROW_M + 3) * LANES + l], p[(ROW_M + 4) * LANES + l], p[(ROW_M + 5) * LANES + l])


@njit(cache=True, inline="always")
def _times_sym(A, M):
    """A M for symmetric M given as (M00, M01, M02, M11, M12, M22)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = A
    m00, m01, m02, m11, m12, m22 = M
    return (a00 * m00 + a01 * m01 + a02 * m02, a00 * m01 + a01 * m11 + a02 * m12, a00 * m02 + a01 * m12 + a02 * m22,
            a10 * m00 + a11 * m01 + a12 * m02, a10 * m01 + a11 * m11 + a12 * m12, a10 * m02 + a11 * m12 + a12 * m22,
            a20 * m00 + a21 * m01 + a22 * m02, a20 * m01 + a21 * m11 + a22 * m12, a20 * m02 + a21 * m12 + a22 * m22)


@njit(cache=True, inline="always")
def _frobenius(A, C):
    return (A[0] * C[0] + A[1] * C[1] + A[2] * C[2] + A[3] * C[3] + A[4] * C[4] + A[5] * C[5]
            + A[6] * C[6] + A[7] * C[7] + A[8] * C[8])


@njit(cache=True, inline="always")
def _lane_store_correction(p, s, l, b, K):
    """dx_k = w_k K b_k into the scratch (b_0 = -(b_1 + b_2 + b_3))."""
    b10, b11, b12, b20, b21, b22, b30, b31, b32 = b
    k00, k01, k02, k10, k11, k12, k20, k21, k22 = K
    u1x = k00 * b10 + k01 * b11 + k02 * b12
    u1y = k10 * b10 + k11 * b11 + k12 * b12
    u1z = k20 * b10 + k21 * b11 + k22 * b12
    u2x = k00 * b20 + k01 * b21 + k02 * b22
    u2y = k10 * b20 + k11 * b21 + k12 * b22
    u2z = k20 * b20 + k21 * b21 + k22 * b22
    u3x = k00 * b30 + k01 * b31 + k02 * b32
    u3y = k10 * b30 + k11 * b31 + k12 * b32
    u3z = k20 * b30 + k21 * b31 + k22 * b32
    w0, w1 = p[(ROW_W + 0) * LANES + l], p[(ROW_W + 1) * LANES + l]
    w2, w3 = p[(ROW_W + 2) * LANES + l], p[(ROW_W + 3) * LANES + l]
    s[(SCR_DX + 0) * LANES + l] = -w0 * (u1x + u2x + u3x)
    s[(SCR_DX + 1) * LANES + l] = -w0 * (u1y + u2y + u3y)
    s[(SCR_DX + 2) * LANES + l] = -w0 * (u1z + u2z + u3z)
    s[(SCR_DX + 3) * LANES + l] = w1 * u1x
    s[(SCR_DX + 4) * LANES + l] = w1 * u1y
    s[(SCR_DX + 5) * LANES + l] = w1 * u1z
    s[(SCR_DX + 6) * LANES + l] = w2 * u2x
    s[(SCR_DX + 7) * LANES + l] = w2 * u2y
    s[(SCR_DX + 8) * LANES + l] = w2 * u2z
    s[(SCR_DX + 9) * LANES + l] = w3 * u3x
    s[(SCR_DX + 10) * LANES + l] = w3 * u3y
    s[(SCR_DX + 11) * LANES + l] = w3 * u3z


@njit(cache=True, inline="always")
def _gram(F):
    """S = F^T F as (S00, S01, S02, S11, S12, S22)."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    return (f00 * f00 + f10 * f10 + f20 * f20, f00 * f01 + f10 * f11 + f20 * f21, f00 * f02 + f10 * f12 + f20 * f22,
            f01 * f01 + f11 * f11 + f21 * f21, f01 * f02 + f11 * f12 + f21 * f22, f02 * f02 + f12 * f12 + f22 * f22)


@njit(cache=True, inline="always")
def _sym_dot(A, M):
    """<A, M> of two symmetric matrices given as (00, 01, 02, 11, 12, 22)."""
    return A[0] * M[0] + A[3] * M[3] + A[5] * M[5] + 2.0 * (A[1] * M[1] + A[2] * M[2] + A[4] * M[4])


@njit(cache=True, inline="always")
def _sym_adjugate(S):
    s00, s01, s02, s11, s12, s22 = S
    return (s11 * s22 - s12 * s12, s02 * s12 - s01 * s22, s01 * s12 - s02 * s11,
            s00 * s22 - s02 * s02, s01 * s02 - s00 * s12, s00 * s11 - s01 * s01)


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _project_lanes_coupled(p, s, lanes, inv_dt2):
    """Coupled 2x2 projection of all lanes of one block (``p``: its parameters, ``s``: scratch with the
    gathered edges; writes the node corrections to ``s``). With S = F^T F:
    a11 = <M, S> / |F|^2 + alpha~_D, a12 = det F tr M / |F| (F^T cof F = det F I),
    a22 = <M, adj S> + alpha~_H (cof F^T cof F = adj S). Branch-free so the lane loop vectorises:
    degenerate tets (|F| < 1e-12 or a singular 2x2 system) get zero corrections, as in project_tet.
    fastmath: only "contract" (fused multiply-add), which changes rounding only."""
    for l in range(lanes):
        b = _lane_b(p, l)
        F = _lane_defgrad(s, b, l)
        M = _lane_M(p, l)
        a_d = p[ROW_ALPHA_DEV * LANES + l] * inv_dt2
        a_h = p[ROW_ALPHA_HYD * LANES + l] * inv_dt2
        lam_d = p[ROW_LAM_DEV * LANES + l]
        lam_h = p[ROW_LAM_HYD * LANES + l]
        S = _gram(F)
        norm = np.sqrt(S[0] + S[3] + S[5])
        inv = 1.0 / max(norm, 1e-12)
        cof = _cofactor(F)
        J = F[0] * cof[0] + F[3] * cof[3] + F[6] * cof[6]
        a11 = _sym_dot(M, S) * inv * inv + a_d
        a12 = J * (M[0] + M[3] + M[5]) * inv
        a22 = _sym_dot(M, _sym_adjugate(S)) + a_h
        r1 = -norm - a_d * lam_d
        r2 = -(J - p[ROW_GAMMA * LANES + l]) - a_h * lam_h
        det = a11 * a22 - a12 * a12
        ok = (norm >= 1e-12) & (det >= 1e-300)
        inv_det = 1.0 / max(det, 1e-300)
        d1 = (a22 * r1 - a12 * r2) * inv_det if ok else 0.0
        d2 = (a11 * r2 - a12 * r1) * inv_det if ok else 0.0
        p[ROW_LAM_DEV * LANES + l] = lam_d + d1
        p[ROW_LAM_HYD * LANES + l] = lam_h + d2
        sd = d1 * inv
        K = (sd * F[0] + d2 * cof[0], sd * F[1] + d2 * cof[1], sd * F[2] + d2 * cof[2],
             sd * F[3] + d2 * cof[3], sd * F[4] + d2 * cof[4], sd * F[5] + d2 * cof[5],
             sd * F[6] + d2 * cof[6], sd * F[7] + d2 * cof[7], sd * F[8] + d2 * cof[8])
        _lane_store_correction(p, s, l, b, K)


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _project_lanes_in_turn(p, s, lanes, inv_dt2):
    """Deviatoric then hydrostatic projection (mode 0) of all lanes of one block; the hydrostatic step
    sees F after the deviatoric step, F + d1 (F M) / |F|. Branch-free; zero corrections where
    project_tet returns early. fastmath: only "contract"."""
    for l in range(lanes):
        b = _lane_b(p, l)
        F = _lane_defgrad(s, b, l)
        M = _lane_M(p, l)
        a_d = p[ROW_ALPHA_DEV * LANES + l] * inv_dt2
        a_h = p[ROW_ALPHA_HYD * LANES + l] * inv_dt2
        lam_d = p[ROW_LAM_DEV * LANES + l]
        lam_h = p[ROW_LAM_HYD * LANES + l]
        norm = np.sqrt(_frobenius(F, F))
        inv = 1.0 / max(norm, 1e-12)
        FM = _times_sym(F, M)
        denom = _frobenius(FM, F) * inv * inv + a_d
        ok = (norm >= 1e-12) & (denom >= 1e-300)
        d1 = (-norm - a_d * lam_d) / max(denom, 1e-300) if ok else 0.0
        sd = d1 * inv
        G = (F[0] + sd * FM[0], F[1] + sd * FM[1], F[2] + sd * FM[2],
             F[3] + sd * FM[3], F[4] + sd * FM[4], F[5] + sd * FM[5],
             F[6] + sd * FM[6], F[7] + sd * FM[7], F[8] + sd * FM[8])  # F after the deviatoric step
        cof = _cofactor(G)
        c_h = G[0] * cof[0] + G[3] * cof[3] + G[6] * cof[6] - p[ROW_GAMMA * LANES + l]
        denom = _frobenius(_times_sym(cof, M), cof) + a_h
        ok = ok & (denom >= 1e-300)
        d2 = (-c_h - a_h * lam_h) / max(denom, 1e-300) if ok else 0.0
        p[ROW_LAM_DEV * LANES + l] = lam_d + d1
        p[ROW_LAM_HYD * LANES + l] = lam_h + d2
        K = (sd * F[0] + d2 * cof[0], sd * F[1] + d2 * cof[1], sd * F[2] + d2 * cof[2],
             sd * F[3] + d2 * cof[3], sd * F[4] + d2 * cof[4], sd * F[5] + d2 * cof[5],
             sd * F[6] + d2 * cof[6], sd * F[7] + d2 * cof[7], sd * F[8] + d2 * cof[8])
        _lane_store_correction(p, s, l, b, K)


@njit(cache=True)
def _project_blocks(x, node_index, params, lanes_used, first, last, inv_dt2, mode, scratch):
    xf = x.reshape(x.size)
    for blk in range(first, last):
        idx = node_index[blk]
        p = params[blk]
        n = lanes_used[blk]
        lanes = min((n + VECTOR - 1) // VECTOR * VECTOR, LANES)  # whole vectors: the tail lanes are padding
        _gather(xf, idx, n, scratch)
        if mode == 1:
            _project_lanes_coupled(p, scratch, lanes, inv_dt2)
        else:
            _project_lanes_in_turn(p, scratch, lanes, inv_dt2)
        _scatter(xf, idx, n, scratch)


@njit(cache=True, parallel=True)
def gauss_seidel_blocked(x, node_index, params, lanes_used, colour_block, domain_colour, inv_dt2, mode, iterations,
                         n_threads):
    """``iterations`` coloured Gauss–Seidel sweeps over the block layout of :func:`pack_blocks`
    (colour c is blocks ``colour_block[c]:colour_block[c+1]``). Colours
    ``domain_colour[d]:domain_colour[d+1]`` are domain d's interior (``sim.coloring.split_into_domains``),
    the last range the separator. Domain interiors share no node: with several threads each sweeps
    its own colours without waiting for the others (one parallel launch per sweep instead of one
    per colour), then the separator's colours follow, each split into one chunk per thread when
    large. ``n_threads`` is ``numba.get_num_threads()`` (inside the kernel it would stop the cache).
    The order does not depend on ``n_threads``; the result is :func:`gauss_seidel`'s up to rounding."""
    n_domains = domain_colour.shape[0] - 2
    scratch = np.zeros(N_SCRATCH * LANES)
    for _ in range(iterations):
        first_shared = 0  # first colour swept colour by colour (all of them with a single domain)
        if n_domains > 1:
            first_shared = domain_colour[n_domains]
            if n_threads > 1:
                for d in prange(n_domains):
                    own = np.zeros(N_SCRATCH * LANES)
                    for c in range(domain_colour[d], domain_colour[d + 1]):
                        _project_blocks(x, node_index, params, lanes_used, colour_block[c], colour_block[c + 1],
                                        inv_dt2, mode, own)
            else:
                _project_blocks(x, node_index, params, lanes_used, 0, colour_block[first_shared], inv_dt2, mode,
                                scratch)
        for c in range(first_shared, colour_block.shape[0] - 1):
            lo = colour_block[c]
            hi = colour_block[c + 1]
            chunks = min(n_threads, (hi - lo) // MIN_BLOCKS_PER_THREAD)
            if chunks <= 1:
                _project_blocks(x, node_index, params, lanes_used, lo, hi, inv_dt2, mode, scratch)
            else:
                for ch in prange(chunks):
                    own = np.zeros(N_SCRATCH * LANES)
                    _project_blocks(x, node_index, params, lanes_used, lo + (hi - lo) * ch // chunks,
                                    lo + (hi - lo) * (ch + 1) // chunks, inv_dt2, mode, own)
