"""Blocked EBM kernels (``kernel = "blocked"``, the default of ``sim.integrators.ebm``): one substep (prediction 5.13,
``iterations`` Jacobi sweeps 5.7-5.9 / 5.14, velocities 5.15 and the energy accounting) in one compiled
call, with the per-tet work vectorised across tets.

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
``sim.integrators.ebm.kernels`` (their energies keep their relative accuracy at rest), with fewer operations:
``cof H`` gives ``I2(H) = tr cof H`` and ``det H = H_0. cof H_0.``, and ``cof F = (1 + tr H) I - H^T + cof H``;
J^(-1/3) = y comes from ``sim.constitutive.kernels.inverse_cube_root`` (no libm call, so the loop vectorises),
``1/J = y^3``, and ``J^(-2/3) - 1 = N / Q`` with ``N = -j y^3 (y + 1)``, ``Q = y^2 + y + 1`` (no cancellation).
``Psi`` is kept as a fraction ``num / den`` (``den = Q``, or ``Q^2`` with the fibre), so that a sweep divides
once per tet: ``lambda' = num / (den sum_j w_j |g_j|^2)``.

``precision = "float32"`` (``sim.integrators.ebm``; split models without Prony): :func:`sweeps_f32` runs the lane loop in
float32 on displacement rows (16 lanes per zmm register), the node pass adds each node's increments two at a time in
float32 and accumulates the pair sums in float64, and the energy accounting runs the float32 lane loop on the same
rows; positions, prediction and velocities stay float64 (end of this module).

Each run compiles only the variants it uses: ``code``, ``prony``, the precision and the threading are literals, and
:func:`variant` returns compiled closures that pass them as constants. Large meshes with more than one numba thread
take :func:`sweeps_parallel` / :func:`sweeps_f32_parallel` (each pass split into one chunk of blocks or free nodes per
thread, bit-identical to the serial sweeps; "two threads" below).

Kernels use ``fastmath={"contract"}`` only (fused multiply-add: one rounding instead of two, nothing else;
no reassociation and no finite-math assumption, so the NaN checks keep working) and ``error_model="numpy"``
(no division checks: divisors are guarded by selects). Results equal the scalar kernel's to rounding
(tested to 1e-10 after several steps: tests/sim/integrators/ebm/test_kernels.py).
"""
from __future__ import annotations

import numpy as np
from numba import literally, njit, prange, types
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

_Y = np.uint32(1)  # unsigned offsets keep indices unsigned: no negative-index wraparound code
_Z = np.uint32(2)
_L = np.uint32(LANES)
_L2 = np.uint32(2 * LANES)


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
                corners[blk, (3 * k + 1) * LANES + l] = xf[i + _Y]
                corners[blk, (3 * k + 2) * LANES + l] = xf[i + _Z]


@njit(cache=True, inline="always")
def _split_model(F, mu, kappa, eta, ax, ay, az, a0_norm, fibre):
    """Zhang 5.35 (+ 5.37 when ``fibre``): ``(num, den, P)`` with ``Psi = num / den``, from H = F - I (module
    docstring); NaN for J <= 0. The same quantities as ``sim.constitutive.kernels.energy_piola`` up to rounding."""
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


@njit(cache=True, inline="always")
def _lanes(code, prony, forces, c, p, r, out, blk, rblk, relax_a, lanes):
    """The branch-free loop over the lanes of one block (``code``, ``prony``, ``forces`` are constants at each
    call site). ``c``: the block's corner positions. Sweep (``forces`` False): the increments
    ``-w_k lambda' g_k`` into ``out``; returns the number of NaN multipliers. Forces: ``dW/dx_k = V P b_k``,
    ``W = V Psi`` and ``|F|^2`` into ``out``."""
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


@njit(cache=True, inline="always")
def _blocks(code, prony, forces, corners, params, relax, out, relax_a, lanes, first, last):
    """The lane loop over blocks ``first:last`` (inlined into one function, so no call per block)."""
    bad = 0
    for blk in range(first, last):
        bad += _lanes(code, prony, forces, corners, params, relax, out, blk, blk if prony else 0, relax_a, lanes)
    return bad


def _all_blocks(corners, params, relax, out, code, prony, forces, relax_a, first, last):
    """The lane loops over blocks ``first:last`` for one (material ``code``, ``prony``, ``forces``); returns the
    number of NaN multipliers (sweep only). Compiled code only: ``code``, ``prony`` and ``forces`` must be compile-time
    constants (literals) at the call, so that a caller compiles the one variant it uses (see the overload)."""
    raise NotImplementedError("sim.integrators.ebm.blocked._all_blocks runs in compiled code only")


