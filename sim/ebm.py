"""``ebm``: the Energy Balance Method (Zhang ch. 5).

Each step (our reading of the lost eq. 5.15 and Fig. 5.1; docs/ebm.md):

1. prediction with the external force, ``x <- x^t + h (v^t + h f_ext / m)`` (5.13); kinematic nodes
   placed at their targets;
2. ``iterations`` times: per tet, the strain energy ``W_k = V_k Psi(F_k)`` and its nodal gradients
   ``dW_k/dx = V_k F S D_X^-T`` (5.10 in its corrected form), the multiplier
   ``lambda_k = W_k / sum_j w_j |dW_k/dx_j|^2`` (5.7, with the inverse masses w_j in the
   denominator), the increments ``dx_{i,k} = -w_i lambda_k dW_k/dx_i`` (5.8), summed per node (5.9) and
   applied (5.14). ``update = "average"`` (default) divides a node's sum by the number of tets that
   contribute to it, so that the simultaneous (Jacobi) increments cannot overshoot; ``"sum"`` is
   the thesis's literal 5.9;
3. velocity from the position change, ``v = (x - x^t) / h`` (our reading of 5.15).

It is position-based dynamics with each element's energy as a zero-compliance constraint: the
iterations lower every element's energy towards the configuration the boundary conditions allow.
Displacement-controlled loads (prescribed nodes) stay in balance because those nodes do not move;
external forces act through the prediction only (5.13), once per step, so a force-loaded body's
equilibrium depends on h and the iteration count — we report it, we do not hide it.

Viscoelasticity (Prony series, ``model.material_params["prony"] = [(alpha, tau), ...]``) replaces S
and Psi by their relaxed values (5.29–5.32, ``sim.prony``); the history advances once per step.
The relative energy difference ``RED = |W_ext - W_strain| / W_ext`` is recorded per step in
``red_history``: W_ext is the work done on the body by the reactions at prescribed nodes and by
external forces (trapezoidal in time), W_strain the stored strain energy.
Settings: ``iterations`` (default 100), ``substeps``, ``update`` ("average" | "sum").
"""
from __future__ import annotations

import numpy as np

from sim import constitutive
from sim.integrators import SimulationDiverged
from sim.model import Model, State
from sim.prony import PronyHistory

UPDATES = ("average", "sum")


class EBM:
    name = "ebm"

    def __init__(self, model: Model, settings: dict):
        if constitutive.uses_anp(model):
            raise ValueError("ebm: average nodal pressure is not supported (element energies only)")
        self.model = model
        self.iterations = int(settings.get("iterations", 100))
        self.substeps = int(settings.get("substeps", 1))
        self.update = settings.get("update", "average")
        if self.update not in UPDATES:
            raise ValueError(f"ebm: update must be one of {', '.join(UPDATES)}, found {self.update!r}")
        self.w = model.inverse_mass()
        counts = np.bincount(model.tets.ravel(), minlength=model.n_nodes).astype(np.float64)
        self.node_scale = 1.0 / np.maximum(counts, 1.0) if self.update == "average" else np.ones(model.n_nodes)
        prony = model.material_params.get("prony")
        self.prony = PronyHistory(prony, model.n_tets) if prony else None
        self.f_ext = model.nodal_external_force()
        self.red_history: list[float] = []
        self.work_in = 0.0
        self._last_load_force = model.nodal_external_force()  # at rest: no reaction yet
        self._last_kin_x = None

    # -- element energies and gradients -------------------------------------------------------------
    def _stress(self, x, h, commit=False):
        """(W_k, nodal gradients (m, 4, 3), P) with the viscoelastic relaxation when configured."""
        m = self.model
        name, mu, lam, eta, a0 = constitutive.model_params(m)
        F = constitutive.deformation_gradients(x, m.tets, m.Dm_inv)
        with np.errstate(invalid="ignore", divide="ignore"):
            vl = constitutive.model_curves(m)
            psi = constitutive.energy_density(name, F, mu, lam, eta, a0, vl=vl)
            P = constitutive.first_piola(name, F, mu, lam, eta, a0, vl=vl)
        if self.prony is not None:
            S = np.linalg.solve(F, P)  # second Piola S = F^-1 P
            if commit:
                self.prony.commit(S, psi, h)
                return None
            S_hat, psi = self.prony.relaxed(S, psi, h)
            P = F @ S_hat
        G = m.volume[:, None, None] * P @ np.swapaxes(m.Dm_inv, 1, 2)  # columns: nodes 1..3
        grads = np.empty((m.n_tets, 4, 3))
        grads[:, 1:, :] = np.swapaxes(G, 1, 2)
        grads[:, 0, :] = -G.sum(axis=2)
        return m.volume * psi, grads, P

    def nodal_forces(self, x, h=1.0):
        """Internal forces -sum_k dW_k/dx per node (with the current viscoelastic relaxation)."""
        _, grads, _ = self._stress(x, h)
        f = np.zeros_like(x)
        for a in range(4):
            np.add.at(f, self.model.tets[:, a], -grads[:, a])
        return f

    def _iterate(self, x, h):
        m = self.model
        tets = m.tets
        wt = self.w[tets]  # (m, 4)
        for _ in range(self.iterations):
            W, grads, _ = self._stress(x, h)
            denom = np.einsum("ma,mad,mad->m", wt, grads, grads)
            lam = np.where(denom > 1e-300, W / np.where(denom > 1e-300, denom, 1.0), 0.0)
            dx = np.zeros_like(x)
            for a in range(4):
                np.add.at(dx, tets[:, a], -(wt[:, a] * lam)[:, None] * grads[:, a])
            x += dx * self.node_scale[:, None]
            if not np.isfinite(x).all():
                raise SimulationDiverged("ebm: non-finite positions during the energy-balance iterations")
        return x

    # -- one step -------------------------------------------------------------------------------------
    def step(self, state: State, dt: float) -> State:
        m = self.model
        h = dt / self.substeps
        x, v, t = state.x.copy(), state.v.copy(), state.t
        for _ in range(self.substeps):
            x_old = x.copy()
            x = x + h * (v + h * self.f_ext * self.w[:, None])  # 5.13
            t += h
            kin, target = m.kinematic_targets(t)
            x_kin_before = x_old[kin]
            x[kin] = target
            x = self._iterate(x, h)  # 5.7-5.9, 5.14
            v = (x - x_old) / h  # 5.15 (our reading)
            self._account_energy(x, x_old, kin, x_kin_before, h)
            if self.prony is not None:
                self._stress(x, h, commit=True)
        return State(x=x, v=v, t=t, private=state.private)

    def _account_energy(self, x, x_old, kin, x_kin_before, h):
        """Accumulate the external work (trapezoidal) and record the relative energy difference."""
        f_int = self.nodal_forces(x, h)
        load = np.zeros_like(x)
        load[kin] = -f_int[kin]  # the reaction the prescribed nodes exert on the body
        load += self.f_ext
        dx = x - x_old
        previous = self._last_load_force
        self.work_in += 0.5 * float(np.sum((load + previous) * dx))
        self._last_load_force = load
        W_strain, _, _ = self._stress(x, h)
        strain = float(np.sum(W_strain))
        self.red_history.append(abs(self.work_in - strain) / max(abs(self.work_in), 1e-300))
