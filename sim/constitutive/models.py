"""Constitutive models shared by every integrator: energy density Psi(F), first Piola stress P(F) and
the tangent dP/dF, vectorised over tets (arrays ``F (m, 3, 3)``, per-tet ``mu, lam (m,)``).

Models (``MODEL_CODES``):

- ``stvk`` — St Venant–Kirchhoff: ``E = (F^T F - I)/2``, ``Psi = mu E:E + lam/2 tr(E)^2``, ``P = F S``.
- ``neo_hookean`` — Zhang eq. 5.35 (ABAQUS C10 = mu/2, D1 = 2/kappa), isochoric/volumetric split:
  ``Psi = mu/2 (I1bar - 3) + kappa/2 (J - 1)^2``, ``I1bar = J^(-2/3) I1``, ``kappa = lam + 2 mu / 3``;
  ``P = mu J^(-2/3) (F - I1/3 F^-T) + kappa (J - 1) cof F`` (Zhang 5.36 pushed forward). Undefined for
  J <= 0.
- ``stable_neo_hookean`` — Macklin & Müller (2021), the form XPBD uses:
  ``Psi = mu/2 (I_C - 3) + lam/2 (J - gamma)^2 - lam/2 (1 - gamma)^2`` with ``gamma = 1 + mu/lam`` so
  the rest state is stress free (the last constant makes Psi(I) = 0); ``P = mu F + lam (J - gamma)
  cof F``. Defined and smooth for inverted F. At lam = 0 (nu = 0) it takes the limit instead of 0 * inf:
  ``lam/2 ((J - gamma)^2 - (1 - gamma)^2) = lam/2 (J - 1)^2 - mu (J - 1) -> -mu (J - 1)`` and
  ``lam (J - gamma) = lam (J - 1) - mu -> -mu`` (exact algebra); for lam > 0 the published form, unchanged.
  Its small-strain limit is linear elasticity with Lamé parameters ``(lam - mu, mu)``: the bulk modulus
  ``lam - mu/3`` is positive only for nu > 1/8, below which the rest state is a saddle and a body collapses
  (:func:`require_stable_rest`).
- ``valanis_landel`` — curve-defined energies of the principal stretches (Qian 4.15–4.20,
  ``sim.constitutive.valanis_landel``; the curves come as ``vl=``, from ``model.material_params``).
- ``anisotropic_neo_hookean`` — ``neo_hookean`` plus a fibre term (Zhang eq. 5.37, with 5.38 corrected: docs/design.md,
  "Zhang 5.37/5.38: fibre stress"): ``Psi_f = eta/2 (I4bar - 1)^2``, ``I4bar = J^(-2/3) a.C a``; default ``eta = 2 mu``.

With ``volumetric=False`` the split models return only their isochoric part (the volumetric term is
then evaluated on nodal volumes: average nodal pressure, ``sim.constitutive.anp``).

The tangent is computed by complex-step differentiation of P (Squire & Trapp 1998): exact to
rounding, for every model, with no hand-derived fourth-order tensors to get wrong.
"""
from __future__ import annotations

import numpy as np

from sim.constitutive.tensor import cofactor, complex_step_jacobian, det
from sim.constitutive.valanis_landel import ValanisLandel

MODEL_CODES = {"stvk": 0, "neo_hookean": 1, "stable_neo_hookean": 2, "anisotropic_neo_hookean": 3,
               "valanis_landel": 4}


SPLIT_MODELS = ("neo_hookean", "anisotropic_neo_hookean")


def bulk_modulus(mu, lam):
    """kappa = lam + 2 mu / 3 [Pa]."""
    return lam + 2.0 * mu / 3.0