@overload(_all_blocks, prefer_literal=True, jit_options={"error_model": "numpy", "fastmath": {"contract"}})
def _all_blocks_variant(corners, params, relax, out, code, prony, forces, relax_a, first, last):
    """One implementation per (material, Prony, forces), the three as literal types: the branches on them are
    resolved before the vectoriser runs, and a run compiles only the lane loops of the variants it calls (the
    earlier single function with all 16 inlined loops took ~7 minutes to compile on first use).
    fastmath: only "contract"."""
    if not all(isinstance(a, types.Literal) for a in (code, prony, forces)):
        return None  # numba retries with the arguments as literals (prefer_literal)
    c, pr, fo = int(code.literal_value), bool(prony.literal_value), bool(forces.literal_value)
    if c not in (NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK):
        raise TypingError(f"sim.integrators.ebm.blocked: no blocked kernel for material code {c}")

    def impl(corners, params, relax, out, code, prony, forces, relax_a, first, last):
        lanes = corners.shape[1] // N_OUT  # LANES, as a run-time value
        return _blocks(c, pr, fo, corners, params, relax, out, relax_a, lanes, first, last)

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
        bad = _all_blocks(corners, params, relax, out, code, prony, False, relax_a, 0, corners.shape[0])
        finite = bad == 0
        if not _node_range(x, of, cf, free_nodes, free_start, free_slot, node_scale, 0, free_nodes.shape[0]):
            finite = False
        if not finite:
            return it
    return iterations


# -- two threads (large meshes; settings-independent: sim.integrators.ebm picks this path when numba has > 1 thread) ------------
# Both passes of a sweep are race-free: a block writes only its own output rows, a node only its own position and its
# own corner slots. So each pass is split into one contiguous chunk per thread (blocks for the lane pass, free nodes for
# the node pass, balanced by incidence count), each chunk running the serial code on its range: every tet and every
# node sum is computed by the same instructions in the same order, and the positions are bit-identical whatever the
# number of threads (tests/sim/integrators/test_threads.py). Two parallel regions per sweep cost a few microseconds, so small
# meshes keep the serial path (``PARALLEL_MIN_TETS``, measured: docs/ebm.md). The parallel functions are compiled
# only when a run takes this path.
PARALLEL_MIN_TETS = 1536


