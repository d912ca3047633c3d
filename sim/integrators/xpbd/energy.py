"""XPBD with any hyperelastic energy of the constitutive library as one constraint per tet,
``C = sqrt(2 V Psi)`` with compliance 1 (so ``C^2 / 2 = V Psi``: Macklin & Müller 2021, Qian §4.4).

``grad C = V P(F) : dF/dx / C``. Gauss-Seidel over the graph colours (tets of a colour share no node). It
honours the material: Zhang's Neo-Hookean 5.35, the anisotropic fibre term, St Venant-Kirchhoff (a numba
kernel, ``energy_sweeps``, with the energies and stresses of ``sim.constitutive.kernels.energy_piola``: Psi from
the displacement gradient, so without the rounding error of ``I1 - 3`` near rest), and Valanis-Landel
curves (NumPy, each colour vectorised: the curves are splines evaluated in Python). A tet whose energy or stress
is not finite (an inverted tet, J <= 0, of the log/J^(-2/3) forms) stops the step with
:class:`sim.errors.SimulationDiverged` naming it, instead of staying inverted unseen; ``C`` is not differentiable at
rest, so tets with ``C < 1e-12`` are skipped.

A Prony branch (``sim.integrators.xpbd.prony``) is the same constraint with its own rest matrix ``Dm^-1 Fv^-1``
(``Dm_inv=``) and its energy weighted by ``a_i`` (``weight=``: ``C = sqrt(2 weight V Psi)``).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from sim.constitutive import models, tensor
from sim.constitutive.kernels import MATERIALS, defgrad, energy_piola, node_gradients
from sim.errors import SimulationDiverged
from sim.integrators.xpbd.kernels import PARALLEL_MIN_TETS, apply_correction, weighted_dot


@njit(cache=True, inline="always")
def _project_energy(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, w, multiplier, inv_dt2, nonfinite):
    """One tet's ``C = sqrt(2 V Psi)`` (compliance 1, ``alpha~ = inv_dt2``); where Psi or P is not finite (J <= 0
    for the split models) the tet is flagged in ``nonfinite`` and left as it is; skipped where ``C <= 1e-12``, as in
    the NumPy sweep."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    F = defgrad(x, i0, i1, i2, i3, Dm_inv, t)
    psi, P = energy_piola(code, F, mu[t], lam[t], eta[t], fibre[t, 0], fibre[t, 1], fibre[t, 2])
    finite = np.isfinite(psi)
    for k in range(9):
        finite = finite and np.isfinite(P[k])
    if not finite:
        nonfinite[t] = True
        return
    V = volume[t]
    C = np.sqrt(max(2.0 * V * psi, 0.0))
    if not C > 1e-12:
        return
    s = V / C
    g = node_gradients((s * P[0], s * P[1], s * P[2], s * P[3], s * P[4], s * P[5], s * P[6], s * P[7], s * P[8]),
                    Dm_inv, t)
    w0, w1, w2, w3 = w[i0], w[i1], w[i2], w[i3]
    denom = weighted_dot(g, g, w0, w1, w2, w3) + inv_dt2
    dl = (-C - inv_dt2 * multiplier[t]) / denom
    multiplier[t] += dl
    apply_correction(x, i0, i1, i2, i3, w0, w1, w2, w3, g, dl)


@njit(cache=True, parallel=True)
def energy_sweeps(x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, w, multiplier, inv_dt2, colour_start,
                  iterations, nonfinite):
    """``iterations`` coloured Gauss-Seidel sweeps of the energy constraints (per-tet data in colour order,
    ``code`` from ``sim.constitutive.kernels.MATERIALS``); ``nonfinite (m,) bool`` flags the tets whose energy or
    stress was not finite (each thread writes only its own tets' flags)."""
    for _ in range(iterations):
        for c in range(colour_start.shape[0] - 1):
            lo = colour_start[c]
            hi = colour_start[c + 1]
            if hi - lo < PARALLEL_MIN_TETS:
                for t in range(lo, hi):
                    _project_energy(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, w, multiplier, inv_dt2,
                                    nonfinite)
            else:
                for t in prange(lo, hi):
                    _project_energy(t, x, tets, Dm_inv, volume, mu, lam, eta, fibre, code, w, multiplier, inv_dt2,
                                    nonfinite)


