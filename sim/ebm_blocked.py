"""Blocked EBM kernels (``kernel = "blocked"``, the default of ``sim.ebm``): one whole step (prediction 5.13,
``iterations`` Jacobi sweeps 5.7-5.9 / 5.14, velocities 5.15 and the energy accounting) in one compiled
call, with the per-tet work vectorised across tets.

The energy balance is a Jacobi update (every tet sees the positions of the previous sweep, the increments
are summed per node), so all tets of a sweep are independent. A sweep runs over blocks of ``LANES``
consecutive tets: the block's edges ``e_k = x_k - x_0`` are gathered into a structure-of-arrays scratch,
a branch-free loop over the lanes (energy, Piola stress, node gradients, multiplier, increments; LLVM
vectorises it, 8-wide zmm FMAs with AVX-512 — check with ``_sweep_block.inspect_asm``) writes each tet's
four increments to a per-tet buffer, and a node pass sums, for every free node, its increments in tet
order (a gather over a precomputed incidence list: no scatter, and the same summation order as the scalar
kernel ``sim.ebm_kernels.ebm_iterations``), then applies ``x_i += dx_i / n_i`` (update = "average").

Per lane, with ``g_k = P b_k`` (``b_k`` the rows of Dm^-1, ``b_0 = -(b_1 + b_2 + b_3)``):
``lambda' = Psi / sum_j w_j |g_j|^2`` and ``dx_k = -w_k lambda' g_k``. This is 5.7-5.8 with the volume
cancelled (``W = V Psi``, ``dW/dx_k = V g_k``: the multiplier scales as 1/V, the increment not at all);
a vanishing denominator (``<= 1e-300``, a tet at rest to the last bit) gives no increment, a NaN one (an
inverted tet of a split model, where J^(-2/3) is undefined) fails the sweep, as in the scalar kernel.
J^(-1/3) comes from ``sim.ebm_kernels._inverse_cube_root`` (bit-pattern seed and three cubically
convergent steps: within 3.3e-16 of 1 / cbrt(J), no libm call, so the loop vectorises).

Kernels use ``fastmath={"contract"}`` only (fused multiply-add: one rounding instead of two, nothing else;
no reassociation, no finite-math assumptions, so NaN checks keep working) and ``error_model="numpy"`` (no
division checks: divisors are guarded by selects). Results equal the scalar kernel's to rounding (tested to
1e-10 after several steps: tests/sim/test_ebm_kernels.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from sim.ebm_kernels import ANISOTROPIC_NEO_HOOKEAN, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK, _energy_piola_root

LANES = 16  # tets per block: one zmm register of float64 per quantity
# rows of a block's parameter array (each row holds LANES values)
ROW_B = 0  # 9 rows: b_k[c] = Dm_inv[k - 1, c] at ROW_B + 3 (k - 1) + c, k = 1..3
ROW_W = 9  # 4 rows: inverse masses w_0..w_3 of the tet's nodes
ROW_MU = 13
ROW_LAM = 14
ROW_ETA = 15
ROW_FIBRE = 16  # 3 rows: a0
ROW_VOLUME = 19
N_ROWS = 20
# rows of the Prony array (rebuilt each step): Gamma (9, row-major), g
ROW_GAMMA = 0
ROW_G = 9
N_RELAX = 10
# rows of the per-tet output: dx_k (or dW/dx_k for the forces) at 3 k + c, then W and |F|^2 (forces only)
OUT_D = 0
OUT_W = 12
OUT_FF = 13
N_OUT = 14

_Y = np.uint32(1)  # unsigned offsets keep indices unsigned: no negative-index wraparound code
_Z = np.uint32(2)
_L = np.uint32(LANES)
_L2 = np.uint32(2 * LANES)


def pack(tets, Dm_inv, volume, mu, lam, eta, fibre, w, n_nodes, free):
    """Block layout of the per-tet data (tet t is lane t % LANES of block t // LANES; padding lanes of the
    last block repeat tet 0, so their arithmetic stays finite, and nothing reads their output).

    Returns ``(node_index (nb, 4 LANES) uint32 = 3 x node, params (nb, N_ROWS LANES), free_nodes (nf,) int64,
    free_start (nf + 1,) int64, free_slot uint32, kin_nodes, kin_start, kin_slot)``: ``*_slot[p]`` is the
    offset in the flattened output ``(nb, N_OUT LANES)`` of coordinate x of one (tet, corner) incident on the
    node, the node's incidences in increasing tet order (the scalar kernel's summation order)."""
    m = tets.shape[0]
    nb = (m + LANES - 1) // LANES
    order = np.concatenate([np.arange(m), np.zeros(nb * LANES - m, np.int64)])  # padding: tet 0
    blk, lane = np.arange(nb * LANES) // LANES, np.arange(nb * LANES) % LANES
    node_index = np.zeros((nb, 4, LANES), np.uint32)
    node_index[blk, :, lane] = 3 * tets[order]
    params = np.zeros((nb, N_ROWS, LANES))
    params[blk, ROW_B:ROW_B + 9, lane] = Dm_inv[order].reshape(-1, 9)
    params[blk, ROW_W:ROW_W + 4, lane] = w[tets[order]]
    params[blk, ROW_MU, lane] = mu[order]
    params[blk, ROW_LAM, lane] = lam[order]
    params[blk, ROW_ETA, lane] = eta[order]
    params[blk, ROW_FIBRE:ROW_FIBRE + 3, lane] = fibre[order]
    params[blk, ROW_VOLUME, lane] = volume[order]
    # incidences (node, tet, corner) sorted by node then tet
    node = tets.ravel()
    tet = np.repeat(np.arange(m), 4)
    corner = np.tile(np.arange(4), m)
    slot = (tet // LANES) * (N_OUT * LANES) + (OUT_D + 3 * corner) * LANES + tet % LANES
    by_node = np.lexsort((tet, node))
    node, slot = node[by_node], slot[by_node]
    start = np.searchsorted(node, np.arange(n_nodes + 1))

    def csr(nodes):
        counts = start[nodes + 1] - start[nodes]
        sel = np.concatenate([np.arange(start[i], start[i + 1]) for i in nodes]) if nodes.size else np.zeros(0, int)
        return (nodes.astype(np.int64), np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                slot[sel].astype(np.uint32))

    free_nodes = np.flatnonzero(free)
    kin_nodes = np.flatnonzero(~free)
    return (node_index.reshape(nb, 4 * LANES), params.reshape(nb, N_ROWS * LANES), *csr(free_nodes),
            *csr(kin_nodes))


def pack_relaxation(Gamma, g, n_blocks):
    """Prony coefficients of a step (``Gamma (m, 3, 3)``, ``g (m,)``) in the block layout (padding: tet 0)."""
    m = Gamma.shape[0]
    order = np.concatenate([np.arange(m), np.zeros(n_blocks * LANES - m, np.int64)])
    relax = np.empty((n_blocks, N_RELAX, LANES))
    relax[:, ROW_GAMMA:ROW_GAMMA + 9, :] = Gamma[order].reshape(n_blocks, LANES, 9).transpose(0, 2, 1)
    relax[:, ROW_G, :] = g[order].reshape(n_blocks, LANES)
    return relax.reshape(n_blocks, N_RELAX * LANES)


@njit(cache=True, inline="always")
def _gather(xf, node_index, scratch):
    """Edges e_k = x_k - x_0 (k = 1..3) of the block's tets into ``scratch`` rows 0..8."""
    for l in range(LANES):
        i0 = node_index[l]
        i1 = node_index[LANES + l]
        i2 = node_index[2 * LANES + l]
        i3 = node_index[3 * LANES + l]
        x0, y0, z0 = xf[i0], xf[i0 + _Y], xf[i0 + _Z]
        scratch[0 * LANES + l] = xf[i1] - x0
        scratch[1 * LANES + l] = xf[i1 + _Y] - y0
        scratch[2 * LANES + l] = xf[i1 + _Z] - z0
        scratch[3 * LANES + l] = xf[i2] - x0
        scratch[4 * LANES + l] = xf[i2 + _Y] - y0
        scratch[5 * LANES + l] = xf[i2 + _Z] - z0
        scratch[6 * LANES + l] = xf[i3] - x0
        scratch[7 * LANES + l] = xf[i3 + _Y] - y0
        scratch[8 * LANES + l] = xf[i3 + _Z] - z0