@njit(cache=True, inline="always")
def _chunk_bounds(free_start, n_free, ch, chunks):
    """First and one-past-last free node of chunk ``ch`` of ``chunks``: consecutive nodes with about the same number
    of incidences."""
    total = free_start[n_free]
    q0 = min(np.searchsorted(free_start, total * ch // chunks), n_free)
    q1 = n_free if ch + 1 >= chunks else min(np.searchsorted(free_start, total * (ch + 1) // chunks), n_free)
    return q0, q1


@njit(cache=True)
def _node_range(x, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1):
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
            ay += of[o + _L]
            az += of[o + _L2]
            ax += of[o2]
            ay += of[o2 + _L]
            az += of[o2 + _L2]
            k += 2
        if k < k1:
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
        k = k0
        while k + 1 < k1:
            o = free_slot[k]
            o2 = free_slot[k + 1]
            cf[o] = vx
            cf[o + _L] = vy
            cf[o + _L2] = vz
            cf[o2] = vx
            cf[o2 + _L] = vy
            cf[o2 + _L2] = vz
            k += 2
        if k < k1:
            o = free_slot[k]
            cf[o] = vx
            cf[o + _L] = vy
            cf[o + _L2] = vz
        if not (abs(vx) < np.inf and abs(vy) < np.inf and abs(vz) < np.inf):
            finite = False
    return finite


@njit(cache=True, parallel=True)
def node_pass_parallel(x, out, corners, free_nodes, free_start, free_slot, node_scale, chunks):
    """:func:`sweeps`'s node pass in ``chunks`` ranges of free nodes, one per thread; False when a position is
    non-finite."""
    of = out.reshape(out.size)
    cf = corners.reshape(corners.size)
    n_free = free_nodes.shape[0]
    ok = np.ones(chunks, np.bool_)
    for ch in prange(chunks):
        q0, q1 = _chunk_bounds(free_start, n_free, ch, chunks)
        ok[ch] = _node_range(x, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1)
    return ok.all()


_LANE_PASSES: dict = {}


def lane_pass_parallel(code, prony, forces, single=False):
    """A compiled ``(corners, params, relax, out, relax_a, chunks) -> NaN multipliers`` (float32 with ``single``:
    ``(corners, params, out, chunks) -> 0``) that runs the lane loop of one (material, Prony, forces) over the blocks
    in ``chunks`` contiguous ranges, one per thread (the constants are the closure's, so each compiles on first use
    and is cached on disk, as :func:`variant`)."""
    key = (int(code), bool(prony), bool(forces), bool(single))
    if key not in _LANE_PASSES:
        c, pr, fo = key[:3]
        if single:
            @njit(cache=True, parallel=True)
            def lane_pass(corners, params, out, chunks):
                nb = corners.shape[0]
                for ch in prange(chunks):
                    _all_blocks_f32(corners, params, out, c, fo, nb * ch // chunks, nb * (ch + 1) // chunks)
                return 0
        else:
            @njit(cache=True, parallel=True)
            def lane_pass(corners, params, relax, out, relax_a, chunks):
                nb = corners.shape[0]
                bad = np.zeros(chunks, np.int64)
                for ch in prange(chunks):
                    bad[ch] = _all_blocks(corners, params, relax, out, c, pr, fo, relax_a, nb * ch // chunks,
                                          nb * (ch + 1) // chunks)
                return bad.sum()
        _LANE_PASSES[key] = lane_pass
    return _LANE_PASSES[key]


def _parallel_lanes(corners, params, relax, out, code, prony, forces, relax_a, chunks):
    """:func:`lane_pass_parallel`'s pass for literal (``code``, ``prony``, ``forces``); compiled code only."""
    raise NotImplementedError("sim.integrators.ebm.blocked._parallel_lanes runs in compiled code only")


@overload(_parallel_lanes, prefer_literal=True)
def _parallel_lanes_variant(corners, params, relax, out, code, prony, forces, relax_a, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, prony, forces)):
        return None
    lane_pass = lane_pass_parallel(int(code.literal_value), bool(prony.literal_value), bool(forces.literal_value))

    def impl(corners, params, relax, out, code, prony, forces, relax_a, chunks):
        return lane_pass(corners, params, relax, out, relax_a, chunks)

    return impl


def _parallel_lanes_f32(corners, params, out, code, forces, chunks):
    """:func:`lane_pass_parallel`'s float32 pass for literal (``code``, ``forces``); compiled code only."""
    raise NotImplementedError("sim.integrators.ebm.blocked._parallel_lanes_f32 runs in compiled code only")


@overload(_parallel_lanes_f32, prefer_literal=True)
def _parallel_lanes_f32_variant(corners, params, out, code, forces, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, forces)):
        return None
    lane_pass = lane_pass_parallel(int(code.literal_value), False, bool(forces.literal_value), single=True)

    def impl(corners, params, out, code, forces, chunks):
        return lane_pass(corners, params, out, chunks)

    return impl


@njit(cache=True)
def sweeps_parallel(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale, code,
                    prony, relax_a, iterations, chunks):
    """:func:`sweeps` with each pass split over ``chunks`` threads (bit-identical results)."""
    literally(code)
    literally(prony)
    load_corners(x, node_index, corners)
    for it in range(iterations):
        bad = _parallel_lanes(corners, params, relax, out, code, prony, False, relax_a, chunks)
        finite = node_pass_parallel(x, out, corners, free_nodes, free_start, free_slot, node_scale, chunks)
        if not (finite and bad == 0):
            return it
    return iterations


def _any_sweeps(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
    """:func:`sweeps`, or with ``single`` (a literal) :func:`sweeps_f32`, or with ``parallel`` (a literal) their
    versions on ``chunks`` threads; compiled code only. (A plain ``if single``
    in :func:`step` is not pruned before typing, so the float32 path would be typed for materials it does not
    support.)"""
    raise NotImplementedError("sim.integrators.ebm.blocked._any_sweeps runs in compiled code only")


@overload(_any_sweeps, prefer_literal=True)
def _any_sweeps_variant(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes,
                        free_start, free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, prony, single, parallel)):
        return None
    c, pr = int(code.literal_value), bool(prony.literal_value)
    if bool(single.literal_value) and bool(parallel.literal_value):
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps_f32_parallel(x, X, node_index, params32, out32, corners32, free_nodes, free_start,
                                       free_slot, node_scale, c, iterations, chunks)
    elif bool(single.literal_value):
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps_f32(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                              node_scale, c, iterations)
    elif bool(parallel.literal_value):
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps_parallel(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot,
                                   node_scale, c, pr, relax_a, iterations, chunks)
    else:
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                          c, pr, relax_a, iterations)
    return impl


def _accounting(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                chunks):
    """The energy accounting's lane loop at the positions the sweeps left in the corner rows: ``dW/dx``, ``W`` and
    ``|F|^2`` per tet; returns the flattened output rows (float64, or float32 with ``single``, where it runs the float32
    loop on the displacement rows ``corners32``; with ``parallel``, on ``chunks`` threads). Compiled code only (``code``,
    ``prony``, ``single``, ``parallel`` literals)."""
    raise NotImplementedError("sim.integrators.ebm.blocked._accounting runs in compiled code only")


@overload(_accounting, prefer_literal=True)
def _accounting_variant(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel,
                        relax_a, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, prony, single, parallel)):
        return None
    c, pr = int(code.literal_value), bool(prony.literal_value)
    if bool(single.literal_value) and bool(parallel.literal_value):
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            _parallel_lanes_f32(corners32, params32, out32, c, True, chunks)
            return out32.reshape(out32.size)
    elif bool(single.literal_value):
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            _all_blocks_f32(corners32, params32, out32, c, True, 0, corners32.shape[0])
            return out32.reshape(out32.size)
    elif bool(parallel.literal_value):
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            _parallel_lanes(corners, params, relax, out, c, pr, True, relax_a, chunks)
            return out.reshape(out.size)
    else:
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            _all_blocks(corners, params, relax, out, c, pr, True, relax_a, 0, corners.shape[0])
            return out.reshape(out.size)
    return impl


@njit(cache=True)
def step(x_prev, v_prev, x, v, t, h, X, f_ext, w, kin_nodes, kin_group, kin_displacement, group_t0, group_t1,
         node_index, params, relax, out, corners, free_nodes, free_start, free_slot, kin_start, kin_slot, node_scale,
         last_load, n_tets, params32, out32, corners32, code, prony, single, parallel, relax_a, iterations, chunks):
    """One EBM step of length ``h`` ending at time ``t``, from (``x_prev``, ``v_prev``) into (``x``, ``v``):

    1. prediction 5.13, ``x = x_prev + h (v_prev + h f_ext w)``, kinematic nodes at their targets
       (``X + fraction(t) displacement`` of their prescribed group, the group ramped linearly from
       ``group_t0`` to ``group_t1``; ``kin_group`` -1: fixed at X), as ``Model.kinematic_targets``;
    2. :func:`sweeps`;
    3. velocities ``v = (x - x_prev) / h`` (5.15, our reading);
    4. energy accounting at the new positions: the strain energy, the largest stretch ``|F|_F / sqrt 3`` and
       the work increment of the loads (external forces, plus the reactions ``-f_int`` at kinematic nodes),
       trapezoidal with ``last_load`` (updated in place).

    Returns ``(sweeps done, work increment [J], strain energy [J], largest stretch)``. ``code``, ``prony`` and
    ``single`` are compiled as literals (one specialisation per material and Prony in use). ``single``: the sweeps
    run :func:`sweeps_f32` on ``params32``, ``out32``, ``corners32`` and the accounting's lane loop in float32 on the
    displacement rows the sweeps leave there (positions, prediction, velocities and the sums of the accounting stay
    float64). ``parallel`` (a literal): the sweeps' and the accounting's passes on ``chunks`` threads (bit-identical
    results; the parallel functions compile only for such a variant)."""
    literally(code)
    literally(prony)
    literally(single)
    literally(parallel)
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
    done = _any_sweeps(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes,
                       free_start, free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks)
    for i in range(n):
        for d in range(3):
            v[i, d] = (x[i, d] - x_prev[i, d]) / h
    if done < iterations:
        return done, 0.0, 0.0, 0.0
    # accounting: dW/dx, W and |F|^2 per tet at the new positions (the corners hold them; float32 with single)
    of = _accounting(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                     chunks)
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


_VARIANTS: dict = {}


def variant(code, prony, single=False, parallel=False):
    """``(step, sweeps)`` for one material ``code``, ``prony`` flag, precision (``single``: the float32 sweeps of
    :func:`sweeps_f32`, split models without Prony only) and threading (``parallel``: each pass split over the
    ``chunks`` threads given as the last argument of both, :func:`sweeps_parallel`; the serial variants take and ignore
    it): :func:`step` and :func:`sweeps` (or :func:`sweeps_f32`) without their literal arguments, compiled (on first
    use, cached on disk) for that combination only.

    ``step`` and ``sweeps`` take ``code`` and ``prony`` as literals (``numba.literally``): called from Python with
    plain values, every call would go through the literal re-dispatch (~0.1 s); these wrappers pass them as
    compile-time constants, so a call costs what an ordinary compiled call does."""
    key = (int(code), bool(prony), bool(single), bool(parallel))
    if single and (prony or key[0] not in (NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN)):
        raise ValueError("ebm: precision float32 supports neo_hookean and anisotropic_neo_hookean without Prony only")
    if key not in _VARIANTS:
        _VARIANTS[key] = _make_variant(*key)
    return _VARIANTS[key]


def _make_variant(code, prony, single, parallel):
    # the closure's constants are part of numba's cache key: one entry per (code, prony, single, parallel)
    @njit(cache=True)
    def step_variant(x_prev, v_prev, x, v, t, h, X, f_ext, w, kin_nodes, kin_group, kin_displacement, group_t0,
                     group_t1, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, kin_start,
                     kin_slot, node_scale, last_load, n_tets, params32, out32, corners32, relax_a, iterations, chunks):
        return step(x_prev, v_prev, x, v, t, h, X, f_ext, w, kin_nodes, kin_group, kin_displacement, group_t0,
                    group_t1, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, kin_start,
                    kin_slot, node_scale, last_load, n_tets, params32, out32, corners32, code, prony, single, parallel,
                    relax_a, iterations, chunks)

    if single and parallel:
        @njit(cache=True)
        def sweeps_variant(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                           node_scale, iterations, chunks):
            return sweeps_f32_parallel(x, X, node_index, params32, out32, corners32, free_nodes, free_start,
                                       free_slot, node_scale, code, iterations, chunks)
    elif single:
        @njit(cache=True)
        def sweeps_variant(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                           node_scale, iterations, chunks):
            return sweeps_f32(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                              node_scale, code, iterations)
    elif parallel:
        @njit(cache=True)
        def sweeps_variant(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                           relax_a, iterations, chunks):
            return sweeps_parallel(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot,
                                   node_scale, code, prony, relax_a, iterations, chunks)
    else:
        @njit(cache=True)
        def sweeps_variant(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                           relax_a, iterations, chunks):
            return sweeps(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                          code, prony, relax_a, iterations)

    return step_variant, sweeps_variant


# -- single precision sweeps (settings ``precision = "float32"``): the split models only, without Prony ----------
# The lane loop runs on float32 (16 lanes per zmm register instead of 8), in the sweeps and in the energy accounting;
# the node pass adds a node's increments two at a time in float32 and accumulates these pair sums in float64 (half the
# conversions; whole float32 sums were a little faster and moved the zhang_rates block 3-4x further from float64,
# float64 sums ~5 % slower: docs/ebm.md); positions, the prediction, the velocities and the accounting's sums stay
# float64. The corner rows hold the displacements u = x - X (float32), so that H = F - I = (u_k - u_0) b_k comes
# without the cancellation of F - I in single precision.
_F32_ONE = np.float32(1.0)
_F32_TWO = np.float32(2.0)
_F32_THREE = np.float32(3.0)
_F32_HALF = np.float32(0.5)
_F32_THIRD = np.float32(1.0 / 3.0)
_F32_TWO_THIRDS = np.float32(2.0 / 3.0)
_F32_C2 = np.float32(2.0 / 9.0)
_F32_C3 = np.float32(14.0 / 81.0)
_F32_TINY = np.float32(1e-37)  # "at rest to the last bit": no increment (float32's smallest normal is 1.2e-38)
_F32_NAN = np.float32(np.nan)
_F32_ZERO = np.float32(0.0)
_INV_CBRT_MAGIC_F32 = np.float32((4.0 / 3.0 * 127.0 - 0.066) * 2.0 ** 23)


@njit(cache=True, inline="always")
def _inverse_cube_root_f32(J):
    """J^(-1/3) in float32 as ``sim.constitutive.kernels.inverse_cube_root`` (exponent-bit seed within 3.4 %, two quartic
    steps); NaN for J <= 0."""
    y = np.int32(_INV_CBRT_MAGIC_F32 - np.float32(np.float32(J).view(np.int32)) * _F32_THIRD).view(np.float32)
    for _ in range(2):
        r = _F32_ONE - J * (y * y * y)
        y = y + y * r * (_F32_THIRD + r * (_F32_C2 + r * _F32_C3))
    return y if J > _F32_ZERO else _F32_NAN


@njit(cache=True, inline="always")
def _split_model_f32(h00, h01, h02, h10, h11, h12, h20, h21, h22, mu, kappa, eta, ax, ay, az, a0_norm, fibre):
    """:func:`_split_model` in float32 from H (every operand float32)."""
    f00, f11, f22 = h00 + _F32_ONE, h11 + _F32_ONE, h22 + _F32_ONE
    f01, f02, f10, f12, f20, f21 = h01, h02, h10, h12, h20, h21
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
    j = tr + I2 + detH
    J = _F32_ONE + j
    HH = (h00 * h00 + f01 * f01 + f02 * f02 + f10 * f10 + h11 * h11 + f12 * f12 + f20 * f20 + f21 * f21
          + h22 * h22)
    d = _F32_TWO * tr + HH
    C00 = _F32_ONE + (h11 + h22) + c00
    C11 = _F32_ONE + (h00 + h22) + c11
    C22 = _F32_ONE + (h00 + h11) + c22
    C01, C02, C12 = c01 - f10, c02 - f20, c12 - f21
    C10, C20, C21 = c10 - f01, c20 - f02, c21 - f12
    y = _inverse_cube_root_f32(J)
    y2 = y * y
    inv_J = y2 * y
    Q = y2 + y + _F32_ONE
    N = -j * inv_J * (y + _F32_ONE)
    a = mu * y2
    b = a * (_F32_THREE + d) * _F32_THIRD * inv_J
    s = kappa * j - b
    num = _F32_HALF * mu * ((_F32_THREE + d) * N + d * Q) + _F32_HALF * kappa * j * j * Q
    if fibre:
        fa0 = f00 * ax + f01 * ay + f02 * az
        fa1 = f10 * ax + f11 * ay + f12 * az
        fa2 = f20 * ax + f21 * ay + f22 * az
        I4 = fa0 * fa0 + fa1 * fa1 + fa2 * fa2
        ha0, ha1, ha2 = h00 * ax + h01 * ay + h02 * az, h10 * ax + h11 * ay + h12 * az, h20 * ax + h21 * ay + h22 * az
        q = _F32_TWO * (ax * ha0 + ay * ha1 + az * ha2) + ha0 * ha0 + ha1 * ha1 + ha2 * ha2 + a0_norm
        D = (_F32_ONE + q) * N + q * Q
        num = num * Q + _F32_HALF * eta * D * D
        den = Q * Q
        e = eta * (y2 * I4 - _F32_ONE) * y2
        s = s - e * _F32_TWO_THIRDS * I4 * inv_J
        e2 = _F32_TWO * e
        u0, u1, u2 = e2 * fa0, e2 * fa1, e2 * fa2
        P = (a * f00 + s * C00 + u0 * ax, a * f01 + s * C01 + u0 * ay, a * f02 + s * C02 + u0 * az,
             a * f10 + s * C10 + u1 * ax, a * f11 + s * C11 + u1 * ay, a * f12 + s * C12 + u1 * az,
             a * f20 + s * C20 + u2 * ax, a * f21 + s * C21 + u2 * ay, a * f22 + s * C22 + u2 * az)
        return num, den, P
    P = (a * f00 + s * C00, a * f01 + s * C01, a * f02 + s * C02,
         a * f10 + s * C10, a * f11 + s * C11, a * f12 + s * C12,
         a * f20 + s * C20, a * f21 + s * C21, a * f22 + s * C22)
    return num, Q, P


@njit(cache=True, inline="always")
def _lanes_f32(fibre, forces, c, p, out, blk, lanes):
    """The lane loop in float32 (``c``: displacement rows u = x - X). Sweep (``forces`` False): writes
    ``-lambda' g_k`` (the node pass multiplies by w_k) and the denominators (row ``OUT_W``: the caller counts the NaN
    ones in a separate pass; a counter in the loop would make it a reduction, or with 64 bits cap the vector width
    at 8 lanes). Forces (the energy accounting of a float32 step): ``dW/dx_k = V P b_k``, ``W = V Psi`` and
    ``|F|^2``, as :func:`_lanes` with ``forces``."""
    for l in range(lanes):
        b10, b11, b12 = p[blk, (ROW_B + 0) * LANES + l], p[blk, (ROW_B + 1) * LANES + l], p[blk, (ROW_B + 2) * LANES + l]
        b20, b21, b22 = p[blk, (ROW_B + 3) * LANES + l], p[blk, (ROW_B + 4) * LANES + l], p[blk, (ROW_B + 5) * LANES + l]
        b30, b31, b32 = p[blk, (ROW_B + 6) * LANES + l], p[blk, (ROW_B + 7) * LANES + l], p[blk, (ROW_B + 8) * LANES + l]
        x0, y0, z0 = c[blk, 0 * LANES + l], c[blk, 1 * LANES + l], c[blk, 2 * LANES + l]
        e1x, e1y, e1z = c[blk, 3 * LANES + l] - x0, c[blk, 4 * LANES + l] - y0, c[blk, 5 * LANES + l] - z0
        e2x, e2y, e2z = c[blk, 6 * LANES + l] - x0, c[blk, 7 * LANES + l] - y0, c[blk, 8 * LANES + l] - z0
        e3x, e3y, e3z = c[blk, 9 * LANES + l] - x0, c[blk, 10 * LANES + l] - y0, c[blk, 11 * LANES + l] - z0
        num, den, P = _split_model_f32(
            e1x * b10 + e2x * b20 + e3x * b30, e1x * b11 + e2x * b21 + e3x * b31, e1x * b12 + e2x * b22 + e3x * b32,
            e1y * b10 + e2y * b20 + e3y * b30, e1y * b11 + e2y * b21 + e3y * b31, e1y * b12 + e2y * b22 + e3y * b32,
            e1z * b10 + e2z * b20 + e3z * b30, e1z * b11 + e2z * b21 + e3z * b31, e1z * b12 + e2z * b22 + e3z * b32,
            p[blk, ROW_MU * LANES + l], p[blk, ROW_KAPPA * LANES + l], p[blk, ROW_ETA * LANES + l],
            p[blk, (ROW_FIBRE + 0) * LANES + l], p[blk, (ROW_FIBRE + 1) * LANES + l],
            p[blk, (ROW_FIBRE + 2) * LANES + l], p[blk, ROW_FIBRE_NORM * LANES + l], fibre)
        if forces:
            V = p[blk, ROW_VOLUME * LANES + l]
            P = (V * P[0], V * P[1], V * P[2], V * P[3], V * P[4], V * P[5], V * P[6], V * P[7], V * P[8])
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
            s = _F32_ONE
            out[blk, OUT_W * LANES + l] = p[blk, ROW_VOLUME * LANES + l] * (num / den)
            h00, h11, h22 = e1x * b10 + e2x * b20 + e3x * b30, e1y * b11 + e2y * b21 + e3y * b31, \
                e1z * b12 + e2z * b22 + e3z * b32
            h01, h02 = e1x * b11 + e2x * b21 + e3x * b31, e1x * b12 + e2x * b22 + e3x * b32
            h10, h12 = e1y * b10 + e2y * b20 + e3y * b30, e1y * b12 + e2y * b22 + e3y * b32
            h20, h21 = e1z * b10 + e2z * b20 + e3z * b30, e1z * b11 + e2z * b21 + e3z * b31
            out[blk, OUT_FF * LANES + l] = (_F32_THREE + _F32_TWO * (h00 + h11 + h22) + h00 * h00 + h01 * h01
                                            + h02 * h02 + h10 * h10 + h11 * h11 + h12 * h12 + h20 * h20 + h21 * h21
                                            + h22 * h22)  # |I + H|^2
        else:
            w0, w1 = p[blk, (ROW_W + 0) * LANES + l], p[blk, (ROW_W + 1) * LANES + l]
            w2, w3 = p[blk, (ROW_W + 2) * LANES + l], p[blk, (ROW_W + 3) * LANES + l]
            denom = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
                     + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
            ok = denom > _F32_TINY
            lam_k = num / (den * denom if ok else _F32_ONE)
            nan = denom != denom
            out[blk, OUT_W * LANES + l] = denom
            s = -(lam_k if ok else (_F32_NAN if nan else _F32_ZERO))
        out[blk, (OUT_D + 0) * LANES + l] = s * g0x
        out[blk, (OUT_D + 1) * LANES + l] = s * g0y
        out[blk, (OUT_D + 2) * LANES + l] = s * g0z
        out[blk, (OUT_D + 3) * LANES + l] = s * g1x
        out[blk, (OUT_D + 4) * LANES + l] = s * g1y
        out[blk, (OUT_D + 5) * LANES + l] = s * g1z
        out[blk, (OUT_D + 6) * LANES + l] = s * g2x
        out[blk, (OUT_D + 7) * LANES + l] = s * g2y
        out[blk, (OUT_D + 8) * LANES + l] = s * g2z
        out[blk, (OUT_D + 9) * LANES + l] = s * g3x
        out[blk, (OUT_D + 10) * LANES + l] = s * g3y
        out[blk, (OUT_D + 11) * LANES + l] = s * g3z


def _all_blocks_f32(corners, params, out, code, forces, first, last):
    """The float32 lane loop of blocks ``first:last`` (``code`` and ``forces`` literals; a split model). Compiled code only."""
    raise NotImplementedError("sim.integrators.ebm.blocked._all_blocks_f32 runs in compiled code only")


@overload(_all_blocks_f32, prefer_literal=True, jit_options={"error_model": "numpy", "fastmath": {"contract"}})
def _all_blocks_f32_variant(corners, params, out, code, forces, first, last):
    """fastmath: only "contract"."""
    if not (isinstance(code, types.Literal) and isinstance(forces, types.Literal)):
        return None
    c, fo = int(code.literal_value), bool(forces.literal_value)
    if c not in (NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN):
        raise TypingError(f"sim.integrators.ebm.blocked: no float32 kernel for material code {c} (split models only)")
    fi = c == ANISOTROPIC_NEO_HOOKEAN

    def impl(corners, params, out, code, forces, first, last):
        lanes = corners.shape[1] // N_OUT
        for blk in range(first, last):
            _lanes_f32(fi, fo, corners, params, out, blk, lanes)

    return impl


@njit(cache=True, error_model="numpy")
def _nan_denominators_f32(out):
    """How many of the last float32 sweep's denominators (row ``OUT_W``, padding lanes included) are NaN."""
    # a run-time trip count: with LANES as a constant LLVM unrolls the row and vectorises the loop over blocks with
    # gathers instead
    lanes = out.shape[1] // N_OUT
    bad = 0
    for blk in range(out.shape[0]):
        for l in range(lanes):
            d = out[blk, OUT_W * LANES + l]
            bad += 1 if d != d else 0
    return bad


@njit(cache=True)
def load_displacements_f32(x, X, node_index, corners):
    """Every tet's node displacements ``x - X`` (float32) into ``corners``, as :func:`load_corners` (each node's
    displacement rounded once, then gathered: 2.1 -> 1.8 us for 504 tets)."""
    xf = x.reshape(x.size)
    Xf = X.reshape(X.size)
    u = np.empty(xf.size, np.float32)
    for j in range(xf.size):
        u[j] = np.float32(xf[j] - Xf[j])
    for blk in range(node_index.shape[0]):
        for k in range(4):
            for l in range(LANES):
                i = node_index[blk, k * LANES + l]
                corners[blk, (3 * k) * LANES + l] = u[i]
                corners[blk, (3 * k + 1) * LANES + l] = u[i + _Y]
                corners[blk, (3 * k + 2) * LANES + l] = u[i + _Z]


@njit(cache=True)
def sweeps_f32(x, X, node_index, params, out, corners, free_nodes, free_start, free_slot, node_scale, code,
               iterations):
    """:func:`sweeps` with the float32 lane loop (``params``, ``out``, ``corners`` float32; ``corners`` rows hold
    displacements; ``node_scale`` includes the inverse masses). The node sums run in tet order, in float64 over float32
    sums of consecutive pairs of incidences; ``x`` is float64.
    ``code`` (a split model) is compiled as a literal.

    NaN multipliers are counted after the last sweep only (a pass over the denominators cost ~4 % of a 504-tet step
    when done every sweep): a NaN multiplier of a tet with a free node makes that node's position NaN in the same sweep,
    which the finiteness check catches there, and a tet whose nodes are all kinematic has the same multiplier in
    every sweep. Either way the sweeps fail (fewer than ``iterations`` done), as in :func:`sweeps`."""
    literally(code)
    load_displacements_f32(x, X, node_index, corners)
    of = out.reshape(out.size)
    cf = corners.reshape(corners.size)
    for it in range(iterations):
        _all_blocks_f32(corners, params, out, code, False, 0, corners.shape[0])
        finite = _node_range_f32(x, X, of, cf, free_nodes, free_start, free_slot, node_scale, 0, free_nodes.shape[0])
        if not finite:
            return it
    if iterations > 0 and _nan_denominators_f32(out) > 0:
        return iterations - 1
    return iterations


@njit(cache=True)
def _node_range_f32(x, X, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1):
    """The node pass of :func:`sweeps_f32` for free nodes ``q0:q1`` (the same code); False when a position is
    non-finite. Its write-back loop repeats :func:`_node_range`'s on purpose: one shared
    ``inline="always"`` helper for both cost 12-14 % of the float32 rate (zhang_rates, 504 tets, one thread,
    alternating: 8,805 / 9,217 vs 10,327 / 10,688 Hz; float64 6,338 / 6,262 vs 6,726 / 7,013 Hz)."""
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
            ax += np.float64(of[o] + of[o2])
            ay += np.float64(of[o + _L] + of[o2 + _L])
            az += np.float64(of[o + _L2] + of[o2 + _L2])
            k += 2
        if k < k1:
            o = free_slot[k]
            ax += np.float64(of[o])
            ay += np.float64(of[o + _L])
            az += np.float64(of[o + _L2])
        i = free_nodes[q]
        sc = node_scale[i]
        vx = x[i, 0] + ax * sc
        vy = x[i, 1] + ay * sc
        vz = x[i, 2] + az * sc
        x[i, 0] = vx
        x[i, 1] = vy
        x[i, 2] = vz
        ux = np.float32(vx - X[i, 0])
        uy = np.float32(vy - X[i, 1])
        uz = np.float32(vz - X[i, 2])
        k = k0
        while k + 1 < k1:
            o = free_slot[k]
            o2 = free_slot[k + 1]
            cf[o] = ux
            cf[o + _L] = uy
            cf[o + _L2] = uz
            cf[o2] = ux
            cf[o2 + _L] = uy
            cf[o2 + _L2] = uz
            k += 2
        if k < k1:
            o = free_slot[k]
            cf[o] = ux
            cf[o + _L] = uy
            cf[o + _L2] = uz
        if not (abs(vx) < np.inf and abs(vy) < np.inf and abs(vz) < np.inf):
            finite = False
    return finite


@njit(cache=True, parallel=True)
def node_pass_f32_parallel(x, X, out, corners, free_nodes, free_start, free_slot, node_scale, chunks):
    """:func:`sweeps_f32`'s node pass in ``chunks`` ranges of free nodes, one per thread; False when a position is
    non-finite."""
    of = out.reshape(out.size)
    cf = corners.reshape(corners.size)
    n_free = free_nodes.shape[0]
    ok = np.ones(chunks, np.bool_)
    for ch in prange(chunks):
        q0, q1 = _chunk_bounds(free_start, n_free, ch, chunks)
        ok[ch] = _node_range_f32(x, X, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1)
    return ok.all()


@njit(cache=True)
def sweeps_f32_parallel(x, X, node_index, params, out, corners, free_nodes, free_start, free_slot, node_scale, code,
                        iterations, chunks):
    """:func:`sweeps_f32` with each pass split over ``chunks`` threads (bit-identical results)."""
    literally(code)
    load_displacements_f32(x, X, node_index, corners)
    for it in range(iterations):
        _parallel_lanes_f32(corners, params, out, code, False, chunks)
        if not node_pass_f32_parallel(x, X, out, corners, free_nodes, free_start, free_slot, node_scale, chunks):
            return it
    if iterations > 0 and _nan_denominators_f32(out) > 0:
        return iterations - 1
    return iterations
