"""Blocked EBM kernels (``kernel = "blocked"``, the default of ``sim.integrators.ebm``): the block layout and the
float64 Jacobi sweeps (5.7-5.9 / 5.14) with the per-tet work vectorised across tets. The whole substep in one
compiled call is ``sim.integrators.ebm.blocked_step``; the float32 lane loops are ``blocked_f32``, the versions on
several threads ``blocked_parallel``.

The energy balance is a Jacobi update (every tet sees the positions of the previous sweep, the increments
are summed per node), so all tets of a sweep are independent. Tets are taken in blocks of ``LANES``
consecutive tets; every per-tet quantity is stored in rows of ``LANES`` values (structure of arrays):

- ``corners`` holds, per tet, the positions of its four nodes (12 rows), written by the node pass;
- a branch-free loop over the lanes of a block (energy, Piola stress, node gradients, multiplier,
  increments; LLVM vectorises it with 8-wide zmm FMAs on AVX-512: ``variant(code, prony)[1].inspect_asm()``)
  reads them and writes the tet's four increments without the inverse mass (12 rows) to ``out``;
- the node pass, for every free node, sums its increments over its incidences in tet order (the scalar
  kernel's summation order; no scatter), applies ``x_i += w_i dx_i / n_i`` (update = "average") and writes
  the new position to the node's corner slots, so no gather by node index is needed in the lane loop.

Per lane, with ``g_k = P b_k`` (``b_k`` the rows of Dm^-1, ``b_0 = -(b_1 + b_2 + b_3)``):
``lambda' = Psi / sum_j w_j |g_j|^2`` and ``dx_k = -w_k lambda' g_k``: 5.7-5.8 with the volume cancelled
(``W = V Psi``, ``dW/dx_k = V g_k``: the multiplier scales as 1/V, the increment not at all). A vanishing
denominator (``<= 1e-300``: a tet at rest to the last bit) gives no increment; a NaN one (an inverted tet of a
split model, where J^(-2/3) is undefined) fails the sweep, as in the scalar kernel.

The split models (Zhang 5.35, 5.37) are evaluated from the displacement gradient ``H = F - I`` as in
``sim.constitutive.kernels`` (their energies keep their relative accuracy at rest), with fewer operations
(:func:`_split_model`, a vectorisable variant of ``energy_piola`` kept for speed: docs/ebm.md#how-fast-and-why):
``cof H`` gives ``I2(H) = tr cof H`` and ``det H = H_0. cof H_0.``, and ``cof F = (1 + tr H) I - H^T + cof H``;
J^(-1/3) = y comes from ``sim.constitutive.kernels.inverse_cube_root`` (no libm call, so the loop vectorises),
``1/J = y^3``, and ``J^(-2/3) - 1 = N / Q`` with ``N = -j y^3 (y + 1)``, ``Q = y^2 + y + 1`` (no cancellation).
``Psi`` is kept as a fraction ``num / den`` (``den = Q``, or ``Q^2`` with the fibre), so that a sweep divides
once per tet: ``lambda' = num / (den sum_j w_j |g_j|^2)``.

Kernels use no ``fastmath``, not even "contract" (fused multiply-adds made a run that compiled the kernels step
differently from one that loaded them from numba's cache: docs/xpbd.md, "Determinism"), and ``error_model="numpy"``
(no division checks: divisors are guarded by selects). Results equal the scalar kernel's to rounding
(tested to 1e-10 after several steps: tests/sim/integrators/ebm/test_kernels.py).
"""
from __future__ import annotations

import functools

import numpy as np
from numba import literally, njit, types
from numba.core.errors import TypingError
from numba.extending import overload

from sim.constitutive.kernels import (ANISOTROPIC_NEO_HOOKEAN, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK, energy_piola_root,
                                      inverse_cube_root)