class EnergyConstraints:
    """The energy constraints of one body (or one Prony branch), per-tet data in the integrator's colour
    order. ``kernel``: "numba" (default where the material has a numba form) or "numpy"."""

    def __init__(self, model, order: np.ndarray, colour_start: np.ndarray, Dm_inv: np.ndarray | None = None,
                 weight: float = 1.0, kernel: str | None = None):
        name, mu, lam, eta, a0 = models.model_params(model)
        self.name = name
        if kernel is None:
            kernel = "numba" if name in MATERIALS else "numpy"
        if kernel not in ("numba", "numpy") or (kernel == "numba" and name not in MATERIALS):
            raise ValueError(f"xpbd energy kernel {kernel!r} is not available for material {name!r}")
        self.kernel = kernel
        self.vl = models.model_curves(model)
        self.order = order
        self.tets = model.tets[order]
        self.Dm_inv = model.Dm_inv[order] if Dm_inv is None else Dm_inv
        self.volume = weight * model.volume[order]
        self.mu, self.lam = mu[order], lam[order]
        self.eta = None if eta is None else np.asarray(eta)[order]
        self.a0 = None if a0 is None else np.asarray(a0)[order]
        self.colour_start = colour_start
        if self.kernel == "numba":
            m = self.tets.shape[0]
            self.numba_args = (np.ascontiguousarray(self.tets, dtype=np.int64), np.ascontiguousarray(self.Dm_inv),
                               np.ascontiguousarray(self.volume), np.ascontiguousarray(self.mu),
                               np.ascontiguousarray(self.lam),
                               np.zeros(m) if self.eta is None else np.ascontiguousarray(self.eta, dtype=np.float64),
                               np.zeros((m, 3)) if self.a0 is None else np.ascontiguousarray(self.a0, dtype=np.float64),
                               MATERIALS[name])

    def sweeps(self, x: np.ndarray, lam: np.ndarray, w: np.ndarray, inv_dt2: float, iterations: int) -> None:
        """``iterations`` Gauss-Seidel sweeps over all colours; ``lam`` holds the multipliers (colour order)."""
        nonfinite = np.zeros(self.tets.shape[0], dtype=np.bool_)
        if self.kernel == "numba":
            energy_sweeps(x, *self.numba_args, w, lam, inv_dt2, self.colour_start, iterations, nonfinite)
        else:
            for _ in range(iterations):
                self.sweep(x, lam, w, inv_dt2, nonfinite)
        if nonfinite.any():
            self.report(x, nonfinite)

    def report(self, x: np.ndarray, nonfinite: np.ndarray) -> None:
        """Raise :class:`SimulationDiverged` naming the first flagged tet (by its index in the model)."""
        bad = np.flatnonzero(nonfinite)
        first = bad[np.argmin(self.order[bad])]
        F = tensor.deformation_gradients(x, self.tets[first:first + 1], self.Dm_inv[first:first + 1])
        J = float(np.linalg.det(F)[0]) if np.isfinite(F).all() else float("nan")
        raise SimulationDiverged(
            f"xpbd (material = 'model', {self.name}): tet {int(self.order[first])} has a non-finite energy or stress "
            f"(J = {J:.3g}{', inverted' if J <= 0.0 else ''}; {bad.size} tet(s) in all)")

    def sweep(self, x: np.ndarray, lam: np.ndarray, w: np.ndarray, inv_dt2: float,
              nonfinite: np.ndarray | None = None) -> None:
        """One NumPy Gauss-Seidel sweep over all colours; ``lam`` holds the multipliers (colour order); tets whose
        energy or stress is not finite are flagged in ``nonfinite`` (colour order) and left as they are."""
        for c in range(self.colour_start.size - 1):
            sl = slice(self.colour_start[c], self.colour_start[c + 1])
            tets = self.tets[sl]
            F = tensor.deformation_gradients(x, tets, self.Dm_inv[sl])
            eta = None if self.eta is None else self.eta[sl]
            a0 = None if self.a0 is None else self.a0[sl]
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                psi = models.energy_density(self.name, F, self.mu[sl], self.lam[sl], eta, a0, vl=self.vl)
                P = models.first_piola(self.name, F, self.mu[sl], self.lam[sl], eta, a0, vl=self.vl)
            V = self.volume[sl]
            C = np.sqrt(np.maximum(2.0 * V * psi, 0.0))
            finite = np.isfinite(psi) & np.isfinite(P).all(axis=(1, 2))
            if nonfinite is not None:
                nonfinite[sl] |= ~finite
            ok = finite & (C > 1e-12)
            if not ok.any():
                continue
            G = (V / np.where(ok, C, 1.0))[:, None, None] * P @ np.swapaxes(self.Dm_inv[sl], 1, 2)
            grads = tensor.node_gradients(G)
            wt = w[tets]
            denom = np.einsum("ka,kad,kad->k", wt, grads, grads) + inv_dt2
            dl = np.where(ok, (-C - inv_dt2 * lam[sl]) / denom, 0.0)
            lam[sl] += dl
            for a in range(4):
                x[tets[:, a]] += (wt[:, a] * dl)[:, None] * grads[:, a]  # no node repeats within a colour
