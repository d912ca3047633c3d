"""Average nodal pressure (ANP) linear tets against volumetric locking (Bonet & Burton 1998; the
treatment Zhang §2.2.1 cites through Joldes et al.'s improved ANP).

Linear tets with nu -> 0.5 lock: one volume constraint per element over-constrains the mesh. ANP
evaluates the volumetric energy of the split models (Zhang eq. 5.35, ``kappa/2 (J - 1)^2``) on
*nodal* volumes instead of element volumes::

    V_a = sum_{t ∋ a} V_t / 4,    v_a = sum_{t ∋ a} v_t / 4,    J_a = v_a / V_a
    E_vol = sum_a V_a kappa_a / 2 (J_a - 1)^2,       kappa_a = sum_{t ∋ a} V_t kappa_t / (4 V_a)

where ``v_t = V_t det F_t`` is a tet's current volume. The isochoric part stays per element. This is
an energy, so its gradient is exact and the reference integrator minimises it like any other:

    dE_vol/dx = sum_t p_t dv_t/dx,   p_t = 1/4 sum_{a ∈ t} kappa_a (J_a - 1)   (the averaged pressure)
    d2E_vol/dx2 = sum_a V_a kappa_a dJ_a/dx (dJ_a/dx)^T + sum_t p_t d2v_t/dx2

The first Hessian term couples the nodes of a node's patch (a sparse ``G^T D G``, positive
semi-definite); the second is element-local.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from sim.constitutive import models, tensor


def check_model(model) -> None:
    if model.constitutive not in models.SPLIT_MODELS:
        raise ValueError(f"average nodal pressure needs a model with a volumetric split "
                         f"({', '.join(models.SPLIT_MODELS)}), found {model.constitutive!r}")


def _nodal(model, x):
    """(V_a, kappa_a, J_a, F, cof F) for the current positions."""
    n = model.n_nodes
    quarter = np.repeat(model.volume / 4.0, 4)
    V_a = np.bincount(model.tets.ravel(), weights=quarter, minlength=n)
    kappa_t = models.bulk_modulus(model.mu, model.lam)
    kappa_a = np.bincount(model.tets.ravel(), weights=np.repeat(model.volume * kappa_t / 4.0, 4), minlength=n)
    kappa_a = kappa_a / np.maximum(V_a, 1e-300)
    F = tensor.deformation_gradients(x, model.tets, model.Dm_inv)
    J_t = tensor.det(F)
    v_a = np.bincount(model.tets.ravel(), weights=np.repeat(model.volume * J_t / 4.0, 4), minlength=n)
    J_a = v_a / np.maximum(V_a, 1e-300)
    return V_a, kappa_a, J_a, F


def energy(model, x) -> float:
    V_a, kappa_a, J_a, _ = _nodal(model, x)
    return float(np.sum(0.5 * V_a * kappa_a * (J_a - 1.0) ** 2))


def _volume_gradients(model, F):
    """dv_t/dx per tet as (m, 4, 3): v_t = V_t det F_t, dv/dF = V_t cof F."""
    G = model.volume[:, None, None] * tensor.cofactor(F) @ np.swapaxes(model.Dm_inv, 1, 2)
    return tensor.node_gradients(G)


def gradient(model, x) -> np.ndarray:
    """dE_vol/dx (n, 3)."""
    _, kappa_a, J_a, F = _nodal(model, x)
    p_t = (kappa_a * (J_a - 1.0))[model.tets].mean(axis=1)
    g_t = p_t[:, None, None] * _volume_gradients(model, F)
    out = np.zeros_like(x)
    for k in range(4):
        np.add.at(out, model.tets[:, k], g_t[:, k])
    return out


def volume_hessians(model, F, h: float = 1e-30) -> np.ndarray:
    """(m, 12, 12) d2v_t/dx2 = V_t B^T d(cof F)/dF B, the derivative of cof F by complex step."""
    T = tensor.complex_step_jacobian(tensor.cofactor, F, h)
    B = tensor.dF_dx(model.Dm_inv)
    return model.volume[:, None, None] * np.matmul(np.matmul(B.transpose(0, 2, 1), T), B)


def element_term(model, x) -> np.ndarray:
    """(m, 12, 12) p_t d2v_t/dx2, the element-local part of the ANP Hessian."""
    _, kappa_a, J_a, F = _nodal(model, x)
    p_t = (kappa_a * (J_a - 1.0))[model.tets].mean(axis=1)
    return p_t[:, None, None] * volume_hessians(model, F)


def coupling_term(model, x) -> sp.csr_matrix:
    """sum_a V_a kappa_a dJ_a/dx (dJ_a/dx)^T as a sparse (3n, 3n) matrix (positive semi-definite)."""
    n = model.n_nodes
    V_a, kappa_a, _, F = _nodal(model, x)
    g_t = _volume_gradients(model, F).reshape(-1, 12)  # dv_t/dx over the tet's 12 dofs
    dofs = (np.repeat(model.tets, 3, axis=1) * 3 + np.tile(np.arange(3), 4)[None, :])  # (m, 12)
    rows = np.repeat(model.tets, 12, axis=1)  # (m, 48): node a of the tet, for each of 12 dofs
    cols = np.tile(dofs, (1, 4))
    vals = (np.repeat(0.25 / np.maximum(V_a[model.tets], 1e-300), 12, axis=1) * np.tile(g_t, (1, 4)))
    G = sp.coo_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(n, 3 * n)).tocsr()
    return (G.T @ sp.diags(V_a * kappa_a) @ G).tocsr()
