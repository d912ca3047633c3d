"""XPBD with any hyperelastic energy of the constitutive library as one constraint per tet,
``C = sqrt(2 V Psi)`` with compliance 1 (so ``C^2 / 2 = V Psi``: Macklin & Müller 2021, Qian §4.4).

``grad C = V P(F) : dF/dx / C``. Gauss-Seidel over the graph colours, each colour vectorised in NumPy
(tets of a colour share no node); slower than the stable Neo-Hookean numba kernels but it honours the
material: Zhang's Neo-Hookean 5.35, the anisotropic fibre term, St Venant-Kirchhoff, Valanis-Landel
curves. Tets whose energy is undefined (J <= 0 for the log/J^(-2/3) forms) are left alone in that
sweep; ``C`` is not differentiable at rest, so tets with ``C < 1e-12`` are skipped too.

A Prony branch (``sim.xpbd_prony``) is the same constraint with its own rest matrix ``Dm^-1 Fv^-1``
(``Dm_inv=``) and its energy weighted by ``a_i`` (``weight=``: ``C = sqrt(2 weight V Psi)``).
"""
from __future__ import annotations

import numpy as np

from sim import constitutive


class EnergyConstraints:
    def __init__(self, model, order: np.ndarray, colour_start: np.ndarray, Dm_inv: np.ndarray | None = None,
                 weight: float = 1.0):
        name, mu, lam, eta, a0 = constitutive.model_params(model)
        self.name = name
        self.vl = constitutive.model_curves(model)
        self.tets = model.tets[order]
        self.Dm_inv = model.Dm_inv[order] if Dm_inv is None else Dm_inv
        self.volume = weight * model.volume[order]
        self.mu, self.lam = mu[order], lam[order]
        self.eta = None if eta is None else np.asarray(eta)[order]
        self.a0 = None if a0 is None else np.asarray(a0)[order]
        self.colour_start = colour_start

    def sweep(self, x: np.ndarray, lam: np.ndarray, w: np.ndarray, inv_dt2: float) -> None:
        """One Gauss-Seidel sweep over all colours; ``lam`` holds the multipliers (colour order)."""
        for c in range(self.colour_start.size - 1):
            sl = slice(self.colour_start[c], self.colour_start[c + 1])
            tets = self.tets[sl]
            F = constitutive.deformation_gradients(x, tets, self.Dm_inv[sl])
            eta = None if self.eta is None else self.eta[sl]
            a0 = None if self.a0 is None else self.a0[sl]
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                psi = constitutive.energy_density(self.name, F, self.mu[sl], self.lam[sl], eta, a0, vl=self.vl)
                P = constitutive.first_piola(self.name, F, self.mu[sl], self.lam[sl], eta, a0, vl=self.vl)
            V = self.volume[sl]
            C = np.sqrt(np.maximum(2.0 * V * psi, 0.0))
            ok = np.isfinite(C) & np.isfinite(P).all(axis=(1, 2)) & (C > 1e-12)
            if not ok.any():
                continue
            G = (V / np.where(ok, C, 1.0))[:, None, None] * P @ np.swapaxes(self.Dm_inv[sl], 1, 2)
            grads = np.empty((tets.shape[0], 4, 3))
            grads[:, 1:] = np.swapaxes(G, 1, 2)
            grads[:, 0] = -G.sum(axis=2)
            wt = w[tets]
            denom = np.einsum("ka,kad,kad->k", wt, grads, grads) + inv_dt2
            dl = np.where(ok, (-C - inv_dt2 * lam[sl]) / denom, 0.0)
            lam[sl] += dl
            for a in range(4):
                x[tets[:, a]] += (wt[:, a] * dl)[:, None] * grads[:, a]  # no node repeats within a colour
