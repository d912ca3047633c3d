"""Numba kernels of the per-tet hyperelastic forces the explicit-type integrators and EBM share: internal
forces and strain energy of a body, inverted-element counts and the elastic stress for the Prony history.

Prony relaxation (Zhang 5.29–5.32 with the incremental update of ``sim.constitutive.prony``): within one step
the history is fixed, so the relaxed stress of every term sum is affine in the elastic one,
``S^ = a S - Gamma`` with ``a = 1 - sum_i A_i`` and ``Gamma = sum_i B_i gamma_i`` (and
``Psi^ = a Psi - sum_i B_i g_i``); pushed forward, ``P^ = F S^ = a P - F Gamma`` — no per-tet solve.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from sim.constitutive.kernels import cofactor, defgrad, energy_piola, node_gradients

@njit(cache=True, inline="always")
def _relaxed(F, P, psi, relax_a, Gamma, g_sum, t):
    """Prony-relaxed (P^, Psi^) = (a P - F Gamma_t, a Psi - g_t)."""
    G = Gamma
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    return (relax_a * P[0] - (f00 * G[t, 0, 0] + f01 * G[t, 1, 0] + f02 * G[t, 2, 0]),
            relax_a * P[1] - (f00 * G[t, 0, 1] + f01 * G[t, 1, 1] + f02 * G[t, 2, 1]),
            relax_a * P[2] - (f00 * G[t, 0, 2] + f01 * G[t, 1, 2] + f02 * G[t, 2, 2]),
            relax_a * P[3] - (f10 * G[t, 0, 0] + f11 * G[t, 1, 0] + f12 * G[t, 2, 0]),
            relax_a * P[4] - (f10 * G[t, 0, 1] + f11 * G[t, 1, 1] + f12 * G[t, 2, 1]),
            relax_a * P[5] - (f10 * G[t, 0, 2] + f11 * G[t, 1, 2] + f12 * G[t, 2, 2]),
            relax_a * P[6] - (f20 * G[t, 0, 0] + f21 * G[t, 1, 0] + f22 * G[t, 2, 0]),
            relax_a * P[7] - (f20 * G[t, 0, 1] + f21 * G[t, 1, 1] + f22 * G[t, 2, 1]),
            relax_a * P[8] - (f20 * G[t, 0, 2] + f21 * G[t, 1, 2] + f22 * G[t, 2, 2])), relax_a * psi - g_sum[t]


@njit(cache=True, inline="always")
def tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma, g_sum):
    """(W_k, node gradients g_1..g_3 as a 9-tuple) of tet t; g_0 = -(g_1 + g_2 + g_3)."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    F = defgrad(x, i0, i1, i2, i3, Dm_inv, t)
    psi, P = energy_piola(code, F, mu[t], lam[t], eta[t], fibre[t, 0], fibre[t, 1], fibre[t, 2])
    if prony:
        P, psi = _relaxed(F, P, psi, relax_a, Gamma, g_sum, t)
    V = volume[t]
    g = node_gradients((V * P[0], V * P[1], V * P[2], V * P[3], V * P[4], V * P[5], V * P[6], V * P[7], V * P[8]),
                    Dm_inv, t)
    return V * psi, g



