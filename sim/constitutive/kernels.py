"""Numba per-tet kernels every integrator shares: the deformation gradient, the cofactor, node gradients
and the hyperelastic energy density with its first Piola stress, written in scalars (no array per tet).

Conventions: ``x (n, 3)``, ``tets (m, 4) int``, ``B = Dm_inv (m, 3, 3)``; a 3x3 matrix is a row-major
9-tuple. For ``G = dC/dF`` the node gradients are ``g_k = G b_k`` (k = 1..3, ``b_k`` the rows of Dm^-1)
and ``g_0 = -(g_1 + g_2 + g_3)``.

Materials (``MATERIALS``; the same formulas as ``sim.constitutive.models``, which stays the NumPy reference):

- ``stvk`` — ``E = (F^T F - I)/2``, ``S = 2 mu E + lam tr(E) I``, ``P = F S``,
  ``Psi = mu E:E + lam/2 tr(E)^2`` (Zhang 5.2.5.1);
- ``neo_hookean`` — Zhang eq. 5.35: ``Psi = mu/2 (J^(-2/3) I1 - 3) + kappa/2 (J - 1)^2``,
  ``P = mu J^(-2/3) (F - I1/3 F^-T) + kappa (J - 1) cof F`` with ``kappa = lam + 2 mu / 3``;
- ``stable_neo_hookean`` — Macklin & Müller (2021): ``P = mu F + lam (J - gamma) cof F``,
  ``gamma = 1 + mu / lam``; at lam = 0 (nu = 0) the limit ``lam (J - gamma) = lam (J - 1) - mu -> -mu``;
- ``anisotropic_neo_hookean`` — ``neo_hookean`` plus the fibre term of Zhang 5.37 with the corrected 5.38
  (docs/design.md, "Zhang 5.37/5.38: fibre stress"): ``Psi_f = eta/2 (I4bar - 1)^2``, ``I4bar = J^(-2/3) |F a0|^2``,
  ``P_f = eta (I4bar - 1) J^(-2/3) (2 (F a0) a0^T - 2/3 I4 F^-T)``.

Energies are evaluated from the displacement gradient ``H = F - I`` (``sim.constitutive.models.energy_density_h``
is the NumPy twin): Zhang's multiplier 5.7 divides ``W_k`` by ``|dW_k/dx|^2``, both of which vanish at rest, and
the textbook forms (``J^(-2/3) I1 - 3``, ``(J - gamma)^2 - (1 - gamma)^2``) carry an absolute rounding error
of about ``eps mu`` that does not vanish with the strain: an element at rest to rounding then gets a
multiplier made of rounding noise and moves by a sizeable fraction of its own size (measured on the
480-tet benchmark block: 37 % of the step's largest displacement after one sweep, different between two
equally valid summation orders). With ``H`` the error of ``Psi`` scales with the strain, and the
increments' error stays at rounding level.

``J^(-2/3) = y^2`` with ``y = 1 / cbrt(J)`` and ``J^(-2/3) - 1 = -j (y + 1) / (J (y^2 + y + 1))``
(``j = J - 1``: exact algebra, no cancellation) for ``J > 0``, NaN otherwise (as NumPy's ``J ** (-2/3)``), so an
inverted element of a split model makes the iteration non-finite and the integrator reports it.

No ``fastmath``: the kernels must reproduce the NumPy path to 1e-10 (tests/sim/integrators/ebm/test_kernels.py),
and reassociation would also change which elements' NaN checks fire.
"""
from __future__ import annotations

import numpy as np
from numba import njit

@njit(cache=True, inline="always")
def defgrad(x, i0, i1, i2, i3, B, t):
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
def cofactor(F):
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    return (f11 * f22 - f21 * f12, f12 * f20 - f22 * f10, f10 * f21 - f20 * f11,
            f21 * f02 - f01 * f22, f22 * f00 - f02 * f20, f20 * f01 - f00 * f21,
            f01 * f12 - f11 * f02, f02 * f10 - f12 * f00, f00 * f11 - f10 * f01)


@njit(cache=True, inline="always")
def node_gradients(G, B, t):
    """(g1, g2, g3) as a 9-tuple: g_k[r] = sum_c G[r, c] B[k, c]."""
    g00, g01, g02, g10, g11, g12, g20, g21, g22 = G
    b00, b01, b02 = B[t, 0, 0], B[t, 0, 1], B[t, 0, 2]
    b10, b11, b12 = B[t, 1, 0], B[t, 1, 1], B[t, 1, 2]
    b20, b21, b22 = B[t, 2, 0], B[t, 2, 1], B[t, 2, 2]
    return (g00 * b00 + g01 * b01 + g02 * b02, g10 * b00 + g11 * b01 + g12 * b02, g20 * b00 + g21 * b01 + g22 * b02,
            g00 * b10 + g01 * b11 + g02 * b12, g10 * b10 + g11 * b11 + g12 * b12, g20 * b10 + g21 * b11 + g22 * b12,
            g00 * b20 + g01 * b21 + g02 * b22, g10 * b20 + g11 * b21 + g12 * b22, g20 * b20 + g21 * b21 + g22 * b22)