@njit(cache=True, inline="always")
def _lanes(code, prony, forces, p, r, s, out, relax_a, lanes):
    """The branch-free loop over the lanes of one block (``code``, ``prony``, ``forces`` are constants at each
    call site). Sweep (``forces`` False): the increments ``-w_k lambda' g_k`` into ``out``; returns the
    number of NaN multipliers. Forces: ``dW/dx_k = V P b_k``, ``W = V Psi`` and ``|F|^2`` into ``out``."""
    bad = 0
    for l in range(lanes):  # a run-time trip count: with a constant one LLVM unrolls the loop instead
        b10, b11, b12 = p[(ROW_B + 0) * LANES + l], p[(ROW_B + 1) * LANES + l], p[(ROW_B + 2) * LANES + l]
        b20, b21, b22 = p[(ROW_B + 3) * LANES + l], p[(ROW_B + 4) * LANES + l], p[(ROW_B + 5) * LANES + l]
        b30, b31, b32 = p[(ROW_B + 6) * LANES + l], p[(ROW_B + 7) * LANES + l], p[(ROW_B + 8) * LANES + l]
        e1x, e1y, e1z = s[0 * LANES + l], s[1 * LANES + l], s[2 * LANES + l]
        e2x, e2y, e2z = s[3 * LANES + l], s[4 * LANES + l], s[5 * LANES + l]
        e3x, e3y, e3z = s[6 * LANES + l], s[7 * LANES + l], s[8 * LANES + l]
        F = (e1x * b10 + e2x * b20 + e3x * b30, e1x * b11 + e2x * b21 + e3x * b31, e1x * b12 + e2x * b22 + e3x * b32,
             e1y * b10 + e2y * b20 + e3y * b30, e1y * b11 + e2y * b21 + e3y * b31, e1y * b12 + e2y * b22 + e3y * b32,
             e1z * b10 + e2z * b20 + e3z * b30, e1z * b11 + e2z * b21 + e3z * b31, e1z * b12 + e2z * b22 + e3z * b32)
        psi, P = _energy_piola_root(code, F, p[ROW_MU * LANES + l], p[ROW_LAM * LANES + l], p[ROW_ETA * LANES + l],
                                    p[(ROW_FIBRE + 0) * LANES + l], p[(ROW_FIBRE + 1) * LANES + l],
                                    p[(ROW_FIBRE + 2) * LANES + l], True)
        if prony:  # P^ = a P - F Gamma, Psi^ = a Psi - g (sim.ebm_kernels._relaxed)
            G = (r[(ROW_GAMMA + 0) * LANES + l], r[(ROW_GAMMA + 1) * LANES + l], r[(ROW_GAMMA + 2) * LANES + l],
                 r[(ROW_GAMMA + 3) * LANES + l], r[(ROW_GAMMA + 4) * LANES + l], r[(ROW_GAMMA + 5) * LANES + l],
                 r[(ROW_GAMMA + 6) * LANES + l], r[(ROW_GAMMA + 7) * LANES + l], r[(ROW_GAMMA + 8) * LANES + l])
            f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
            P = (relax_a * P[0] - (f00 * G[0] + f01 * G[3] + f02 * G[6]),
                 relax_a * P[1] - (f00 * G[1] + f01 * G[4] + f02 * G[7]),
                 relax_a * P[2] - (f00 * G[2] + f01 * G[5] + f02 * G[8]),
                 relax_a * P[3] - (f10 * G[0] + f11 * G[3] + f12 * G[6]),
                 relax_a * P[4] - (f10 * G[1] + f11 * G[4] + f12 * G[7]),
                 relax_a * P[5] - (f10 * G[2] + f11 * G[5] + f12 * G[8]),
                 relax_a * P[6] - (f20 * G[0] + f21 * G[3] + f22 * G[6]),
                 relax_a * P[7] - (f20 * G[1] + f21 * G[4] + f22 * G[7]),
                 relax_a * P[8] - (f20 * G[2] + f21 * G[5] + f22 * G[8]))
            psi = relax_a * psi - r[ROW_G * LANES + l]
        if forces:
            V = p[ROW_VOLUME * LANES + l]
            P = (V * P[0], V * P[1], V * P[2], V * P[3], V * P[4], V * P[5], V * P[6], V * P[7], V * P[8])
            psi = V * psi
        # node gradients g_k = P b_k (rows of P times the rows of Dm^-1), g_0 = -(g_1 + g_2 + g_3)
        g1x = P[0] * b10 + P[1] * b11 + P[2] * b12
        g1y = P[3] * b10 + P[4] * b11 + P[5] * b12
        g1z = P[6] * b10 + P[7] * b11 + P[8] * b12
        g2x = P[0] * b20 + P[1] * b21 + P[2] * b22
        g2y = P[3] * b20 + P[4] * b21 + P[5] * b22
        g2z = P[6] * b20 + P[7] * b21 + P[8] * b22
        g3x = P[0] * b30 + P[1] * b31 + P[2] * b32
        g3y = P[3] * b30 + P[4] * b31 + P[5] * b32
        g3z = P[6] * b30 + P[7] * b31 + P[8] * b32
        g0x = -(g1x + g2x + g3x)
        g0y = -(g1y + g2y + g3y)
        g0z = -(g1z + g2z + g3z)
        if forces:
            s0 = s1 = s2 = s3 = 1.0
            out[OUT_W * LANES + l] = psi
            out[OUT_FF * LANES + l] = (F[0] * F[0] + F[1] * F[1] + F[2] * F[2] + F[3] * F[3] + F[4] * F[4]
                                       + F[5] * F[5] + F[6] * F[6] + F[7] * F[7] + F[8] * F[8])
        else:
            w0, w1 = p[(ROW_W + 0) * LANES + l], p[(ROW_W + 1) * LANES + l]
            w2, w3 = p[(ROW_W + 2) * LANES + l], p[(ROW_W + 3) * LANES + l]
            denom = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
                     + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
            ok = denom > 1e-300
            lam_k = psi / (denom if ok else 1.0)  # 5.7 (volume cancelled)
            nan = denom != denom
            bad += 1 if nan else 0
            lam_k = lam_k if ok else (np.nan if nan else 0.0)
            # 5.8: dx_k = -w_k lambda g_k
            s0, s1, s2, s3 = -(w0 * lam_k), -(w1 * lam_k), -(w2 * lam_k), -(w3 * lam_k)
        out[(OUT_D + 0) * LANES + l] = s0 * g0x
        out[(OUT_D + 1) * LANES + l] = s0 * g0y
        out[(OUT_D + 2) * LANES + l] = s0 * g0z
        out[(OUT_D + 3) * LANES + l] = s1 * g1x
        out[(OUT_D + 4) * LANES + l] = s1 * g1y
        out[(OUT_D + 5) * LANES + l] = s1 * g1z
        out[(OUT_D + 6) * LANES + l] = s2 * g2x
        out[(OUT_D + 7) * LANES + l] = s2 * g2y
        out[(OUT_D + 8) * LANES + l] = s2 * g2z
        out[(OUT_D + 9) * LANES + l] = s3 * g3x
        out[(OUT_D + 10) * LANES + l] = s3 * g3y
        out[(OUT_D + 11) * LANES + l] = s3 * g3z
    return bad


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _sweep_block(code, prony, forces, p, r, s, out, relax_a, lanes):
    """One block's lane loop, one compiled copy per (material, Prony, forces): the branches on the constants
    are resolved before the vectoriser runs. fastmath: only "contract"."""
    if forces:
        if prony:
            if code == NEO_HOOKEAN:
                return _lanes(NEO_HOOKEAN, True, True, p, r, s, out, relax_a, lanes)
            if code == ANISOTROPIC_NEO_HOOKEAN:
                return _lanes(ANISOTROPIC_NEO_HOOKEAN, True, True, p, r, s, out, relax_a, lanes)
            if code == STABLE_NEO_HOOKEAN:
                return _lanes(STABLE_NEO_HOOKEAN, True, True, p, r, s, out, relax_a, lanes)
            return _lanes(STVK, True, True, p, r, s, out, relax_a, lanes)
        if code == NEO_HOOKEAN:
            return _lanes(NEO_HOOKEAN, False, True, p, r, s, out, relax_a, lanes)
        if code == ANISOTROPIC_NEO_HOOKEAN:
            return _lanes(ANISOTROPIC_NEO_HOOKEAN, False, True, p, r, s, out, relax_a, lanes)
        if code == STABLE_NEO_HOOKEAN:
            return _lanes(STABLE_NEO_HOOKEAN, False, True, p, r, s, out, relax_a, lanes)
        return _lanes(STVK, False, True, p, r, s, out, relax_a, lanes)
    if prony:
        if code == NEO_HOOKEAN:
            return _lanes(NEO_HOOKEAN, True, False, p, r, s, out, relax_a, lanes)
        if code == ANISOTROPIC_NEO_HOOKEAN:
            return _lanes(ANISOTROPIC_NEO_HOOKEAN, True, False, p, r, s, out, relax_a, lanes)
        if code == STABLE_NEO_HOOKEAN:
            return _lanes(STABLE_NEO_HOOKEAN, True, False, p, r, s, out, relax_a, lanes)
        return _lanes(STVK, True, False, p, r, s, out, relax_a, lanes)
    if code == NEO_HOOKEAN:
        return _lanes(NEO_HOOKEAN, False, False, p, r, s, out, relax_a, lanes)
    if code == ANISOTROPIC_NEO_HOOKEAN:
        return _lanes(ANISOTROPIC_NEO_HOOKEAN, False, False, p, r, s, out, relax_a, lanes)
    if code == STABLE_NEO_HOOKEAN:
        return _lanes(STABLE_NEO_HOOKEAN, False, False, p, r, s, out, relax_a, lanes)
    return _lanes(STVK, False, False, p, r, s, out, relax_a, lanes)