def energy_density(name: str, F, mu, lam, eta=None, a0=None, volumetric: bool = True, vl=None):
    """Psi per tet [J/m^3]."""
    if name == "valanis_landel":
        return vl.energy(F)
    C = np.einsum("mki,mkj->mij", F, F)
    I1 = np.einsum("mii->m", C)
    J = det(F)
    if name == "stvk":
        E = 0.5 * (C - np.eye(3))
        return mu * np.einsum("mij,mij->m", E, E) + 0.5 * lam * np.einsum("mii->m", E) ** 2
    if name == "stable_neo_hookean":
        with np.errstate(divide="ignore", invalid="ignore"):
            gamma = 1.0 + mu / lam
            psi = 0.5 * mu * (I1 - 3.0) + 0.5 * lam * (J - gamma) ** 2 - 0.5 * lam * (1.0 - gamma) ** 2
        return np.where(lam > 0.0, psi, 0.5 * mu * (I1 - 3.0) - mu * (J - 1.0))  # the lam -> 0 limit
    if name in SPLIT_MODELS:
        with np.errstate(invalid="ignore", divide="ignore"):
            Jm23 = J ** (-2.0 / 3.0)
        psi = 0.5 * mu * (Jm23 * I1 - 3.0)
        if volumetric:
            psi = psi + 0.5 * bulk_modulus(mu, lam) * (J - 1.0) ** 2
        if name == "anisotropic_neo_hookean":
            I4 = np.einsum("mi,mij,mj->m", a0, C, a0)
            psi = psi + 0.5 * eta * (Jm23 * I4 - 1.0) ** 2
        return psi
    raise KeyError(f"unknown constitutive model {name!r}; expected one of {', '.join(MODEL_CODES)}")


def energy_density_h(name: str, F, mu, lam, eta=None, a0=None, vl=None):
    """Psi per tet [J/m^3] evaluated from the displacement gradient H = F - I: the NumPy twin of the numba
    ``sim.constitutive.kernels.energy_piola`` that the EBM multiplier uses.

    The same energies as :func:`energy_density` (the reference form), kept as a second form because their rounding
    error must scale with the strain: 5.7 divides W_k by |dW_k/dx|^2 and both vanish at rest, so the textbook forms'
    absolute error of about eps mu turns elements at rest to rounding into noise-driven increments
    (docs/ebm.md, "Energies near rest"). ``J - 1 = tr H + I2(H) + det H``, ``I1 - 3 = 2 tr H + H:H``,
    ``J^(-2/3) - 1 = (y - 1)(y + 1)`` with ``y = J^(-1/3)`` and ``y - 1 = -j / (J (y^2 + y + 1))``, j = J - 1;
    NaN for J <= 0 in the split models.
    """
    if name not in ("neo_hookean", "anisotropic_neo_hookean", "stable_neo_hookean"):
        return energy_density(name, F, mu, lam, eta, a0, vl=vl)
    H = F - np.eye(3)
    tr = np.einsum("mii->m", H)
    HH = np.einsum("mij,mij->m", H, H)
    I2 = 0.5 * (tr * tr - np.einsum("mij,mji->m", H, H))
    detH = det(H)
    j = tr + I2 + detH
    if name == "stable_neo_hookean":
        return 0.5 * mu * (HH - 2.0 * I2 - 2.0 * detH) + 0.5 * lam * j * j
    J = 1.0 + j
    with np.errstate(invalid="ignore", divide="ignore"):
        y = np.where(J > 0.0, 1.0 / np.cbrt(J), np.nan)  # J^(-1/3)
        m = -j / (J * (y * y + y + 1.0)) * (y + 1.0)  # J^(-2/3) - 1 = (y - 1)(y + 1), y - 1 = -j / (J (y^2 + y + 1))
    d = 2.0 * tr + HH
    psi = 0.5 * mu * (3.0 * m + d + m * d) + 0.5 * bulk_modulus(mu, lam) * j * j
    if name == "anisotropic_neo_hookean":
        Ha = np.einsum("mij,mj->mi", H, a0)
        q = 2.0 * np.einsum("mi,mi->m", a0, Ha) + np.einsum("mi,mi->m", Ha, Ha) + (np.einsum("mi,mi->m", a0, a0) - 1.0)
        dbar = m * (1.0 + q) + q
        psi = psi + 0.5 * eta * dbar * dbar
    return psi


