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
  cof F``. Defined and smooth for inverted F.
- ``valanis_landel`` — curve-defined energies of the principal stretches (Qian 4.15–4.20,
  ``sim.valanis_landel``; the curves come as ``vl=``, from ``model.material_params``).
- ``anisotropic_neo_hookean`` — ``neo_hookean`` plus a fibre term (Zhang eq. 5.37) (Zhang eq. 5.37, DESIGN.md's fix of
  5.38): ``Psi_f = eta/2 (I4bar - 1)^2``, ``I4bar = J^(-2/3) a.C a``; default ``eta = 2 mu``.

With ``volumetric=False`` the split models return only their isochoric part (the volumetric term is
then evaluated on nodal volumes: average nodal pressure, ``sim.anp``).

The tangent is computed by complex-step differentiation of P (Squire & Trapp 1998): exact to
rounding, for every model, with no hand-derived fourth-order tensors to get wrong.
"""
from __future__ import annotations

import numpy as np

MODEL_CODES = {"stvk": 0, "neo_hookean": 1, "stable_neo_hookean": 2, "anisotropic_neo_hookean": 3,
               "valanis_landel": 4}


def _det(F):
    return (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
            - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
            + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))


def cofactor(F):
    """cof F = det(F) F^-T, written with cross products of F's columns (valid for singular F)."""
    f0, f1, f2 = F[:, :, 0], F[:, :, 1], F[:, :, 2]
    return np.stack([np.cross(f1, f2), np.cross(f2, f0), np.cross(f0, f1)], axis=2)


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
    J = _det(F)
    if name == "stvk":
        E = 0.5 * (C - np.eye(3))
        return mu * np.einsum("mij,mij->m", E, E) + 0.5 * lam * np.einsum("mii->m", E) ** 2
    if name == "stable_neo_hookean":
        gamma = 1.0 + mu / lam
        return 0.5 * mu * (I1 - 3.0) + 0.5 * lam * (J - gamma) ** 2 - 0.5 * lam * (1.0 - gamma) ** 2
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
    J = _det(F)
    if name == "stable_neo_hookean":
        gamma = 1.0 + mu / lam
        return mu[m] * F + (lam * (J - gamma))[m] * cof
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


def complex_step_jacobian(fn, F, h: float = 1e-30):
    """d fn(F) / dF as (m, 9, 9) for a (m, 3, 3) -> (m, 3, 3) map analytic in F (complex step)."""
    m = F.shape[0]
    out = np.empty((m, 9, 9))
    Fc = F.astype(np.complex128)
    for col in range(9):
        step = np.zeros((3, 3), np.complex128)
        step.flat[col] = 1j * h
        out[:, :, col] = fn(Fc + step).reshape(m, 9).imag / h
    return out


def project_psd(H):
    """Clamp the negative eigenvalues of symmetric matrices (..., n, n) to zero."""
    w, V = np.linalg.eigh(0.5 * (H + np.swapaxes(H, -1, -2)))
    return np.einsum("...ij,...j,...kj->...ik", V, np.maximum(w, 0.0), V)


def model_curves(model):
    """The Valanis-Landel curves of a ``valanis_landel`` model (``None`` for the other models)."""
    if model.constitutive != "valanis_landel":
        return None
    from sim.valanis_landel import ValanisLandel

    return ValanisLandel.from_params(model.material_params)


def model_params(model):
    """(name, mu, lam, eta, a0) of a :class:`sim.model.Model`."""
    eta = a0 = None
    if model.constitutive == "anisotropic_neo_hookean":
        eta = np.broadcast_to(np.asarray(model.material_params.get("eta", 2.0 * model.mu), float), model.mu.shape)
        a0 = model.fibre if model.fibre is not None else np.tile([0.0, 0.0, 1.0], (model.n_tets, 1))
    return model.constitutive, model.mu, model.lam, eta, a0


def deformation_gradients(x, tets, Dm_inv):
    """F = Ds Dm^-1 per tet."""
    p = x[tets]
    Ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    return Ds @ Dm_inv


def uses_anp(model) -> bool:
    """True when the model's volumetric energy is evaluated on nodal volumes (``sim.anp``)."""
    return getattr(model, "pressure", "element") == "anp"


def elastic_energy(model, x) -> float:
    name, mu, lam, eta, a0 = model_params(model)
    F = deformation_gradients(x, model.tets, model.Dm_inv)
    anp = uses_anp(model)
    e = float(np.sum(model.volume * energy_density(name, F, mu, lam, eta, a0, volumetric=not anp,
                                                    vl=model_curves(model))))
    if anp:
        from sim import anp as anp_module

        e += anp_module.energy(model, x)
    return e


def elastic_gradient(model, x) -> np.ndarray:
    """dE/dx (n, 3): node k = 1..3 of a tet gets V P Dm^-T column k, node 0 minus their sum."""
    name, mu, lam, eta, a0 = model_params(model)
    F = deformation_gradients(x, model.tets, model.Dm_inv)
    anp = uses_anp(model)
    P = first_piola(name, F, mu, lam, eta, a0, volumetric=not anp, vl=model_curves(model))
    G = model.volume[:, None, None] * P @ np.swapaxes(model.Dm_inv, 1, 2)  # (m, 3, 3): columns = nodes 1..3
    g = np.zeros_like(x)
    for k in range(3):
        np.add.at(g, model.tets[:, k + 1], G[:, :, k])
    np.add.at(g, model.tets[:, 0], -G.sum(axis=2))
    if anp:
        from sim import anp as anp_module

        g += anp_module.gradient(model, x)
    return g


def elastic_forces(model, x) -> np.ndarray:
    return -elastic_gradient(model, x)


def dF_dx(Dm_inv):
    """(m, 9, 12): derivative of vec(F) (row-major) with respect to the 12 node coordinates."""
    m = Dm_inv.shape[0]
    B = np.zeros((m, 9, 12))
    weights = np.concatenate([-Dm_inv.sum(axis=1, keepdims=True), Dm_inv], axis=1)  # (m, 4, 3): dF_ij/dx_a,i
    for a in range(4):
        for i in range(3):
            for j in range(3):
                B[:, 3 * i + j, 3 * a + i] = weights[:, a, j]
    return B


def element_hessians(model, x, project: bool = True) -> np.ndarray:
    """(m, 12, 12) Hessians V B^T (dP/dF) B, optionally PSD-projected per element. With average nodal
    pressure this includes the element-local ANP term; the nodal coupling term is ``anp.coupling_term``."""
    name, mu, lam, eta, a0 = model_params(model)
    F = deformation_gradients(x, model.tets, model.Dm_inv)
    B = dF_dx(model.Dm_inv)
    anp = uses_anp(model)
    T = tangent(name, F, mu, lam, eta, a0, volumetric=not anp, vl=model_curves(model))
    H = model.volume[:, None, None] * np.matmul(np.matmul(B.transpose(0, 2, 1), T), B)
    if anp:
        from sim import anp as anp_module

        H = H + anp_module.element_term(model, x)
    return project_psd(H) if project else H
