"""Tensor maths on stacks of 3x3 matrices ``F (m, 3, 3)``: determinant, cofactor, deformation gradients,
their derivative with respect to node positions, complex-step Jacobians and the PSD projection."""
from __future__ import annotations

import numpy as np


def det(F):
    """det F per matrix of a stack (m, 3, 3), written out (works on complex F)."""
    return (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
            - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
            + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))


def cofactor(F):
    """cof F = det(F) F^-T, written with cross products of F's columns (valid for singular F)."""
    f0, f1, f2 = F[:, :, 0], F[:, :, 1], F[:, :, 2]
    return np.stack([np.cross(f1, f2), np.cross(f2, f0), np.cross(f0, f1)], axis=2)


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


def deformation_gradients(x, tets, Dm_inv):
    """F = Ds Dm^-1 per tet."""
    p = x[tets]
    Ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    return Ds @ Dm_inv


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


def node_gradients(G):
    """(m, 4, 3) gradients on a tet's four nodes from ``G = dE/dF Dm^-T`` (m, 3, 3): node k = 1..3 gets column k,
    node 0 minus their sum."""
    g = np.empty((G.shape[0], 4, 3))
    g[:, 1:, :] = np.swapaxes(G, 1, 2)
    g[:, 0, :] = -G.sum(axis=2)
    return g