def first_piola(name: str, F, mu, lam, eta=None, a0=None, volumetric: bool = True, vl=None):
    """P = dPsi/dF per tet (m, 3, 3) [Pa]. Works on complex F (for the complex-step tangent)."""
    if name == "valanis_landel":
        return vl.piola(F)
    m = (slice(None), None, None)
    if name == "stvk":
        C = np.einsum("mki,mkj->mij", F, F)
        E = 0.5 * (C - np.eye(3))
        S = 2.0 * mu[m] * E + lam[m] * np.einsum("mii->m", E)[m] * np.eye(3)
        return F @ S
    cof = cofactor(F)
    J = det(F)
    if name == "stable_neo_hookean":
        with np.errstate(divide="ignore", invalid="ignore"):
            gamma = 1.0 + mu / lam
            s = np.where(lam > 0.0, lam * (J - gamma), -mu)  # lam (J - 1) - mu -> -mu as lam -> 0
        return mu[m] * F + s[m] * cof
    if name in SPLIT_MODELS:
        FinvT = cof / J[m]
        Jm23 = J ** (-2.0 / 3.0)
        I1 = np.einsum("mij,mij->m", F, F)
        P = (mu * Jm23)[m] * (F - (I1 / 3.0)[m] * FinvT)
        if volumetric:
            P = P + (bulk_modulus(mu, lam) * (J - 1.0))[m] * cof
        if name == "anisotropic_neo_hookean":
            C = np.einsum("mki,mkj->mij", F, F)
            I4 = np.einsum("mi,mij,mj->m", a0, C, a0)
            # dI4bar/dF = J^(-2/3) (2 F a a^T - 2/3 I4 F^-T)
            dI4bar = Jm23[m] * (2.0 * np.einsum("mij,mj,mk->mik", F, a0, a0) - (2.0 / 3.0) * I4[m] * FinvT)
            P = P + (eta * (Jm23 * I4 - 1.0))[m] * dI4bar
        return P
    raise KeyError(f"unknown constitutive model {name!r}; expected one of {', '.join(MODEL_CODES)}")


def tangent(name: str, F, mu, lam, eta=None, a0=None, h: float = 1e-30, volumetric: bool = True, vl=None):
    """dP/dF as (m, 9, 9) (row = P_ij, column = F_kl, row-major), by complex step."""
    if name == "valanis_landel":
        return vl.tangent(F)
    return complex_step_jacobian(lambda G: first_piola(name, G, mu, lam, eta, a0, volumetric), F, h)


def model_curves(model):
    """The Valanis-Landel curves of a ``valanis_landel`` model (``None`` for the other models)."""
    if model.constitutive != "valanis_landel":
        return None
    return ValanisLandel.from_params(model.material_params)


def model_params(model):
    """(name, mu, lam, eta, a0) of a :class:`sim.model.Model`."""
    eta = a0 = None
    if model.constitutive == "anisotropic_neo_hookean":
        # a writable copy, never broadcast_to's read-only view: the numba kernels then see one array type
        # (one compile) whether eta was given per element or derived from mu
        eta = np.array(np.broadcast_to(np.asarray(model.material_params.get("eta", 2.0 * model.mu), float),
                                       model.mu.shape))
        a0 = model.fibre if model.fibre is not None else np.tile([0.0, 0.0, 1.0], (model.n_tets, 1))
    return model.constitutive, model.mu, model.lam, eta, a0


# the stable Neo-Hookean rest state is a minimum only where its bulk modulus lam - mu/3 > 0, i.e. nu > 1/8
STABLE_NEO_HOOKEAN_MIN_NU = 0.125


def require_stable_rest(model, law: str = "the stable Neo-Hookean energy") -> None:
    """Raise ValueError when ``law`` (Macklin & Müller's stable Neo-Hookean with the model's Lamé ``lam``, ``mu``)
    has no stable rest state in some tet: linearised at F = I it is linear elasticity with Lamé parameters
    ``(lam - mu, mu)``, whose bulk modulus ``lam - mu/3`` is not positive for nu <= 1/8 (nu = 0 included), and
    such a body collapses (measured: a 10 cm cube under gravity reaches J = 6e-4 at nu = 0.12, J = 0.90 at 0.15)."""
    bad = np.flatnonzero(np.asarray(model.nu) <= STABLE_NEO_HOOKEAN_MIN_NU)
    if bad.size:
        t = int(bad[0])
        raise ValueError(
            f"{law} has a stable rest state only for nu > 1/8 (its small-strain bulk modulus lam - mu/3 must be "
            f"positive); found nu = {float(model.nu[t]):g} in {bad.size} tet(s) (first: tet {t}); use nu > 0.125 "
            "or a material with another constitutive model")


def uses_anp(model) -> bool:
    """True when the model's volumetric energy is evaluated on nodal volumes (``sim.constitutive.anp``)."""
    return getattr(model, "pressure", "element") == "anp"
