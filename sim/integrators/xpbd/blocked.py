"""Blocked XPBD Gauss–Seidel (the default solve of ``sim.integrators.xpbd``): the same stable Neo-Hookean tet
projection as ``sim.integrators.xpbd.kernels.project_tet`` (Qian eqs. 4.42–4.44, Macklin & Müller 2021), for the
tets of one colour in blocks of ``LANES``: each block is gathered into a small structure-of-arrays
scratch, projected by a branch-free loop over its lanes that LLVM vectorises (8-wide zmm FMAs with
AVX-512, 4-wide ymm with AVX2; check with ``_project_lanes_coupled.inspect_asm(sig)``), and
scattered back. Tets of one colour share no node, so the lanes of a block are independent and the
result is the per-tet projection's up to rounding (tests/sim/integrators/xpbd/test_kernels.py).

Per tet the solve only needs B = Dm^-1 (rows b_1..b_3, b_0 = -(b_1 + b_2 + b_3)), the inverse masses
w_k of its nodes and M = sum_k w_k b_k b_k^T (constant within a solve, precomputed). With node
gradients g_k = G b_k, sum_k w_k g_k . h_k = <G M, H>, so for G_D = F / |F| and G_H = cof F

- a11 = <M, S> / |F|^2 + alpha~_D with S = F^T F,
- a12 = det F tr M / |F| (F^T cof F = det F I),
- a22 = <M, adj S> + alpha~_H (cof F^T cof F = adj(F^T F)),

and the combined correction K = d1 F / |F| + d2 cof F moves node k by w_k K b_k. In turn (mode 0)
the deviatoric step changes F to F + d1 (F M) / |F|, exactly what recomputing F from the moved nodes
gives. Kernels use no ``fastmath``, not even "contract": fused multiply-adds made a run that compiled the
kernels step differently from one that loaded them from numba's cache (docs/xpbd.md, "Determinism"), and
``error_model="numpy"`` (no division checks; divisors are bounded away from zero by ``max``).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from sim.constitutive.kernels import cofactor

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


def colour_slots(colour_start):
    """Where each tet (in colour order, colours ``colour_start``) sits in the block layout: ``(colour_block
    (n_colours + 1,) int64, slot (m,) int64)``, colour c in blocks ``colour_block[c]:colour_block[c + 1]``, tet k in
    block ``slot[k] // LANES``, lane ``slot[k] % LANES`` (each colour padded to whole blocks)."""
    sizes = np.diff(colour_start)
    blocks_per_colour = (sizes + LANES - 1) // LANES
    colour_block = np.concatenate([[0], np.cumsum(blocks_per_colour)]).astype(np.int64)
    slot = np.concatenate([colour_block[c] * LANES + np.arange(sizes[c]) for c in range(sizes.size)]
                          ).astype(np.int64) if sizes.size else np.zeros(0, np.int64)
    return colour_block, slot


def _mass_rows(Dm_inv, wk):
    """M = sum_k w_k b_k b_k^T (m, 6) as (M00, M01, M02, M11, M12, M22), b_0 = -(b_1 + b_2 + b_3)."""
    b_all = np.concatenate([-Dm_inv.sum(axis=1, keepdims=True), Dm_inv], axis=1)  # (m, 4, 3): b_0..b_3
    M = np.einsum("mk,mki,mkj->mij", wk, b_all, b_all)
    return M[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]


