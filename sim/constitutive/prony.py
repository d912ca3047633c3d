"""Prony-series viscoelasticity (Zhang eqs. 5.29–5.32), as an incremental per-tet history.

The relaxation function ``alpha(t) = 1 - sum_i alpha_i (1 - exp(-t / tau_i))`` turns the elastic
second Piola stress S into ``S^ = S - sum_i gamma_i`` (5.31), and each history term obeys the
incremental update below 5.32::

    gamma_i^t = A_i S^t + B_i gamma_i^(t - dt),   A_i = dt alpha_i / (dt + tau_i),   B_i = tau_i / (dt + tau_i)

(a backward-Euler discretisation of ``tau_i d(gamma_i)/dt + gamma_i = alpha_i S``). The same kernel
applied to the energy density (5.29) gives ``Psi^ = Psi - sum_i g_i`` with the same update. Under a
step strain held constant, ``S^`` relaxes from S towards the long-term ``(1 - sum alpha_i) S``.
``terms`` are ``[(alpha_1, tau_1), ...]`` with ``sum alpha_i < 1`` and ``tau_i > 0`` [s].
"""
from __future__ import annotations

import numpy as np


def check_terms(terms) -> list[tuple[float, float]]:
    terms = [(float(a), float(t)) for a, t in terms]
    if any(not (0.0 <= a < 1.0) or not t > 0.0 for a, t in terms) or sum(a for a, _ in terms) >= 1.0:
        raise ValueError(f"Prony terms must have 0 <= alpha_i, sum alpha_i < 1 and tau_i > 0 s, found {terms}")
    return terms


class PronyHistory:
    """History ``gamma_i`` (stress) and ``g_i`` (energy) per tet for each Prony term."""

    def __init__(self, terms, n_tets: int):
        self.terms = check_terms(terms)
        self.gamma = np.zeros((len(self.terms), n_tets, 3, 3))
        self.g = np.zeros((len(self.terms), n_tets))

    def relaxed(self, S: np.ndarray, psi: np.ndarray, dt: float):
        """(S^, Psi^) for the current elastic S and Psi, *without* committing the history."""
        gamma, g = self._advance(S, psi, dt)
        return S - gamma.sum(axis=0), psi - g.sum(axis=0)

    def commit(self, S: np.ndarray, psi: np.ndarray, dt: float) -> None:
        """Advance the history by dt with the converged S and Psi of this step."""
        self.gamma, self.g = self._advance(S, psi, dt)

    def _advance(self, S, psi, dt):
        gamma = np.empty_like(self.gamma)
        g = np.empty_like(self.g)
        for i, (alpha, tau) in enumerate(self.terms):
            A, B = dt * alpha / (dt + tau), tau / (dt + tau)
            gamma[i] = A * S + B * self.gamma[i]
            g[i] = A * psi + B * self.g[i]
        return gamma, g