@njit(cache=True)
def _all_blocks(xf, node_index, params, relax, out, scratch, code, prony, forces, relax_a):
    """The lane loop over every block; returns the number of NaN multipliers (sweep only)."""
    bad = 0
    lanes = scratch.shape[0] // 9  # LANES, as a run-time value
    for blk in range(node_index.shape[0]):
        _gather(xf, node_index[blk], scratch)
        bad += _sweep_block(code, prony, forces, params[blk], relax[blk if prony else 0], scratch, out[blk],
                            relax_a, lanes)
    return bad


@njit(cache=True)
def sweeps(x, node_index, params, relax, out, scratch, free_nodes, free_start, free_slot, node_scale, code, prony,
           relax_a, iterations):
    """``iterations`` Jacobi sweeps (5.7-5.9, 5.14) on ``x`` (n, 3) in place: per sweep every block's
    increments into ``out``, then every free node's sum over its incidences (in tet order), scaled by
    ``node_scale`` and applied. Kinematic nodes have w = 0, so no increment. Returns the number of sweeps
    done: fewer than ``iterations`` when a multiplier was NaN or a position non-finite."""
    xf = x.reshape(x.size)
    of = out.reshape(out.size)
    for it in range(iterations):
        bad = _all_blocks(xf, node_index, params, relax, out, scratch, code, prony, False, relax_a)
        finite = bad == 0
        for q in range(free_nodes.shape[0]):
            ax = 0.0
            ay = 0.0
            az = 0.0
            for k in range(free_start[q], free_start[q + 1]):
                o = free_slot[k]
                ax += of[o]
                ay += of[o + _L]
                az += of[o + _L2]
            i = free_nodes[q]
            sc = node_scale[i]
            vx = x[i, 0] + ax * sc
            vy = x[i, 1] + ay * sc
            vz = x[i, 2] + az * sc
            x[i, 0] = vx
            x[i, 1] = vy
            x[i, 2] = vz
            if not (abs(vx) < np.inf and abs(vy) < np.inf and abs(vz) < np.inf):
                finite = False
        if not finite:
            return it
    return iterations