@njit(cache=True)
def forces_and_energy(x, f, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma, g_sum):
    """Internal forces ``f = -sum_k dW_k/dx`` (written into ``f``), the total strain energy ``sum_k W_k`` [J]
    (relaxed when ``prony``) and the largest element stretch ``max_k |F_k|_F / sqrt(3)`` (1 at rest)."""
    f[:] = 0.0
    total = 0.0
    FF = 0.0
    for t in range(tets.shape[0]):
        W, g = tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma,
                                    g_sum)
        total += W
        F = defgrad(x, tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3], Dm_inv, t)
        FF = max(FF, F[0] * F[0] + F[1] * F[1] + F[2] * F[2] + F[3] * F[3] + F[4] * F[4] + F[5] * F[5]
                 + F[6] * F[6] + F[7] * F[7] + F[8] * F[8])
        i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        f[i0, 0] += g[0] + g[3] + g[6]
        f[i0, 1] += g[1] + g[4] + g[7]
        f[i0, 2] += g[2] + g[5] + g[8]
        f[i1, 0] -= g[0]
        f[i1, 1] -= g[1]
        f[i1, 2] -= g[2]
        f[i2, 0] -= g[3]
        f[i2, 1] -= g[4]
        f[i2, 2] -= g[5]
        f[i3, 0] -= g[6]
        f[i3, 1] -= g[7]
        f[i3, 2] -= g[8]
    return total, np.sqrt(FF / 3.0)


# -- two threads (explicit, cnn on large meshes: sim.forces) -----------------------------------------------------------
# forces_and_energy scatters every tet's node forces into f, which is not race-free across threads. Its two-thread
# version splits it into a per-tet pass (each tet writes its four corner contributions to its own rows) and a per-node
# gather that adds a node's contributions in increasing tet order, from 0: the additions the scatter makes, in the same
# order (``f -= g`` is stored as ``+(-g)``, which is exact), so the forces are bit-identical to forces_and_energy's for
# any number of threads (tests/sim/integrators/test_threads.py). Used from PARALLEL_MIN_TETS tets with more than one numba thread
# (measured crossover: docs/integrators-zhang.md); compiled only then.
PARALLEL_MIN_TETS = 1024


def node_incidences(tets, n_nodes):
    """``(start (n_nodes + 1,), corner (4 m,))`` int64: node i's incidences are the flat corner indices
    ``4 t + k`` (``tets[t, k] == i``) ``corner[start[i]:start[i + 1]]``, in increasing tet order."""
    flat = np.asarray(tets, dtype=np.int64).ravel()
    corner = np.argsort(flat, kind="stable").astype(np.int64)  # stable: by node, then by tet (and corner)
    start = np.searchsorted(flat[corner], np.arange(n_nodes + 1)).astype(np.int64)
    return start, corner


@njit(cache=True)
def _contributions(x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma, g_sum, contrib, tet_W,
                   tet_FF, t0, t1):
    """Tets ``t0:t1``: each tet's energy, ``|F|^2`` and the four contributions :func:`forces_and_energy` adds to its
    nodes' forces (rows ``4 t + k`` of ``contrib``; ``f -= g`` stored as ``-g``)."""
    for t in range(t0, t1):
        W, g = tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma,
                                    g_sum)
        tet_W[t] = W
        F = defgrad(x, tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3], Dm_inv, t)
        tet_FF[t] = (F[0] * F[0] + F[1] * F[1] + F[2] * F[2] + F[3] * F[3] + F[4] * F[4] + F[5] * F[5]
                     + F[6] * F[6] + F[7] * F[7] + F[8] * F[8])
        r = 4 * t
        contrib[r, 0] = g[0] + g[3] + g[6]
        contrib[r, 1] = g[1] + g[4] + g[7]
        contrib[r, 2] = g[2] + g[5] + g[8]
        contrib[r + 1, 0] = -g[0]
        contrib[r + 1, 1] = -g[1]
        contrib[r + 1, 2] = -g[2]
        contrib[r + 2, 0] = -g[3]
        contrib[r + 2, 1] = -g[4]
        contrib[r + 2, 2] = -g[5]
        contrib[r + 3, 0] = -g[6]
        contrib[r + 3, 1] = -g[7]
        contrib[r + 3, 2] = -g[8]


@njit(cache=True)
def _gather(f, start, corner, contrib, i0, i1):
    """Nodes ``i0:i1``: the sum of their contributions from 0, in tet order."""
    for i in range(i0, i1):
        fx = 0.0
        fy = 0.0
        fz = 0.0
        for k in range(start[i], start[i + 1]):
            c = corner[k]
            fx += contrib[c, 0]
            fy += contrib[c, 1]
            fz += contrib[c, 2]
        f[i, 0] = fx
        f[i, 1] = fy
        f[i, 2] = fz


