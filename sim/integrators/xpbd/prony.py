"""Prony viscoelasticity for XPBD: generalised Maxwell branches as rest-shape drift.

The relaxation function of Zhang eqs. 5.29–5.32, ``g(t) = 1 - sum_i a_i (1 - exp(-t / tau_i))``, is the
response of a long-term spring ``1 - sum_i a_i`` in parallel with one Maxwell branch per Prony term
(stiffness ``a_i``, relaxation time ``tau_i``). Here each branch keeps a viscous deformation ``Fv_i`` per
tet and the strain energy is

    Psi^(F) = (1 - sum_i a_i) Psi(F) + sum_i a_i Psi(F Fv_i^-1)

so each branch is an ordinary hyperelastic constraint set: the same stable Neo-Hookean constraints
(or the model's own energy) with rest matrix ``Dm^-1 Fv_i^-1`` and compliances divided by ``a_i`` (the
long-term set's by ``1 - sum a_i``). After every step the viscous deformations drift towards the
current stretch with the exact exponential update of a Maxwell element under the step's strain,

    Fv_i <- U + (Fv_i - U) exp(-dt / tau_i),      U = sqrt(F^T F)  (the right stretch of F = R U),

which on the small-strain level is ``eps_v <- eps + (eps_v - eps) exp(-dt/tau)``: under a strain held
from t = 0 the branch stress decays as ``a_i exp(-t/tau_i)`` and the total follows g(t) exactly.
Relaxing towards ``U`` rather than ``F`` keeps the branches objective (a rigid rotation ``F = R`` has
``U = I`` and leaves ``Fv`` and the energy unchanged); ``Fv`` stays symmetric positive definite (a
convex combination of SPD matrices starting from I), so ``Fv^-1`` exists. The update moves every
branch towards its own rest state and never raises the branch energies at small strain (it scales
``eps - eps_v`` by ``exp(-dt/tau) < 1``): it only dissipates.

Differences from the reference integrator's Prony form (``sim.constitutive.prony``, 5.31 on the second Piola stress
with the backward-Euler coefficients A_i, B_i): the same linear viscoelastic limit, where the reference's
``B_i^n`` stands for ``exp(-t / tau_i)``; with alpha = 0.5, tau = 0.58 s the two relaxation curves differ by
at most 0.16 % of the instantaneous stress at dt = 0.01 s (0.26 % at 1/60 s, 0.77 % at 0.05 s).
"""
from __future__ import annotations

import numpy as np

from sim.constitutive import tensor
from sim.constitutive.prony import check_terms


def right_stretch(F: np.ndarray) -> np.ndarray:
    """``U = sqrt(F^T F)`` per tet (m, 3, 3), symmetric positive semi-definite (also for inverted F)."""
    C = np.swapaxes(F, 1, 2) @ F
    eigenvalues, Q = np.linalg.eigh(C)
    root = np.sqrt(np.maximum(eigenvalues, 0.0))
    return (Q * root[:, None, :]) @ np.swapaxes(Q, 1, 2)


class MaxwellBranches:
    """Viscous deformations ``Fv (n_terms, m, 3, 3)`` of the Prony branches of one body; per-tet data
    (``tets``, ``Dm_inv``) in the integrator's order.

    Parameters
    ----------
    terms : ``[(a_1, tau_1 [s]), ...]`` with ``a_i >= 0``, ``sum a_i < 1``, ``tau_i > 0``.
    tets, Dm_inv : the tets and their inverse rest shape matrices.
    """

    def __init__(self, terms, tets: np.ndarray, Dm_inv: np.ndarray):
        self.terms = check_terms(terms)
        self.weights = np.array([a for a, _ in self.terms])
        self.tau = np.array([t for _, t in self.terms])
        self.long_term = 1.0 - float(self.weights.sum())
        self.tets = tets
        self.Dm_inv = Dm_inv
        self.Fv = np.broadcast_to(np.eye(3), (len(self.terms), tets.shape[0], 3, 3)).copy()

    def rest_matrix(self, branch: int) -> np.ndarray:
        """``Dm^-1 Fv_i^-1`` (m, 3, 3): F times it is the branch's elastic deformation ``F Fv_i^-1``."""
        return np.ascontiguousarray(self.Dm_inv @ np.linalg.inv(self.Fv[branch]))

    def relax(self, x: np.ndarray, dt: float) -> None:
        """Advance every branch by ``dt`` with the current positions (the exact exponential update)."""
        U = right_stretch(tensor.deformation_gradients(x, self.tets, self.Dm_inv))
        for i, tau in enumerate(self.tau):
            self.Fv[i] = U + (self.Fv[i] - U) * np.exp(-dt / tau)

    def sets(self):
        """``[(weight, rest matrix), ...]``: the long-term set first, then one per branch."""
        return [(self.long_term, self.Dm_inv)] + [(float(a), self.rest_matrix(i)) for i, a in enumerate(self.weights)]
