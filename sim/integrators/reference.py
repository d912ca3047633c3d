"""The implicit reference integrator: backward Euler (dynamic) or quasi-static equilibrium, solved by
Newton's method with a backtracking line search and a sparse direct solve (scipy).

Each step minimises the incremental potential over the free nodes (kinematic nodes are placed at
their targets and eliminated; nodes held in some components only are placed on their constraint and solved for in
the basis of their free motion, ``x = x_0 + T y``, which eliminates the held components)::

    dynamic:      Phi(x) = 1/(2 h^2) (x - x~)^T M (x - x~) + E(x) - f_ext . x,   x~ = x_n + h v_n
    quasistatic:  Phi(x) = E(x) - f_ext . x

with the Hessian assembled from element Hessians (``sim.constitutive``) plus ``M / h^2``: the exact
one when its Newton step descends, else the PSD-projected one (per-element eigenvalue clamping). Converged when
``|grad Phi| <= tol * (|grad Phi(x_0)| + |f_ext| + |reactions at x_0| + 1e-12)`` over the free dofs
(default ``tol = 1e-8``). It exists to measure the other integrators, not to be fast.

| name | default | unit | range | equation |
|---|---|---|---|---|
| ``mode`` | "dynamic" | – | "dynamic", "quasistatic" | Phi above |
| ``tol`` | 1e-8 | – | (0, 1e-2] | relative gradient norm at convergence |
| ``max_newton`` | 50 | – | [1, 1000] | Newton iterations per solve |
| ``anp`` | false | – | bool | average nodal pressure (``sim.constitutive.anp``) |
| ``load_steps`` | 1 | – | >= 1 | quasi-static load increments per step |
| ``substeps``, ``iterations`` | 1 | – | >= 1 | ignored (set from the scene's ``[simulation]``) |

``ReferenceSceneSettings`` is the scene's ``[simulation.reference]`` table; ``ReferenceSettings`` adds
``load_steps`` and accepts (and ignores) the scene's ``substeps`` and ``iterations``. Quadratic (10-node) tets:
``sim.integrators.reference_quadratic`` (the same solver, its own element energy).
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from sim.constitutive import anp, elastic, models, tensor
from sim.constitutive.prony import PronyHistory
from sim.errors import SimulationDiverged
from sim.model import Model, State
from sim.settings import Settings

MODES = ("dynamic", "quasistatic")


class ReferenceSceneSettings(Settings):
    """The scene's ``[simulation.reference]`` table."""

    mode: Literal[MODES] = Field("dynamic", description="backward Euler, or quasi-static equilibria")  # type: ignore[valid-type]
    tol: float = Field(1e-8, gt=0.0, le=1e-2, description="Newton tolerance on the relative gradient [-]")
    max_newton: int = Field(50, ge=1, le=1000, description="Newton iterations per solve [-]")
    anp: bool = Field(False, description="average nodal pressure against volumetric locking")


class ReferenceSettings(ReferenceSceneSettings):
    """Every parameter of the ``reference`` integrator (the table in the module docstring)."""

    load_steps: int = Field(1, ge=1, le=10000, description="quasi-static load increments per step [-]")
    substeps: int = Field(1, ge=1, le=1000, description="ignored: Newton solves each step whole")
    iterations: int = Field(1, ge=1, le=10000, description="ignored: see max_newton")