# material codes, the same numbers as sim.constitutive.models.MODEL_CODES
STVK, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN = 0, 1, 2, 3
MATERIALS = {"stvk": STVK, "neo_hookean": NEO_HOOKEAN, "stable_neo_hookean": STABLE_NEO_HOOKEAN,
             "anisotropic_neo_hookean": ANISOTROPIC_NEO_HOOKEAN}


@njit(cache=True, inline="always")
def j_minus_two_thirds(J, j):
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
def inverse_cube_root(J):
    """J^(-1/3) for normal J > 0 (NaN for J <= 0) without a branch or a libm call, so that a loop over
    lanes vectorises: a seed from the exponent bits (relative error <= 3.4 %), then two steps of
    ``y <- y (1 + r/3 + 2 r^2/9 + 14 r^3/81)`` with ``r = 1 - J y^3`` (the series of ``(1 - r)^(-1/3)``, error
    ~ 35/243 r^4 per step): 3.4e-2 -> 2e-5 -> rounding. Measured against 1 / cbrt(J) over J in
    [1e-260, 1e260]: within 2 u of the exact value (the derivation is in the test)."""
    y = np.int64(_INV_CBRT_MAGIC - np.float64(np.float64(J).view(np.int64)) * (1.0 / 3.0)).view(np.float64)
    for _ in range(2):
        r = 1.0 - J * (y * y * y)
        y = y + y * r * (1.0 / 3.0 + r * (2.0 / 9.0 + r * (14.0 / 81.0)))
    return y if J > 0.0 else np.nan


@njit(cache=True, inline="always")
def j_minus_two_thirds_branch_free(J, j):
    """``j_minus_two_thirds`` with the vectorisable :func:`inverse_cube_root` (NaN for J <= 0 through y)."""
    y = inverse_cube_root(J)
    return y * y, -j / (J * (y * y + y + 1.0)) * (y + 1.0)


@njit(cache=True, inline="always")
def displacement_invariants(F):
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
def energy_piola(code, F, mu, lam, eta, ax, ay, az):
    """(Psi, P as a row-major 9-tuple) of one tet."""
    return energy_piola_root(code, F, mu, lam, eta, ax, ay, az, False)


@njit(cache=True, inline="always")
def energy_piola_root(code, F, mu, lam, eta, ax, ay, az, branch_free):
    """:func:`energy_piola` with the choice of J^(-1/3): ``branch_free`` (a constant at every call site, so the
    compiler drops the other branch) takes :func:`inverse_cube_root`, which lets a loop over lanes vectorise
    (sim.integrators.ebm.blocked); otherwise ``1 / cbrt(J)``."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = F
    if code == STABLE_NEO_HOOKEAN:
        cof = cofactor(F)
        J = f00 * cof[0] + f01 * cof[1] + f02 * cof[2]
        tr, HH, I2, detH = displacement_invariants(F)
        j = tr + I2 + detH
        # mu/2 (I1 - 3) + lam/2 ((J - gamma)^2 - (1 - gamma)^2) = mu/2 (H:H - 2 I2 - 2 det H) + lam/2 j^2
        psi = 0.5 * mu * (HH - 2.0 * I2 - 2.0 * detH) + 0.5 * lam * j * j
        # lam (J - gamma) with gamma = 1 + mu / lam as published (bit for bit as before for lam > 0), and its limit
        # lam (J - 1) - mu -> -mu at lam = 0 (nu = 0) instead of 0 * inf
        s = lam * (J - (1.0 + mu / lam)) if lam > 0.0 else -mu
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
    cof = cofactor(F)
    J = f00 * cof[0] + f01 * cof[1] + f02 * cof[2]
    inv_J = 1.0 / J
    I1 = (f00 * f00 + f01 * f01 + f02 * f02 + f10 * f10 + f11 * f11 + f12 * f12
          + f20 * f20 + f21 * f21 + f22 * f22)
    kappa = lam + 2.0 * mu / 3.0
    tr, HH, I2, detH = displacement_invariants(F)
    j = tr + I2 + detH  # J - 1
    d = 2.0 * tr + HH  # I1 - 3
    if branch_free:
        Jm23, m = j_minus_two_thirds_branch_free(J, j)
    else:
        Jm23, m = j_minus_two_thirds(J, j)
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
