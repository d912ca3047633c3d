"""A body's elastic energy, its gradient (minus the internal forces) and the element Hessians, from the NumPy
reference models of ``sim.constitutive.models`` (and average nodal pressure, ``sim.constitutive.anp``)."""
from __future__ import annotations

import numpy as np

from sim.constitutive import anp
from sim.constitutive.models import energy_density, first_piola, model_curves, model_params, tangent, uses_anp
from sim.constitutive.tensor import dF_dx, deformation_gradients, project_psd


def elastic_energy(model, x) -> float:
    name, mu, lam, eta, a0 = model_params(model)
    F = deformation_gradients(x, model.tets, model.Dm_inv)
    nodal_pressure = uses_anp(model)
    e = float(np.sum(model.volume * energy_density(name, F, mu, lam, eta, a0, volumetric=not nodal_pressure,
                                                    vl=model_curves(model))))
    if nodal_pressure:
        e += anp.energy(model, x)
    return e


def elastic_gradient(model, x) -> np.ndarray:
    """dE/dx (n, 3): node k = 1..3 of a tet gets V P Dm^-T column k, node 0 minus their sum."""
    name, mu, lam, eta, a0 = model_params(model)
    F = deformation_gradients(x, model.tets, model.Dm_inv)
    nodal_pressure = uses_anp(model)
    P = first_piola(name, F, mu, lam, eta, a0, volumetric=not nodal_pressure, vl=model_curves(model))
    G = model.volume[:, None, None] * P @ np.swapaxes(model.Dm_inv, 1, 2)  # (m, 3, 3): columns = nodes 1..3
    g = np.zeros_like(x)
    for k in range(3):
        np.add.at(g, model.tets[:, k + 1], G[:, :, k])
    np.add.at(g, model.tets[:, 0], -G.sum(axis=2))
    if nodal_pressure:
        g += anp.gradient(model, x)
    return g


def elastic_forces(model, x) -> np.ndarray:
    """Internal nodal forces -dE/dx (n, 3) [N]."""
    return -elastic_gradient(model, x)


def element_hessians(model, x, project: bool = True) -> np.ndarray:
    """(m, 12, 12) Hessians V B^T (dP/dF) B, optionally PSD-projected per element. With average nodal
    pressure this includes the element-local ANP term; the nodal coupling term is ``anp.coupling_term``."""
    name, mu, lam, eta, a0 = model_params(model)
    F = deformation_gradients(x, model.tets, model.Dm_inv)
    B = dF_dx(model.Dm_inv)
    nodal_pressure = uses_anp(model)
    T = tangent(name, F, mu, lam, eta, a0, volumetric=not nodal_pressure, vl=model_curves(model))
    H = model.volume[:, None, None] * np.matmul(np.matmul(B.transpose(0, 2, 1), T), B)
    if nodal_pressure:
        H = H + anp.element_term(model, x)
    return project_psd(H) if project else H