@njit(cache=True, parallel=True)
def forces_and_energy_parallel(x, f, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma, g_sum,
                               start, corner, contrib, tet_W, tet_FF, chunks):
    """:func:`forces_and_energy` in ``chunks`` ranges (one per thread), bit-identical for any ``chunks``: the
    per-tet pass (energy, ``|F|^2``, four corner contributions into ``contrib (4 m, 3)``), then the per-node gather of
    the contributions in tet order (``start``, ``corner``: :func:`node_incidences`), then the energy summed in tet
    order. ``tet_W``, ``tet_FF`` (m,) are scratch."""
    m = tets.shape[0]
    n = f.shape[0]
    for ch in prange(chunks):
        _contributions(x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma, g_sum, contrib,
                       tet_W, tet_FF, m * ch // chunks, m * (ch + 1) // chunks)
    for ch in prange(chunks):
        _gather(f, start, corner, contrib, n * ch // chunks, n * (ch + 1) // chunks)
    total = 0.0
    FF = 0.0
    for t in range(m):
        total += tet_W[t]
        FF = max(FF, tet_FF[t])
    return total, np.sqrt(FF / 3.0)


@njit(cache=True, inline="always")
def _inverted(x, tets, t):
    """1 when tet ``t`` has a non-positive (or NaN) volume ``det(x1 - x0, x2 - x0, x3 - x0)``, else 0."""
    i0 = tets[t, 0]
    ax, ay, az = x[tets[t, 1], 0] - x[i0, 0], x[tets[t, 1], 1] - x[i0, 1], x[tets[t, 1], 2] - x[i0, 2]
    bx, by, bz = x[tets[t, 2], 0] - x[i0, 0], x[tets[t, 2], 1] - x[i0, 1], x[tets[t, 2], 2] - x[i0, 2]
    cx, cy, cz = x[tets[t, 3], 0] - x[i0, 0], x[tets[t, 3], 1] - x[i0, 1], x[tets[t, 3], 2] - x[i0, 2]
    return 0 if ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx) > 0.0 else 1


@njit(cache=True, parallel=True)
def count_inverted_parallel(x, tets):
    """:func:`count_inverted` on all threads (an integer count: the same for any number of threads)."""
    n = 0
    for t in prange(tets.shape[0]):
        n += _inverted(x, tets, t)
    return n


@njit(cache=True)
def count_inverted(x, tets):
    """Number of tets with a non-positive volume, ``det(x1 - x0, x2 - x0, x3 - x0) <= 0`` (the rest tets are
    positively oriented, so this is ``J <= 0``)."""
    n = 0
    for t in range(tets.shape[0]):
        n += _inverted(x, tets, t)
    return n


@njit(cache=True)
def elastic_stress(x, S, psi, tets, Dm_inv, mu, lam, eta, fibre, code):
    """Elastic second Piola stress ``S = F^-1 P`` (m, 3, 3) and ``Psi`` (m,) per tet, for the Prony history
    update (``F^-1 = cof(F)^T / J``)."""
    for t in range(tets.shape[0]):
        i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        F = defgrad(x, i0, i1, i2, i3, Dm_inv, t)
        p, P = energy_piola(code, F, mu[t], lam[t], eta[t], fibre[t, 0], fibre[t, 1], fibre[t, 2])
        psi[t] = p
        cof = cofactor(F)
        inv_J = 1.0 / (F[0] * cof[0] + F[1] * cof[1] + F[2] * cof[2])
        for r in range(3):
            for c in range(3):
                # (F^-1)_{rk} = cof_{kr} / J
                S[t, r, c] = (cof[r] * P[c] + cof[3 + r] * P[3 + c] + cof[6 + r] * P[6 + c]) * inv_J
