"""Numba kernel of the Energy Balance Method (Zhang ch. 5): Jacobi sweeps of the per-tet energy balance, with the
energies and stresses of ``sim.constitutive.kernels`` (scalar code per tet, no allocation per tet,
structure-of-arrays inputs ``x (n, 3)``, ``tets (m, 4) int``, ``Dm_inv (m, 3, 3)``, per-tet
``volume, mu, lam, eta (m,)``, ``fibre (m, 3)``).

EBM per tet k (5.7–5.10 as corrected: docs/design.md, "Zhang ch. 5: EBM (5.7, 5.8, 5.10/5.11, 5.15)"):
``W_k = V_k Psi``, nodal gradients ``g_a = V_k P Dm^-T`` columns (a = 1..3) and ``g_0 = -(g_1 + g_2 + g_3)``, the
multiplier ``lambda_k = W_k / sum_j w_j |g_j|^2`` and the increments ``-w_i lambda_k g_i`` summed per node (5.9),
scaled by ``node_scale`` (1 / tet count for ``update = "average"``) and applied after the sweep (5.14,
Jacobi: every tet sees the same positions).

No ``fastmath``: the kernel must reproduce the NumPy path to 1e-10 (tests/sim/integrators/ebm/test_kernels.py).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from sim.constitutive.force_kernels import count_inverted, tet_energy_gradient

@njit(cache=True)
def ebm_iterations(x, dx, tets, Dm_inv, volume, mu, lam, eta, fibre, code, w, node_scale, prony, relax_a, Gamma,
                   g_sum, iterations):
    """``iterations`` Jacobi sweeps of the energy balance (5.7–5.9, 5.14) on ``x`` in place; ``dx`` (n, 3) is
    scratch. Returns the number of sweeps done: fewer than ``iterations`` when a position became
    non-finite (the caller raises SimulationDiverged)."""
    n = x.shape[0]
    for it in range(iterations):
        dx[:] = 0.0
        for t in range(tets.shape[0]):
            W, g = tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a,
                                        Gamma, g_sum)
            i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
            w0, w1, w2, w3 = w[i0], w[i1], w[i2], w[i3]
            g0x = -(g[0] + g[3] + g[6])
            g0y = -(g[1] + g[4] + g[7])
            g0z = -(g[2] + g[5] + g[8])
            denom = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
                     + w2 * (g[3] * g[3] + g[4] * g[4] + g[5] * g[5]) + w3 * (g[6] * g[6] + g[7] * g[7] + g[8] * g[8]))
            if not denom > 1e-300:
                if denom != denom:  # NaN (an inverted split-model element): the sweep fails, as in NumPy
                    dx[i0, 0] = dx[i1, 0] = dx[i2, 0] = dx[i3, 0] = np.nan
                continue  # a zero gradient: no increment
            lam_k = W / denom  # 5.7
            s0, s1, s2, s3 = w0 * lam_k, w1 * lam_k, w2 * lam_k, w3 * lam_k
            dx[i0, 0] -= s0 * g0x  # 5.8, summed per node (5.9)
            dx[i0, 1] -= s0 * g0y
            dx[i0, 2] -= s0 * g0z
            dx[i1, 0] -= s1 * g[0]
            dx[i1, 1] -= s1 * g[1]
            dx[i1, 2] -= s1 * g[2]
            dx[i2, 0] -= s2 * g[3]
            dx[i2, 1] -= s2 * g[4]
            dx[i2, 2] -= s2 * g[5]
            dx[i3, 0] -= s3 * g[6]
            dx[i3, 1] -= s3 * g[7]
            dx[i3, 2] -= s3 * g[8]
        finite = True
        for i in range(n):  # 5.14
            s = node_scale[i]
            for d in range(3):
                v = x[i, d] + dx[i, d] * s
                x[i, d] = v
                if not math.isfinite(v):
                    finite = False
        if not finite:
            return it
    return iterations


@njit(cache=True)
def uninverting_fraction(x, x_prev, v_prev, f_ext, w, h, kin_nodes, kin_target, tets, backtrack, max_backtracks):
    """The share ``alpha`` of the velocity that the prediction 5.13 may extrapolate without inverting an element:
    1, or the first of ``backtrack, backtrack^2, ...`` for which ``x = x_prev + h (alpha v_prev + h f_ext w)``
    (kinematic nodes at ``kin_target``) gives every tet a positive volume ``det(x1 - x0, x2 - x0, x3 - x0)``.
    ``x`` (n, 3) is scratch and holds that prediction on return, with the arithmetic of the step kernels (so that
    theirs, given ``alpha * v_prev``, is the one checked, bit for bit). Returns 0.0 when even
    ``backtrack^max_backtracks`` inverts a tet: then the kinematic targets or the external force invert it, not the
    velocity, and the sweeps report the failure.

    Why: the split Neo-Hookean energies (5.35, 5.37) are undefined for J <= 0, so an inverted prediction makes every
    later sweep non-finite. The velocity 5.15 is the position change of sweeps that have not converged (on the Zhang
    5.3.2 cylinder they wander by ~1e-2 m per sweep however many are run), and the prediction extrapolates that
    wander; a backtracking line search on the velocity keeps the one condition the energy needs, and removes as
    little of the body's motion as the search's grid allows. A step whose full prediction inverts nothing is
    unchanged."""
    n = x.shape[0]
    alpha = 1.0
    for _ in range(max_backtracks + 1):
        for i in range(n):
            for d in range(3):
                x[i, d] = x_prev[i, d] + h * (alpha * v_prev[i, d] + h * f_ext[i, d] * w[i])
        for q in range(kin_nodes.shape[0]):
            for d in range(3):
                x[kin_nodes[q], d] = kin_target[q, d]
        if count_inverted(x, tets) == 0:
            return alpha
        alpha *= backtrack
    return 0.0