LANES = 16  # tets per block (two zmm registers of float64 per quantity)
# rows of a block's parameter array (each row holds LANES values)
ROW_B = 0  # 9 rows: b_k[c] = Dm_inv[k - 1, c] at ROW_B + 3 (k - 1) + c, k = 1..3
ROW_W = 9  # 4 rows: inverse masses w_0..w_3 of the tet's nodes
ROW_MU = 13
ROW_LAM = 14  # lambda (Lame)
ROW_KAPPA = 15  # bulk modulus lambda + 2 mu / 3 of the split models
ROW_ETA = 16
ROW_FIBRE = 17  # 3 rows: a0
ROW_FIBRE_NORM = 20  # |a0|^2 - 1
ROW_VOLUME = 21
N_ROWS = 22
# rows of the Prony array (rebuilt each step): Gamma (9, row-major), g
ROW_GAMMA = 0
ROW_G = 9
N_RELAX = 10
# rows of the per-tet output: dx_k (or dW/dx_k for the forces) at 3 k + c, then W and |F|^2 (forces only).
# The corner positions use the same layout (rows 0..11, two unused), so an incidence has one offset in both.
OUT_D = 0
OUT_W = 12
OUT_FF = 13
N_OUT = 14

OFF_Y = np.uint32(1)  # unsigned offsets keep indices unsigned: no negative-index wraparound code
OFF_Z = np.uint32(2)
OFF_L = np.uint32(LANES)
OFF_L2 = np.uint32(2 * LANES)


def pack(tets, Dm_inv, volume, mu, lam, eta, fibre, w, n_nodes, free):
    """Block layout of the per-tet data (tet t is lane t % LANES of block t // LANES; padding lanes of the
    last block repeat tet 0, so their arithmetic stays finite, and nothing reads their output).

    Returns ``(node_index (nb, 4 LANES) uint32 = 3 x node, params (nb, N_ROWS LANES), free_nodes (nf,) int64,
    free_start (nf + 1,) int64, free_slot uint32, kin_nodes, kin_start, kin_slot)``: ``*_slot[p]`` is the
    offset in a flattened ``(nb, N_OUT LANES)`` output of coordinate
    x of one (tet, corner) incident on the node, the node's incidences in increasing tet order; the same offset
    in the corner positions."""
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
    params[blk, ROW_KAPPA, lane] = lam[order] + 2.0 * mu[order] / 3.0  # as sim.integrators.ebm.kernels
    params[blk, ROW_ETA, lane] = eta[order]
    a0 = fibre[order]
    params[blk, ROW_FIBRE:ROW_FIBRE + 3, lane] = a0
    params[blk, ROW_FIBRE_NORM, lane] = a0[:, 0] * a0[:, 0] + a0[:, 1] * a0[:, 1] + a0[:, 2] * a0[:, 2] - 1.0
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

    return (node_index.reshape(nb, 4 * LANES), params.reshape(nb, N_ROWS * LANES), *csr(np.flatnonzero(free)),
            *csr(np.flatnonzero(~free)))


def pack_relaxation(Gamma, g, n_blocks):
    """Prony coefficients of a step (``Gamma (m, 3, 3)``, ``g (m,)``) in the block layout (padding: tet 0)."""
    m = Gamma.shape[0]
    order = np.concatenate([np.arange(m), np.zeros(n_blocks * LANES - m, np.int64)])
    relax = np.empty((n_blocks, N_RELAX, LANES))
    relax[:, ROW_GAMMA:ROW_GAMMA + 9, :] = Gamma[order].reshape(n_blocks, LANES, 9).transpose(0, 2, 1)
    relax[:, ROW_G, :] = g[order].reshape(n_blocks, LANES)
    return relax.reshape(n_blocks, N_RELAX * LANES)


@njit(cache=True)
def load_corners(x, node_index, corners):
    """Every tet's node positions into ``corners`` (nb, N_OUT LANES; rows 3 k + c), padding lanes included."""
    xf = x.reshape(x.size)
    for blk in range(node_index.shape[0]):
        for k in range(4):
            for l in range(LANES):
                i = node_index[blk, k * LANES + l]
                corners[blk, (3 * k) * LANES + l] = xf[i]
                corners[blk, (3 * k + 1) * LANES + l] = xf[i + OFF_Y]
                corners[blk, (3 * k + 2) * LANES + l] = xf[i + OFF_Z]