def pack_blocks(tets, Dm_inv, w, alpha_dev, alpha_hyd, gamma, colour_start):
    """Block layout of per-tet data stored in colour order: each colour padded to whole blocks of
    ``LANES`` tets (:func:`colour_slots`). Returns ``(node_index (nb, 4 LANES) int32, params (nb, N_ROWS LANES)
    float64, lanes_used (nb,) int64, colour_block (n_colours + 1,) int64)``; padding lanes have zero B, w and M,
    so their correction is zero, and are neither gathered nor scattered."""
    colour_block, slot = colour_slots(colour_start)
    n_blocks = int(colour_block[-1])
    blk, lane = slot // LANES, slot % LANES
    node_index = np.zeros((n_blocks, 4, LANES), np.uint32)
    node_index[blk, :, lane] = 3 * tets
    params = np.zeros((n_blocks, N_ROWS, LANES))
    params[blk, ROW_B:ROW_B + 9, lane] = Dm_inv.reshape(-1, 9)  # b_k[c] = Dm_inv[k - 1, c]
    wk = w[tets]  # (m, 4)
    params[blk, ROW_M:ROW_M + 6, lane] = _mass_rows(Dm_inv, wk)
    params[blk, ROW_W:ROW_W + 4, lane] = wk
    params[blk, ROW_ALPHA_DEV, lane] = alpha_dev
    params[blk, ROW_ALPHA_HYD, lane] = alpha_hyd
    params[blk, ROW_GAMMA, lane] = gamma
    lanes_used = np.zeros(n_blocks, np.int64)
    np.add.at(lanes_used, blk, 1)
    return (node_index.reshape(n_blocks, 4 * LANES), params.reshape(n_blocks, N_ROWS * LANES), lanes_used,
            colour_block)


def make_inert(params, slots):
    """Zero every parameter of the lanes ``slots`` (a removed tet's, ``XPBD.remove_tets``): with B = 0 the lane's
    F is 0, its projection takes the degenerate branch (|F| < 1e-12: d1 = d2 = 0) and its node corrections
    w_k K b_k are exactly zero, so the lane moves nothing (x += 0.0) while keeping its place in the block."""
    p = params.reshape(params.shape[0], N_ROWS, LANES)
    p[slots // LANES, :, slots % LANES] = 0.0


def set_inverse_masses(params, slots, tets, Dm_inv, w):
    """Rewrite the rows w_k and M of the tets at ``slots`` (their node ids ``tets``, rest matrices ``Dm_inv``) from
    the inverse masses ``w``: after a removal changed the lumped masses of their nodes. The same arithmetic as
    :func:`pack_blocks`, so the rows equal a fresh packing's."""
    p = params.reshape(params.shape[0], N_ROWS, LANES)
    blk, lane = slots // LANES, slots % LANES
    wk = w[tets]
    p[blk, ROW_M:ROW_M + 6, lane] = _mass_rows(Dm_inv, wk)
    p[blk, ROW_W:ROW_W + 4, lane] = wk


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


@njit(cache=True, error_model="numpy")
def _project_lanes_coupled(p, s, lanes, inv_dt2):
    """Coupled 2x2 projection of all lanes of one block (``p``: its parameters, ``s``: scratch with the
    gathered edges; writes the node corrections to ``s``). With S = F^T F:
    a11 = <M, S> / |F|^2 + alpha~_D, a12 = det F tr M / |F| (F^T cof F = det F I),
    a22 = <M, adj S> + alpha~_H (cof F^T cof F = adj S). Branch-free so the lane loop vectorises:
    degenerate tets (|F| < 1e-12 or a singular 2x2 system) get zero corrections, as in project_tet.
    No fastmath (docs/xpbd.md, "Determinism")."""
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
        cof = cofactor(F)
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


@njit(cache=True, error_model="numpy")
def _project_lanes_in_turn(p, s, lanes, inv_dt2):
    """Deviatoric then hydrostatic projection (mode 0) of all lanes of one block; the hydrostatic step
    sees F after the deviatoric step, F + d1 (F M) / |F|. Branch-free; zero corrections where
    project_tet returns early. No fastmath."""
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
        cof = cofactor(G)
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
    ``domain_colour[d]:domain_colour[d+1]`` are domain d's interior (``sim.integrators.xpbd.colouring.split_into_domains``),
    the last range the separator. Domain interiors share no node: with several threads each sweeps
    its own colours without waiting for the others (one parallel launch per sweep instead of one
    per colour), then the separator's colours follow, each split into one chunk per thread when
    large. ``n_threads`` is ``numba.get_num_threads()`` (inside the kernel it would stop the cache).
    The order does not depend on ``n_threads``; the result is ``sim.integrators.xpbd.kernels.gauss_seidel``'s up to rounding."""
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
