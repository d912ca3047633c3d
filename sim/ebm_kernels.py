"""Numba kernels of the Energy Balance Method (Zhang ch. 5) and of the per-tet hyperelastic forces the
explicit-type integrators share: scalar code per tet, no allocation per tet, structure-of-arrays inputs
(``x (n, 3)``, ``tets (m, 4) int``, ``Dm_inv (m, 3, 3)``, per-tet ``volume, mu, lam, eta (m,)``,
``fibre (m, 3)``).

Materials (``MATERIALS``; the same formulas as ``sim.constitutive``, which stays the NumPy reference):

- ``stvk`` — ``E = (F^T F - I)/2``, ``S = 2 mu E + lam tr(E) I``, ``P = F S``,
  ``Psi = mu E:E + lam/2 tr(E)^2`` (Zhang 5.2.5.1);
- ``neo_hookean`` — Zhang eq. 5.35: ``Psi = mu/2 (J^(-2/3) I1 - 3) + kappa/2 (J - 1)^2``,
  ``P = mu J^(-2/3) (F - I1/3 F^-T) + kappa (J - 1) cof F`` with ``kappa = lam + 2 mu / 3``;
- ``stable_neo_hookean`` — Macklin & Müller (2021): ``P = mu F + lam (J - gamma) cof F``,
  ``gamma = 1 + mu / lam``;
- ``anisotropic_neo_hookean`` — ``neo_hookean`` plus the fibre term of Zhang 5.37 with DESIGN.md's fix of
  5.38: ``Psi_f = eta/2 (I4bar - 1)^2``, ``I4bar = J^(-2/3) |F a0|^2``,
  ``P_f = eta (I4bar - 1) J^(-2/3) (2 (F a0) a0^T - 2/3 I4 F^-T)``.

Energies are evaluated from the displacement gradient ``H = F - I`` (``sim.ebm.energy_density`` is the
NumPy twin): Zhang's multiplier 5.7 divides ``W_k`` by ``|dW_k/dx|^2``, both of which vanish at rest, and
the textbook forms (``J^(-2/3) I1 - 3``, ``(J - gamma)^2 - (1 - gamma)^2``) carry an absolute rounding error
of about ``eps mu`` that does not vanish with the strain: an element at rest to rounding then gets a
multiplier made of rounding noise and moves by a sizeable fraction of its own size (measured on the
480-tet benchmark block: 37 % of the step's largest displacement after one sweep, different between two
equally valid summation orders). With ``H`` the error of ``Psi`` scales with the strain, and the
increments' error stays at rounding level.

``J^(-2/3) = y^2`` with ``y = 1 / cbrt(J)`` and ``J^(-2/3) - 1 = -j (y + 1) / (J (y^2 + y + 1))``
(``j = J - 1``: exact algebra, no cancellation) for ``J > 0``, NaN otherwise (as NumPy's ``J ** (-2/3)``), so an
inverted element of a split model makes the iteration non-finite and the integrator reports it.

Prony relaxation (Zhang 5.29–5.32 with the incremental update of ``sim.prony``): within one step the
history is fixed, so the relaxed stress of every term sum is affine in the elastic one,
``S^ = a S - Gamma`` with ``a = 1 - sum_i A_i`` and ``Gamma = sum_i B_i gamma_i`` (and
``Psi^ = a Psi - sum_i B_i g_i``); pushed forward, ``P^ = F S^ = a P - F Gamma`` — no per-tet solve.

EBM per tet k (5.7–5.10 as corrected in DESIGN.md): ``W_k = V_k Psi``, nodal gradients
``g_a = V_k P Dm^-T`` columns (a = 1..3) and ``g_0 = -(g_1 + g_2 + g_3)``, the multiplier
``lambda_k = W_k / sum_j w_j |g_j|^2`` and the increments ``-w_i lambda_k g_i`` summed per node (5.9),
scaled by ``node_scale`` (1 / tet count for ``update = "average"``) and applied after the sweep (5.14,
Jacobi: every tet sees the same positions).

No ``fastmath``: the kernels must reproduce the NumPy path to 1e-10 (tests/sim/test_ebm_kernels.py),
and reassociation would also change which elements' NaN checks fire.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from sim.xpbd_kernels import _cofactor, _defgrad, _node_grads

# material codes, the same numbers as sim.constitutive.MODEL_CODES
STVK, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN = 0, 1, 2, 3
MATERIALS = {"stvk": STVK, "neo_hookean": NEO_HOOKEAN, "stable_neo_hookean": STABLE_NEO_HOOKEAN,
             "anisotropic_neo_hookean": ANISOTROPIC_NEO_HOOKEAN}


@njit(cache=True, inline="always")
def _j_minus_two_thirds(J, j):
    """(J^(-2/3), J^(-2/3) - 1) from J and j = J - 1 (accurate), NaN for J <= 0: with y = J^(-1/3),
    ``y - 1 = (y^3 - 1) / (y^2 + y + 1) = -j / (J (y^2 + y + 1))`` has no cancellation."""
    if J > 0.0:
        y = 1.0 / np.cbrt(J)
        return y * y, -j / (J * (y * y + y + 1.0)) * (y + 1.0)
    return np.nan, np.nan


# J^(-1/3) seed from the bit pattern: bits(J) / 2^52 ~ log2 J + 1023, so bits(y) ~ (4/3 1023 - c) 2^52 - bits(J) / 3;
# c = 0.066 minimises the seed's largest relative error over a binade (3.4 %)
_INV_CBRT_MAGIC = (4.0 / 3.0 * 1023.0 - 0.066) * 2.0 ** 52


@njit(cache=True, inline="always")
def _inverse_cube_root(J):
    """J^(-1/3) for normal J > 0 (NaN for J <= 0) without a branch or a libm call, so that a loop over
    lanes vectorises: a seed from the exponent bits (relative error <= 3.4 %), then two steps of
    ``y <- y (1 + r/3 + 2 r^2/9 + 14 r^3/81)`` with ``r = 1 - J y^3`` (the series of ``(1 - r)^(-1/3)``, error
    ~ 35/243 r^4 per step): 3.4e-2 -> 2e-5 -> rounding. Measured against 1 / cbrt(J) over J in
    [1e-260, 1e260]: largest relative difference 2.2e-16, mean 5.3e-17."""
    y = np.int64(_INV_CBRT_MAGIC - np.float64(np.float64(J).view(np.int64)) * (1.0 / 3.0)).view(np.float64)
    for _ in range(2):
        r = 1.0 - J * (y * y * y)
        y = y + y * r * (1.0 / 3.0 + r * (2.0 / 9.0 + r * (14.0 / 81.0)))
    return y if J > 0.0 else np.nan


@njit(cache=True, inline="always")
def _j_minus_two_thirds_branch_free(J, j):
    """``_j_minus_two_thirds`` with the vectorisable :func:`_inverse_cube_root` (NaN for J <= 0 through y)."""
    y = _inverse_cube_root(J)
    return y * y, -j / (J * (y * y + y + 1.0)) * (y + 1.0)


@njit(cache=True, inline="always")
def _displacement_invariants(F):
    """(tr H, H:H, I2(H), det H) of the displacement gradient H = F - I, so that J - 1 = tr H + I2 + det H
    and I1 - 3 = 2 tr H + H:H hold without the cancellation of ``det F - 1`` and ``F:F - 3``."""
    h00, h01, h02 = F[0] - 1.0, F[1], F[2]
    h10, h11, h12 = F[3], F[4] - 1.0, F[5]
    h20, h21, h22 = F[6], F[7], F[8] - 1.0
    tr = h00 + h11 + h22
    HH = (h00 * h00 + h01 * h01 + h02 * h02 + h10 * h10 + h11 * h11 + h12 * h12
          + h20 * h20 + h21 * h21 + h22 * h22)
    I2 = h00 * h11 + h00 * h22 + h11 * h22 - h01 * h10 - h02 * h20 - h12 * h21
    detH = (h00 * (h11 * h22 - h12 * h21) - h01 * (h10 * h22 - h12 * h20) + h02 * (h10 * h21 - h11 * h20))
    return tr, HH, I2, detH


@njit(cache=True, inline="always")
def _energy_piola(code, F, mu, lam, eta, ax, ay, az):
    """(Psi, P as a row-major 9-tuple) of one tet."""
    return _energy_piola_root(code, F, mu, lam, eta, ax, ay, az, False)


@njit(cache=True, inline="always")
def _energy_piola_root(code, F, mu, lam, eta, ax, ay, az, branch_free):
    """:func:`_energy_piola` with the choice of J^(-1/3): ``branch_free`` (a constant at every call site, so the
    compiler drops the other branch) takes :func:`_inverse_cube_root`, which lets a loop over lanes vectorise
    (sim.ebm_blocked); otherwise ``1 / cbrt(J)``."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    if code == STABLE_NEO_HOOKEAN:
        cof = _cofactor(F)
        J = f00 * cof[0] + f01 * cof[1] + f02 * cof[2]
        gamma = 1.0 + mu / lam
        tr, HH, I2, detH = _displacement_invariants(F)
        j = tr + I2 + detH
        # mu/2 (I1 - 3) + lam/2 ((J - gamma)^2 - (1 - gamma)^2) = mu/2 (H:H - 2 I2 - 2 det H) + lam/2 j^2
        psi = 0.5 * mu * (HH - 2.0 * I2 - 2.0 * detH) + 0.5 * lam * j * j
        s = lam * (J - gamma)
        return psi, (mu * f00 + s * cof[0], mu * f01 + s * cof[1], mu * f02 + s * cof[2],
                     mu * f10 + s * cof[3], mu * f11 + s * cof[4], mu * f12 + s * cof[5],
                     mu * f20 + s * cof[6], mu * f21 + s * cof[7], mu * f22 + s * cof[8])
    if code == STVK:
        # E = (F^T F - I) / 2 (symmetric)
        e00 = 0.5 * (f00 * f00 + f10 * f10 + f20 * f20 - 1.0)
        e11 = 0.5 * (f01 * f01 + f11 * f11 + f21 * f21 - 1.0)
        e22 = 0.5 * (f02 * f02 + f12 * f12 + f22 * f22 - 1.0)
        e01 = 0.5 * (f00 * f01 + f10 * f11 + f20 * f21)
        e02 = 0.5 * (f00 * f02 + f10 * f12 + f20 * f22)
        e12 = 0.5 * (f01 * f02 + f11 * f12 + f21 * f22)
        tr = e00 + e11 + e22
        psi = mu * (e00 * e00 + e11 * e11 + e22 * e22 + 2.0 * (e01 * e01 + e02 * e02 + e12 * e12)) \
            + 0.5 * lam * tr * tr
        s00 = 2.0 * mu * e00 + lam * tr
        s11 = 2.0 * mu * e11 + lam * tr
        s22 = 2.0 * mu * e22 + lam * tr
        s01 = 2.0 * mu * e01
        s02 = 2.0 * mu * e02
        s12 = 2.0 * mu * e12
        return psi, (f00 * s00 + f01 * s01 + f02 * s02, f00 * s01 + f01 * s11 + f02 * s12,
                     f00 * s02 + f01 * s12 + f02 * s22,
                     f10 * s00 + f11 * s01 + f12 * s02, f10 * s01 + f11 * s11 + f12 * s12,
                     f10 * s02 + f11 * s12 + f12 * s22,
                     f20 * s00 + f21 * s01 + f22 * s02, f20 * s01 + f21 * s11 + f22 * s12,
                     f20 * s02 + f21 * s12 + f22 * s22)
    # the split models: Zhang 5.35 (+ the fibre term 5.37)
    cof = _cofactor(F)
    J = f00 * cof[0] + f01 * cof[1] + f02 * cof[2]
    inv_J = 1.0 / J
    I1 = (f00 * f00 + f01 * f01 + f02 * f02 + f10 * f10 + f11 * f11 + f12 * f12
          + f20 * f20 + f21 * f21 + f22 * f22)
    kappa = lam + 2.0 * mu / 3.0
    tr, HH, I2, detH = _displacement_invariants(F)
    j = tr + I2 + detH  # J - 1
    d = 2.0 * tr + HH  # I1 - 3
    if branch_free:
        Jm23, m = _j_minus_two_thirds_branch_free(J, j)
    else:
        Jm23, m = _j_minus_two_thirds(J, j)
    psi = 0.5 * mu * (3.0 * m + d + m * d) + 0.5 * kappa * j * j  # J^(-2/3) I1 - 3 = 3 m + d + m d
    a = mu * Jm23
    b = a * I1 / 3.0 * inv_J  # times cof = times J F^-T
    c = kappa * (J - 1.0)
    p = (a * f00 - b * cof[0] + c * cof[0], a * f01 - b * cof[1] + c * cof[1], a * f02 - b * cof[2] + c * cof[2],
         a * f10 - b * cof[3] + c * cof[3], a * f11 - b * cof[4] + c * cof[4], a * f12 - b * cof[5] + c * cof[5],
         a * f20 - b * cof[6] + c * cof[6], a * f21 - b * cof[7] + c * cof[7], a * f22 - b * cof[8] + c * cof[8])
    if code == ANISOTROPIC_NEO_HOOKEAN:
        # F a0 and I4 = |F a0|^2 = a0 . C a0
        fa0 = f00 * ax + f01 * ay + f02 * az
        fa1 = f10 * ax + f11 * ay + f12 * az
        fa2 = f20 * ax + f21 * ay + f22 * az
        I4 = fa0 * fa0 + fa1 * fa1 + fa2 * fa2
        # I4 - 1 = 2 a0.H a0 + |H a0|^2 + (|a0|^2 - 1) and I4bar - 1 = m I4 + (I4 - 1), both without cancellation
        ha0, ha1, ha2 = fa0 - ax, fa1 - ay, fa2 - az
        q = 2.0 * (ax * ha0 + ay * ha1 + az * ha2) + ha0 * ha0 + ha1 * ha1 + ha2 * ha2 + (ax * ax + ay * ay + az * az - 1.0)
        dbar = m * (1.0 + q) + q
        psi += 0.5 * eta * dbar * dbar
        e = eta * (Jm23 * I4 - 1.0) * Jm23  # P_f = e (2 (F a0) a0^T - 2/3 I4 F^-T)
        q = e * (2.0 / 3.0) * I4 * inv_J
        p = (p[0] + 2.0 * e * fa0 * ax - q * cof[0], p[1] + 2.0 * e * fa0 * ay - q * cof[1],
             p[2] + 2.0 * e * fa0 * az - q * cof[2],
             p[3] + 2.0 * e * fa1 * ax - q * cof[3], p[4] + 2.0 * e * fa1 * ay - q * cof[4],
             p[5] + 2.0 * e * fa1 * az - q * cof[5],
             p[6] + 2.0 * e * fa2 * ax - q * cof[6], p[7] + 2.0 * e * fa2 * ay - q * cof[7],
             p[8] + 2.0 * e * fa2 * az - q * cof[8])
    return psi, p


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
def _tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma, g_sum):
    """(W_k, node gradients g_1..g_3 as a 9-tuple) of tet t; g_0 = -(g_1 + g_2 + g_3)."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    F = _defgrad(x, i0, i1, i2, i3, Dm_inv, t)
    psi, P = _energy_piola(code, F, mu[t], lam[t], eta[t], fibre[t, 0], fibre[t, 1], fibre[t, 2])
    if prony:
        P, psi = _relaxed(F, P, psi, relax_a, Gamma, g_sum, t)
    V = volume[t]
    g = _node_grads((V * P[0], V * P[1], V * P[2], V * P[3], V * P[4], V * P[5], V * P[6], V * P[7], V * P[8]),
                    Dm_inv, t)
    return V * psi, g


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
            W, g = _tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a,
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
def forces_and_energy(x, f, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma, g_sum):
    """Internal forces ``f = -sum_k dW_k/dx`` (written into ``f``), the total strain energy ``sum_k W_k`` [J]
    (relaxed when ``prony``) and the largest element stretch ``max_k |F_k|_F / sqrt(3)`` (1 at rest)."""
    f[:] = 0.0
    total = 0.0
    FF = 0.0
    for t in range(tets.shape[0]):
        W, g = _tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma,
                                    g_sum)
        total += W
        F = _defgrad(x, tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3], Dm_inv, t)
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
# any number of threads (tests/sim/test_threads.py). Used from PARALLEL_MIN_TETS tets with more than one numba thread
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
        W, g = _tet_energy_gradient(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, prony, relax_a, Gamma,
                                    g_sum)
        tet_W[t] = W
        F = _defgrad(x, tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3], Dm_inv, t)
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
        F = _defgrad(x, i0, i1, i2, i3, Dm_inv, t)
        p, P = _energy_piola(code, F, mu[t], lam[t], eta[t], fibre[t, 0], fibre[t, 1], fibre[t, 2])
        psi[t] = p
        cof = _cofactor(F)
        inv_J = 1.0 / (F[0] * cof[0] + F[1] * cof[1] + F[2] * cof[2])
        for r in range(3):
            for c in range(3):
                # (F^-1)_{rk} = cof_{kr} / J
                S[t, r, c] = (cof[r] * P[c] + cof[3 + r] * P[3 + c] + cof[6 + r] * P[6 + c]) * inv_J