class ReferenceIntegrator:
    name = "reference"

    def __init__(self, model: Model, settings: ReferenceSettings | dict | None = None):
        settings = ReferenceSettings.of(settings)
        self.settings = settings
        self.model = model
        self.mode = settings.mode
        self.tol = settings.tol
        self.max_newton = settings.max_newton
        self.load_steps = settings.load_steps
        if settings.anp:
            anp.check_model(model)
            model.pressure = "anp"
        prony = model.material_params.get("prony")
        self.prony = PronyHistory(prony, model.n_tets) if prony else None
        if self.prony is not None and models.uses_anp(model):
            raise ValueError("reference: Prony viscoelasticity with average nodal pressure is not supported")
        m = model
        idx = np.repeat(m.tets, 3, axis=1) * 3 + np.tile(np.arange(3), 4)[None, :]  # (m, 12) dof ids
        self.rows = np.repeat(idx, 12, axis=1).ravel()
        self.cols = np.tile(idx, (1, 12)).ravel()
        self.mass_dof = np.repeat(m.mass, 3)
        self.partial = model.partial()  # nodes held in some components: solved for in their free-motion basis
        self._basis = None
        self.last_iterations = 0
        self.last_residual = np.inf

    # -- Prony viscoelasticity (Zhang 5.29-5.32): with the incremental update of the history, the
    # relaxed stress of this step is S^ = a S(F) - Gamma, a = 1 - sum A_i, Gamma = sum B_i gamma_i^n,
    # which is the stress of the energy a Psi(F) - Gamma : E(F) (E the Green strain): Newton minimises it.
    def _visco(self, h):
        a, gamma = 1.0, np.zeros((self.model.n_tets, 3, 3))
        for i, (alpha, tau) in enumerate(self.prony.terms):
            a -= h * alpha / (h + tau)
            gamma += tau / (h + tau) * self.prony.gamma[i]
        return a, gamma

    def _elastic_energy(self, x, h):
        m = self.model
        if self.prony is None:
            return elastic.elastic_energy(m, x)
        a, gamma = self._visco(h)
        F = tensor.deformation_gradients(x, m.tets, m.Dm_inv)
        E = 0.5 * (np.swapaxes(F, 1, 2) @ F - np.eye(3))
        return a * elastic.elastic_energy(m, x) - float(np.sum(m.volume * np.einsum("mij,mij->m", gamma, E)))

    def _elastic_gradient(self, x, h):
        m = self.model
        if self.prony is None:
            return elastic.elastic_gradient(m, x)
        a, gamma = self._visco(h)
        F = tensor.deformation_gradients(x, m.tets, m.Dm_inv)
        G = m.volume[:, None, None] * (F @ gamma) @ np.swapaxes(m.Dm_inv, 1, 2)
        g = a * elastic.elastic_gradient(m, x)
        for k in range(3):
            np.add.at(g, m.tets[:, k + 1], -G[:, :, k])
        np.add.at(g, m.tets[:, 0], G.sum(axis=2))
        return g

    def _element_hessians(self, x, h, project):
        m = self.model
        if self.prony is None:
            return elastic.element_hessians(m, x, project=project)
        a, gamma = self._visco(h)
        F = tensor.deformation_gradients(x, m.tets, m.Dm_inv)
        T = tensor.complex_step_jacobian(lambda G: -G @ gamma, F)
        B = tensor.dF_dx(m.Dm_inv)
        H = a * elastic.element_hessians(m, x, project=False)
        H = H + m.volume[:, None, None] * np.matmul(np.matmul(B.transpose(0, 2, 1), T), B)
        return tensor.project_psd(H) if project else H

    def _commit(self, x, h):
        """Advance the Prony history by h with the converged state."""
        if self.prony is None:
            return
        m = self.model
        name, mu, lam, eta, a0 = models.model_params(m)
        F = tensor.deformation_gradients(x, m.tets, m.Dm_inv)
        vl = models.model_curves(m)
        psi = models.energy_density(name, F, mu, lam, eta, a0, vl=vl)
        S = np.linalg.solve(F, models.first_piola(name, F, mu, lam, eta, a0, vl=vl))
        self.prony.commit(S, psi, h)

    def _phi(self, x, x_tilde, h, f_ext):
        e = self._elastic_energy(x, h) - float(np.sum(f_ext * x))
        if self.mode == "dynamic":
            d = (x - x_tilde).ravel()
            e += 0.5 / (h * h) * float(np.sum(self.mass_dof * d * d))
        return e

    def _grad(self, x, x_tilde, h, f_ext):
        g = self._elastic_gradient(x, h) - f_ext
        if self.mode == "dynamic":
            g = g + (self.model.mass[:, None] / (h * h)) * (x - x_tilde)
        return g

    def _hessian(self, x, h, project=True):
        H = self._element_hessians(x, h, project)
        n = 3 * self.model.n_nodes
        K = sp.coo_matrix((H.ravel(), (self.rows, self.cols)), shape=(n, n)).tocsr()
        if models.uses_anp(self.model):
            K = K + anp.coupling_term(self.model, x)
        if self.mode == "dynamic":
            K = K + sp.diags(self.mass_dof / (h * h))
        return K

    def _descent(self, hessian, g, far: bool, t: float, it: int) -> np.ndarray:
        """A Newton direction ``-K^-1 g`` that descends, K = ``hessian(project)`` (the free or reduced block)
        with a tiny diagonal shift; the projected (PSD) Hessian is tried first when ``far`` from equilibrium,
        the exact one first near it, the other if the first gives no descent."""
        for project in ((True, False) if far else (False, True)):
            K = hessian(project)
            K = K + sp.diags(np.full(K.shape[0], 1e-12 * max(abs(K.diagonal()).max(), 1e-300)))
            candidate = self._newton_step(K, g)
            if np.isfinite(candidate).all() and float(g @ candidate) < 0.0:
                return candidate
        raise SimulationDiverged(f"reference: no descent direction at t = {t:.6g} s (iteration {it})")

    def _newton_step(self, K, g):
        """``-K^-1 g`` by a sparse direct solve (``reference_quadratic`` orders its wider element couplings apart)."""
        return -spsolve(K.tocsc(), g)

    def _free_dofs(self, kin: np.ndarray) -> np.ndarray:
        """(3n,) bool: the dofs not of the kinematic nodes ``kin``."""
        free = np.ones(3 * self.model.n_nodes, dtype=bool)
        free[(kin[:, None] * 3 + np.arange(3)).ravel()] = False
        return free

    def solve(self, x0, x_tilde, h, t):
        """Newton on Phi from ``x0`` with kinematic nodes at their targets at time ``t``."""
        m = self.model
        x = x0.copy()
        kin, target = m.kinematic_targets(t)
        x[kin] = target
        free = self._free_dofs(kin)
        f_ext = m.nodal_external_force()
        if not self.partial.empty:
            return self._solve_reduced(x, x_tilde, h, t, free, f_ext)
        g_all = self._grad(x, x_tilde, h, f_ext).ravel()
        g = g_all[free]
        # force scale of the problem: the start residual, the loads and the boundary reactions (so a
        # start that is already in equilibrium is recognised as converged, not measured against itself)
        scale = (np.linalg.norm(g) + np.linalg.norm(f_ext.ravel()[free]) + np.linalg.norm(g_all[~free]) + 1e-12)
        phi = self._phi(x, x_tilde, h, f_ext)
        for it in range(self.max_newton):
            if np.linalg.norm(g) <= self.tol * scale:
                self.last_iterations, self.last_residual = it, float(np.linalg.norm(g) / scale)
                return x
            # The exact Hessian gives quadratic convergence near a minimum; where it is indefinite
            # (compressed stable Neo-Hookean elements) its step may not descend, and the PSD-projected
            # one is used. Far from equilibrium (tangled or inverted starts) the projected Hessian goes
            # first: its steps head for the rest shape instead of stalling in a tangled saddle region.
            far = np.linalg.norm(g) > 1e-3 * scale
            dx = self._descent(lambda project: self._hessian(x, h, project)[free][:, free], g, far, t, it)
            step = 1.0
            gnorm = np.linalg.norm(g)
            for _ in range(40):
                trial = x.copy()
                trial.ravel()[free] += step * dx
                phi_trial = self._phi(trial, x_tilde, h, f_ext)
                if np.isfinite(phi_trial) and phi_trial <= phi + 1e-4 * step * float(g @ dx):
                    break
                # Near convergence the energy change drowns in the cancellation noise of Psi (the
                # terms of Neo-Hookean energy cancel to second order in the strain): accept a step that
                # leaves the energy unchanged to 1e-8 and halves the gradient.
                if np.isfinite(phi_trial) and abs(phi_trial - phi) <= 1e-8 * (abs(phi) + 1e-300):
                    g_trial = self._grad(trial, x_tilde, h, f_ext).ravel()[free]
                    if np.linalg.norm(g_trial) < 0.5 * gnorm:
                        break
                step *= 0.5
            else:
                raise SimulationDiverged(f"reference: line search failed at t = {t:.6g} s (iteration {it})")
            x, phi = trial, phi_trial
            g = self._grad(x, x_tilde, h, f_ext).ravel()[free]
        self.last_iterations, self.last_residual = self.max_newton, float(np.linalg.norm(g) / scale)
        if self.last_residual > 1e3 * self.tol:
            raise SimulationDiverged(f"reference: Newton did not converge at t = {t:.6g} s "
                                     f"(relative gradient {self.last_residual:.2e} after {self.max_newton} iterations)")
        return x

    def _free_basis(self, free):
        """``T`` (3n, r) sparse: the motions the unknowns may make. Unit columns for the dofs of free nodes, the
        orthonormal basis of the free motion (``PartialTargets.free_bases``) for nodes held in some components; a
        Newton step is ``dx = T dy`` and the reduced system ``T^T K T dy = -T^T g`` (the held components
        eliminated)."""
        if self._basis is None:
            p = self.partial
            is_partial = np.zeros(self.model.n_nodes, dtype=bool)
            is_partial[p.nodes] = True
            rows, cols, vals = [], [], []
            col = 0
            bases = dict(zip(p.nodes.tolist(), p.free_bases()))
            for i in range(self.model.n_nodes):
                if is_partial[i]:
                    Q = bases[i]
                    for r in range(Q.shape[1]):
                        rows += [3 * i, 3 * i + 1, 3 * i + 2]
                        cols += [col] * 3
                        vals += Q[:, r].tolist()
                        col += 1
                else:
                    for k in range(3):
                        if free[3 * i + k]:
                            rows.append(3 * i + k)
                            cols.append(col)
                            vals.append(1.0)
                            col += 1
            self._basis = sp.csr_matrix((vals, (rows, cols)), shape=(3 * self.model.n_nodes, col))
        return self._basis

    def _solve_reduced(self, x, x_tilde, h, t, free, f_ext):
        """:meth:`solve` with nodes held in some components: Newton in the coordinates ``y`` of ``x = x_0 + T y``
        (:meth:`_free_basis`), the same convergence test and line search on the reduced gradient ``T^T g``."""
        self.partial.place(x, t)
        T = self._free_basis(free)
        Tt = T.T.tocsr()
        g_all = self._grad(x, x_tilde, h, f_ext).ravel()
        g = Tt @ g_all
        reactions = g_all - T @ g  # the held components' (and kinematic nodes') share of the gradient
        scale = np.linalg.norm(g) + np.linalg.norm(Tt @ f_ext.ravel()) + np.linalg.norm(reactions) + 1e-12
        phi = self._phi(x, x_tilde, h, f_ext)
        for it in range(self.max_newton):
            gnorm = np.linalg.norm(g)
            if gnorm <= self.tol * scale:
                self.last_iterations, self.last_residual = it, float(gnorm / scale)
                return x
            dy = self._descent(lambda project: (Tt @ self._hessian(x, h, project) @ T).tocsc(), g,
                               gnorm > 1e-3 * scale, t, it)
            dx = (T @ dy).reshape(x.shape)
            step = 1.0
            for _ in range(40):
                trial = x + step * dx
                phi_trial = self._phi(trial, x_tilde, h, f_ext)
                if np.isfinite(phi_trial) and phi_trial <= phi + 1e-4 * step * float(g @ dy):
                    break
                if np.isfinite(phi_trial) and abs(phi_trial - phi) <= 1e-8 * (abs(phi) + 1e-300):
                    if np.linalg.norm(Tt @ self._grad(trial, x_tilde, h, f_ext).ravel()) < 0.5 * gnorm:
                        break
                step *= 0.5
            else:
                raise SimulationDiverged(f"reference: line search failed at t = {t:.6g} s (iteration {it})")
            x, phi = trial, phi_trial
            g = Tt @ self._grad(x, x_tilde, h, f_ext).ravel()
        self.last_iterations, self.last_residual = self.max_newton, float(np.linalg.norm(g) / scale)
        if self.last_residual > 1e3 * self.tol:
            raise SimulationDiverged(f"reference: Newton did not converge at t = {t:.6g} s "
                                     f"(relative gradient {self.last_residual:.2e} after {self.max_newton} iterations)")
        return x

    def _predicted(self, x, h, t):
        """``x`` (an equilibrium) with the kinematic nodes moved to their targets at ``t`` and the free nodes by the
        linear response to that move, ``du_f = -K_ff^-1 K_fk du_k`` (K the projected tangent at ``x``): the
        displacement predictor of incremental FE solvers. Placing only the kinematic nodes crushes the element
        layer next to a moved face once the increment exceeds its height (a 0.1 m step on the 0.0625 m nodes
        of the quadratic cylinder inverts it: no descent direction); the predicted start spreads the move over
        the body. ``None`` where nothing moves or nodes are held in some components only."""
        m = self.model
        if not self.partial.empty:
            return None
        kin, target = m.kinematic_targets(t)
        d = np.zeros(3 * m.n_nodes)
        d.reshape(-1, 3)[kin] = target - x[kin]
        if not d.any():
            return None
        free = self._free_dofs(kin)
        K = self._hessian(x, h, True)
        du = self._newton_step(K[free][:, free], K[free][:, ~free] @ d[~free])
        if not np.isfinite(du).all():
            return None
        y = x.copy().ravel()
        y[~free] += d[~free]
        y[free] += du
        return y.reshape(x.shape)

    def _load_path(self, x, t0, t_end):
        """Quasi-static equilibria along the load path, ``load_steps`` increments from ``t0`` to ``t_end``.
        An increment whose Newton solve fails (:meth:`_solve_increment`) is
        halved (down to 1/64 of the initial one); the increment grows back after each success."""
        full = (t_end - t0) / self.load_steps
        inc, t = full, t0
        while t < t_end - 1e-12 * max(abs(t_end), 1.0):
            t_next = min(t + inc, t_end)
            try:
                x = self._solve_increment(x, t_next - t, t_next)
            except SimulationDiverged:
                if inc <= full / 64:
                    raise
                inc *= 0.5
                continue
            t = t_next
            inc = min(2.0 * inc, full)
        return x

    def _solve_increment(self, x, h, t):
        """One load increment's equilibrium from ``x``: Newton from the predicted start (:meth:`_predicted`), from
        the plain one (only the kinematic nodes moved) where there is no prediction or its solve fails. The
        prediction took the quasi-static Newton from 7 to 3 iterations a load step on the quadratic cylinder and
        made the compressed ones solvable at all (docs/report.md, "Cost per unit")."""
        start, y = self._predicted(x, h, t), None
        if start is not None:
            try:
                y = self.solve(start, None, h, t)
            except SimulationDiverged:
                pass
        if y is None:
            y = self.solve(x, None, h, t)
        self._commit(y, h)
        return y

    def step(self, state: State, dt: float) -> State:
        t_end = state.t + dt
        if self.mode == "quasistatic":
            return State(x=self._load_path(state.x, state.t, t_end), v=np.zeros_like(state.x), t=t_end,
                         private=state.private)
        x_tilde = state.x + dt * state.v
        x = self.solve(x_tilde, x_tilde, dt, t_end)
        if not np.isfinite(x).all():
            raise SimulationDiverged(f"reference: non-finite positions at t = {t_end:.6g} s")
        self._commit(x, dt)
        return State(x=x, v=(x - state.x) / dt, t=t_end, private=state.private)