@njit(cache=True)
def step(x_prev, v_prev, x, v, t, h, X, f_ext, w, kin_nodes, kin_group, kin_displacement, group_t0, group_t1,
         node_index, params, relax, out, scratch, free_nodes, free_start, free_slot, kin_start, kin_slot, node_scale,
         last_load, n_tets, code, prony, relax_a, iterations):
    """One EBM step of length ``h`` ending at time ``t``, from (``x_prev``, ``v_prev``) into (``x``, ``v``):

    1. prediction 5.13, ``x = x_prev + h (v_prev + h f_ext w)``, kinematic nodes at their targets
       (``X + fraction(t) displacement`` of their prescribed group, the group ramped linearly from
       ``group_t0`` to ``group_t1``; ``kin_group`` -1: fixed at X);
    2. :func:`sweeps`;
    3. velocities ``v = (x - x_prev) / h`` (5.15, our reading);
    4. energy accounting at the new positions: the strain energy, the largest stretch ``|F|_F / sqrt 3`` and
       the work increment of the loads (external forces, plus the reactions ``-f_int`` at kinematic nodes),
       trapezoidal with ``last_load`` (updated in place).

    Returns ``(sweeps done, work increment [J], strain energy [J], largest stretch)``."""
    n = x.shape[0]
    for i in range(n):
        for d in range(3):
            x[i, d] = x_prev[i, d] + h * (v_prev[i, d] + h * f_ext[i, d] * w[i])
    for q in range(kin_nodes.shape[0]):
        i = kin_nodes[q]
        grp = kin_group[q]
        if grp < 0:
            for d in range(3):
                x[i, d] = X[i, d]
        else:
            t0 = group_t0[grp]
            t1 = group_t1[grp]
            if t1 <= t0:
                frac = 1.0 if t >= t0 else 0.0
            else:
                frac = min(max((t - t0) / (t1 - t0), 0.0), 1.0)
            for d in range(3):
                x[i, d] = X[i, d] + frac * kin_displacement[q, d]
    done = sweeps(x, node_index, params, relax, out, scratch, free_nodes, free_start, free_slot, node_scale, code,
                  prony, relax_a, iterations)
    for i in range(n):
        for d in range(3):
            v[i, d] = (x[i, d] - x_prev[i, d]) / h
    if done < iterations:
        return done, 0.0, 0.0, 0.0
    # accounting: dW/dx, W and |F|^2 per tet at the new positions
    xf = x.reshape(x.size)
    _all_blocks(xf, node_index, params, relax, out, scratch, code, prony, True, relax_a)
    of = out.reshape(out.size)
    strain = 0.0
    FF = 0.0
    for t in range(n_tets):
        base = (t // LANES) * (N_OUT * LANES) + t % LANES
        strain += of[base + OUT_W * LANES]
        FF = max(FF, of[base + OUT_FF * LANES])
    # loads: f_ext everywhere, plus the reaction -f_int = sum dW/dx at kinematic nodes
    work = 0.0
    q = 0
    for i in range(n):
        lx = f_ext[i, 0]
        ly = f_ext[i, 1]
        lz = f_ext[i, 2]
        if q < kin_nodes.shape[0] and kin_nodes[q] == i:
            fx = 0.0
            fy = 0.0
            fz = 0.0
            for k in range(kin_start[q], kin_start[q + 1]):
                o = kin_slot[k]
                fx -= of[o]
                fy -= of[o + _L]
                fz -= of[o + _L2]
            lx = -fx + lx
            ly = -fy + ly
            lz = -fz + lz
            q += 1
        work += ((lx + last_load[i, 0]) * (x[i, 0] - x_prev[i, 0]) + (ly + last_load[i, 1]) * (x[i, 1] - x_prev[i, 1])
                 + (lz + last_load[i, 2]) * (x[i, 2] - x_prev[i, 2]))
        last_load[i, 0] = lx
        last_load[i, 1] = ly
        last_load[i, 2] = lz
    return done, 0.5 * work, strain, np.sqrt(FF / 3.0)