@njit(cache=True, inline="always")
def _split_model(F, mu, kappa, eta, ax, ay, az, a0_norm, fibre):
    """Zhang 5.35 (+ 5.37 when ``fibre``): ``(num, den, P)`` with ``Psi = num / den``, from H = F - I (module
    docstring); NaN for J <= 0. The same quantities as ``sim.constitutive.kernels.energy_piola`` up to rounding, in a
    branch-free form whose lane loop vectorises: kept for speed (docs/ebm.md#how-fast-and-why)."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    h00, h11, h22 = f00 - 1.0, f11 - 1.0, f22 - 1.0
    # cof H (the off-diagonal entries of H are F's)
    c00 = h11 * h22 - f21 * f12
    c01 = f12 * f20 - h22 * f10
    c02 = f10 * f21 - f20 * h11
    c10 = f21 * f02 - f01 * h22
    c11 = h22 * h00 - f02 * f20
    c12 = f20 * f01 - h00 * f21
    c20 = f01 * f12 - h11 * f02
    c21 = f02 * f10 - f12 * h00
    c22 = h00 * h11 - f10 * f01
    tr = h00 + h11 + h22
    I2 = c00 + c11 + c22
    detH = h00 * c00 + f01 * c01 + f02 * c02
    j = tr + I2 + detH  # J - 1
    J = 1.0 + j
    HH = (h00 * h00 + f01 * f01 + f02 * f02 + f10 * f10 + h11 * h11 + f12 * f12 + f20 * f20 + f21 * f21
          + h22 * h22)
    d = 2.0 * tr + HH  # I1 - 3
    # cof F = (1 + tr H) I - H^T + cof H
    C00 = 1.0 + (h11 + h22) + c00
    C11 = 1.0 + (h00 + h22) + c11
    C22 = 1.0 + (h00 + h11) + c22
    C01, C02, C12 = c01 - f10, c02 - f20, c12 - f21
    C10, C20, C21 = c10 - f01, c20 - f02, c21 - f12
    y = inverse_cube_root(J)  # J^(-1/3), NaN for J <= 0
    y2 = y * y
    inv_J = y2 * y
    Q = y2 + y + 1.0
    N = -j * inv_J * (y + 1.0)  # J^(-2/3) - 1 = N / Q
    a = mu * y2
    b = a * (3.0 + d) * (1.0 / 3.0) * inv_J
    s = kappa * j - b  # P = mu J^(-2/3) F + (kappa (J - 1) - mu J^(-2/3) I1 / (3 J)) cof F
    # Psi Q = mu/2 ((3 + d) N + d Q) + kappa/2 j^2 Q   (Psi = mu/2 (3 m + d + m d) + kappa/2 j^2, m = N / Q)
    num = 0.5 * mu * ((3.0 + d) * N + d * Q) + 0.5 * kappa * j * j * Q
    if fibre:
        fa0 = f00 * ax + f01 * ay + f02 * az
        fa1 = f10 * ax + f11 * ay + f12 * az
        fa2 = f20 * ax + f21 * ay + f22 * az
        I4 = fa0 * fa0 + fa1 * fa1 + fa2 * fa2
        # I4 - 1 = 2 a0.H a0 + |H a0|^2 + (|a0|^2 - 1); (I4bar - 1) Q = (1 + q) N + q Q, without cancellation
        ha0, ha1, ha2 = fa0 - ax, fa1 - ay, fa2 - az
        q = 2.0 * (ax * ha0 + ay * ha1 + az * ha2) + ha0 * ha0 + ha1 * ha1 + ha2 * ha2 + a0_norm
        D = (1.0 + q) * N + q * Q
        num = num * Q + 0.5 * eta * D * D
        den = Q * Q
        e = eta * (y2 * I4 - 1.0) * y2  # P_f = e (2 (F a0) a0^T - 2/3 I4 F^-T)
        s = s - e * (2.0 / 3.0) * I4 * inv_J
        e2 = 2.0 * e
        u0, u1, u2 = e2 * fa0, e2 * fa1, e2 * fa2
        P = (a * f00 + s * C00 + u0 * ax, a * f01 + s * C01 + u0 * ay, a * f02 + s * C02 + u0 * az,
             a * f10 + s * C10 + u1 * ax, a * f11 + s * C11 + u1 * ay, a * f12 + s * C12 + u1 * az,
             a * f20 + s * C20 + u2 * ax, a * f21 + s * C21 + u2 * ay, a * f22 + s * C22 + u2 * az)
        return num, den, P
    P = (a * f00 + s * C00, a * f01 + s * C01, a * f02 + s * C02,
         a * f10 + s * C10, a * f11 + s * C11, a * f12 + s * C12,
         a * f20 + s * C20, a * f21 + s * C21, a * f22 + s * C22)
    return num, Q, P


@functools.lru_cache(maxsize=None)
def _lane_loop(code, prony, forces):
    """The branch-free loop over the lanes of one block for one (material ``code``, ``prony``, ``forces``), made
    per variant so that the three are constants in its own IR: numba drops the branches of the other variants
    before it inlines the material functions, and so copies only this variant's code into the caller
    (docs/design.md, "Compile time"). ``c``: the block's corner positions. Sweep (``forces`` False): the
    increments ``-w_k lambda' g_k`` into ``out``; returns the number of NaN multipliers. Forces:
    ``dW/dx_k = V P b_k``, ``W = V Psi`` and ``|F|^2`` into ``out``."""

    @njit(inline="always")
    def lanes_of_block(c, p, r, out, blk, rblk, relax_a, lanes):
        bad = 0
        for l in range(lanes):  # a run-time trip count: with a constant one LLVM unrolls the loop instead
            b10, b11, b12 = p[blk, (ROW_B + 0) * LANES + l], p[blk, (ROW_B + 1) * LANES + l], p[blk, (ROW_B + 2) * LANES + l]
            b20, b21, b22 = p[blk, (ROW_B + 3) * LANES + l], p[blk, (ROW_B + 4) * LANES + l], p[blk, (ROW_B + 5) * LANES + l]
            b30, b31, b32 = p[blk, (ROW_B + 6) * LANES + l], p[blk, (ROW_B + 7) * LANES + l], p[blk, (ROW_B + 8) * LANES + l]
            x0, y0, z0 = c[blk, 0 * LANES + l], c[blk, 1 * LANES + l], c[blk, 2 * LANES + l]
            e1x, e1y, e1z = c[blk, 3 * LANES + l] - x0, c[blk, 4 * LANES + l] - y0, c[blk, 5 * LANES + l] - z0
            e2x, e2y, e2z = c[blk, 6 * LANES + l] - x0, c[blk, 7 * LANES + l] - y0, c[blk, 8 * LANES + l] - z0
            e3x, e3y, e3z = c[blk, 9 * LANES + l] - x0, c[blk, 10 * LANES + l] - y0, c[blk, 11 * LANES + l] - z0
            F = (e1x * b10 + e2x * b20 + e3x * b30, e1x * b11 + e2x * b21 + e3x * b31, e1x * b12 + e2x * b22 + e3x * b32,
                 e1y * b10 + e2y * b20 + e3y * b30, e1y * b11 + e2y * b21 + e3y * b31, e1y * b12 + e2y * b22 + e3y * b32,
                 e1z * b10 + e2z * b20 + e3z * b30, e1z * b11 + e2z * b21 + e3z * b31, e1z * b12 + e2z * b22 + e3z * b32)
            mu = p[blk, ROW_MU * LANES + l]
            if code == NEO_HOOKEAN or code == ANISOTROPIC_NEO_HOOKEAN:
                num, den, P = _split_model(F, mu, p[blk, ROW_KAPPA * LANES + l], p[blk, ROW_ETA * LANES + l],
                                           p[blk, (ROW_FIBRE + 0) * LANES + l], p[blk, (ROW_FIBRE + 1) * LANES + l],
                                           p[blk, (ROW_FIBRE + 2) * LANES + l], p[blk, ROW_FIBRE_NORM * LANES + l],
                                           code == ANISOTROPIC_NEO_HOOKEAN)
            else:
                num, P = energy_piola_root(code, F, mu, p[blk, ROW_LAM * LANES + l], 0.0, 0.0, 0.0, 0.0, True)
                den = 1.0
            if prony:  # P^ = a P - F Gamma, Psi^ = a Psi - g (sim.constitutive.force_kernels._relaxed)
                G = (r[rblk, (ROW_GAMMA + 0) * LANES + l], r[rblk, (ROW_GAMMA + 1) * LANES + l], r[rblk, (ROW_GAMMA + 2) * LANES + l],
                     r[rblk, (ROW_GAMMA + 3) * LANES + l], r[rblk, (ROW_GAMMA + 4) * LANES + l], r[rblk, (ROW_GAMMA + 5) * LANES + l],
                     r[rblk, (ROW_GAMMA + 6) * LANES + l], r[rblk, (ROW_GAMMA + 7) * LANES + l], r[rblk, (ROW_GAMMA + 8) * LANES + l])
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
                num = relax_a * num - r[rblk, ROW_G * LANES + l] * den
            if forces:
                V = p[blk, ROW_VOLUME * LANES + l]
                P = (V * P[0], V * P[1], V * P[2], V * P[3], V * P[4], V * P[5], V * P[6], V * P[7], V * P[8])
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
                out[blk, OUT_W * LANES + l] = p[blk, ROW_VOLUME * LANES + l] * (num / den)
                out[blk, OUT_FF * LANES + l] = (F[0] * F[0] + F[1] * F[1] + F[2] * F[2] + F[3] * F[3] + F[4] * F[4]
                                           + F[5] * F[5] + F[6] * F[6] + F[7] * F[7] + F[8] * F[8])
            else:
                w0, w1 = p[blk, (ROW_W + 0) * LANES + l], p[blk, (ROW_W + 1) * LANES + l]
                w2, w3 = p[blk, (ROW_W + 2) * LANES + l], p[blk, (ROW_W + 3) * LANES + l]
                denom = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
                         + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
                ok = denom > 1e-300
                lam_k = num / (den * denom if ok else 1.0)  # 5.7 (volume cancelled)
                nan = denom != denom
                bad += 1 if nan else 0
                lam_k = lam_k if ok else (np.nan if nan else 0.0)
                # 5.8: dx_k = -w_k lambda g_k; the node pass multiplies by w_k (a node's inverse mass, with its scale)
                s0 = s1 = s2 = s3 = -lam_k
            out[blk, (OUT_D + 0) * LANES + l] = s0 * g0x
            out[blk, (OUT_D + 1) * LANES + l] = s0 * g0y
            out[blk, (OUT_D + 2) * LANES + l] = s0 * g0z
            out[blk, (OUT_D + 3) * LANES + l] = s1 * g1x
            out[blk, (OUT_D + 4) * LANES + l] = s1 * g1y
            out[blk, (OUT_D + 5) * LANES + l] = s1 * g1z
            out[blk, (OUT_D + 6) * LANES + l] = s2 * g2x
            out[blk, (OUT_D + 7) * LANES + l] = s2 * g2y
            out[blk, (OUT_D + 8) * LANES + l] = s2 * g2z
            out[blk, (OUT_D + 9) * LANES + l] = s3 * g3x
            out[blk, (OUT_D + 10) * LANES + l] = s3 * g3y
            out[blk, (OUT_D + 11) * LANES + l] = s3 * g3z
        return bad

    return lanes_of_block


def all_blocks(corners, params, relax, out, code, prony, forces, relax_a, first, last):
    """The lane loops over blocks ``first:last`` for one (material ``code``, ``prony``, ``forces``); returns the
    number of NaN multipliers (sweep only). Compiled code only: ``code``, ``prony`` and ``forces`` must be compile-time
    constants (literals) at the call, so that a caller compiles the one variant it uses (see the overload)."""
    raise NotImplementedError("sim.integrators.ebm.blocked.all_blocks runs in compiled code only")


@overload(all_blocks, prefer_literal=True, jit_options={"error_model": "numpy"})
def _all_blocks_variant(corners, params, relax, out, code, prony, forces, relax_a, first, last):
    """One implementation per (material, Prony, forces), the three as literal types: the branches on them are
    resolved before the vectoriser runs, and a run compiles only the lane loops of the variants it calls (one
    function with all 16 inlined loops compiled far too slowly: docs/ebm.md#how-fast-and-why).
    No fastmath (docs/xpbd.md, "Determinism")."""
    if not all(isinstance(a, types.Literal) for a in (code, prony, forces)):
        return None  # numba retries with the arguments as literals (prefer_literal)
    c, pr, fo = int(code.literal_value), bool(prony.literal_value), bool(forces.literal_value)
    if c not in (NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK):
        raise TypingError(f"sim.integrators.ebm.blocked: no blocked kernel for material code {c}")

    lanes_of_block = _lane_loop(c, pr, fo)

    def impl(corners, params, relax, out, code, prony, forces, relax_a, first, last):
        lanes = corners.shape[1] // N_OUT  # LANES, as a run-time value
        bad = 0
        for blk in range(first, last):  # the lane loop inlined: no call per block
            bad += lanes_of_block(corners, params, relax, out, blk, blk if pr else 0, relax_a, lanes)
        return bad

    return impl


@njit(cache=True)
def sweeps(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale, code, prony,
           relax_a, iterations):
    """``iterations`` Jacobi sweeps (5.7-5.9, 5.14) on ``x`` (n, 3) in place: per sweep every block's
    increments into ``out``, then every free node's sum over its incidences (in tet order), scaled by
    ``node_scale``, applied to ``x`` and copied to its corner slots. Kinematic nodes have w = 0, so no
    increment. Returns the number of sweeps done: fewer than ``iterations`` when a multiplier was NaN or a
    position non-finite. ``corners`` holds the final positions on return. ``code`` and ``prony`` are compiled
    as literals: one specialisation per (material, Prony) in use."""
    literally(code)
    literally(prony)
    load_corners(x, node_index, corners)
    of = out.reshape(out.size)
    cf = corners.reshape(corners.size)
    for it in range(iterations):
        bad = all_blocks(corners, params, relax, out, code, prony, False, relax_a, 0, corners.shape[0])
        finite = bad == 0
        if not node_range(x, of, cf, free_nodes, free_start, free_slot, node_scale, 0, free_nodes.shape[0]):
            finite = False
        if not finite:
            return it
    return iterations


@njit(cache=True)
def node_range(x, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1):
    """The node pass of :func:`sweeps` for free nodes ``q0:q1`` (the same code: sums in tet order, unrolled by two);
    returns False when a new position is non-finite."""
    finite = True
    for q in range(q0, q1):
        k0 = free_start[q]
        k1 = free_start[q + 1]
        ax = 0.0
        ay = 0.0
        az = 0.0
        k = k0
        while k + 1 < k1:
            o = free_slot[k]
            o2 = free_slot[k + 1]
            ax += of[o]
            ay += of[o + OFF_L]
            az += of[o + OFF_L2]
            ax += of[o2]
            ay += of[o2 + OFF_L]
            az += of[o2 + OFF_L2]
            k += 2
        if k < k1:
            o = free_slot[k]
            ax += of[o]
            ay += of[o + OFF_L]
            az += of[o + OFF_L2]
        i = free_nodes[q]
        sc = node_scale[i]
        vx = x[i, 0] + ax * sc
        vy = x[i, 1] + ay * sc
        vz = x[i, 2] + az * sc
        x[i, 0] = vx
        x[i, 1] = vy
        x[i, 2] = vz
        k = k0
        while k + 1 < k1:
            o = free_slot[k]
            o2 = free_slot[k + 1]
            cf[o] = vx
            cf[o + OFF_L] = vy
            cf[o + OFF_L2] = vz
            cf[o2] = vx
            cf[o2 + OFF_L] = vy
            cf[o2 + OFF_L2] = vz
            k += 2
        if k < k1:
            o = free_slot[k]
            cf[o] = vx
            cf[o + OFF_L] = vy
            cf[o + OFF_L2] = vz
        if not (abs(vx) < np.inf and abs(vy) < np.inf and abs(vz) < np.inf):
            finite = False
    return finite


# Meshes of this many tets or more take the sweeps on several threads when numba has more than one
# (sim.integrators.ebm.blocked_parallel; the crossover is measured in docs/ebm.md#how-fast-and-why).
PARALLEL_MIN_TETS = 1536
