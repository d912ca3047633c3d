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

With the split Neo-Hookean models (5.35, 5.37: undefined for J <= 0) the velocity term of the prediction is shortened
(by 0.9 at a time) until no element is inverted (``sim.integrators.ebm.kernels.uninverting_fraction``; docs/design.md,
"Zhang ch. 5: EBM"): the velocity of sweeps that have not converged carries their wander, and extrapolating it can
invert an element, on which every later sweep would fail. ``shortened_predictions`` lists ``(t, alpha)`` of each step
where it did; a step whose full prediction inverts nothing is unchanged.

It is position-based dynamics with each element's energy as a zero-compliance constraint: the
iterations lower every element's energy towards the configuration the boundary conditions allow.
Displacement-controlled loads (prescribed nodes) stay in balance because those nodes do not move;
external forces act through the prediction only (5.13), once per step, so a force-loaded body's
equilibrium depends on h and the iteration count — we report it, we do not hide it.

Viscoelasticity (Prony series, ``model.material_params["prony"] = [(alpha, tau), ...]``) replaces S
and Psi by their relaxed values (5.29–5.32, ``sim.constitutive.prony``); the history advances once per step.
The relative energy difference ``RED = |W_ext - W_strain| / W_ext`` is recorded per step in
``red_history``: W_ext is the work done on the body by the reactions at prescribed nodes and by
external forces (trapezoidal in time), W_strain the stored strain energy.
Nodes held in some components only (``sim.model.PartialTargets``) are projected onto their constraint after every
iteration (with the scalar kernel: a model with such nodes does not take the blocked one).
Parameters: :class:`sim.integrators.ebm.settings.EBMSettings` (the table of its module docstring). ``kernel``:
"blocked" (default: each substep in one compiled call with the per-tet work vectorised across tets,
``sim.integrators.ebm.blocked_step``); "numba": the scalar per-tet kernel of ``sim.integrators.ebm.kernels``, which
the blocked kernel is tested against to 1e-10; "numpy": the vectorised NumPy reference below, which the scalar kernel
is tested against to 1e-10. Valanis–Landel materials always take the NumPy path (their curves are not compiled).
``precision = "float32"``: with the blocked kernel, the per-tet lane loops (sweeps and energy accounting) in float32
(``sim.integrators.ebm.blocked_f32``; Neo-Hookean and anisotropic Neo-Hookean without Prony only); its deviation from
float64 is measured in docs/ebm.md: as large as a 1e-13 m perturbation of a float64 run on the Zhang 5.3.2 cases, so
not the default. With more than one numba thread, meshes of ``sim.integrators.ebm.blocked.PARALLEL_MIN_TETS`` tets or
more run the blocked sweeps on all threads, bit-identical to one thread (docs/ebm.md, "Two threads").
"""
from __future__ import annotations

import numba
import numpy as np

from sim.constitutive import force_kernels, models, tensor
from sim.constitutive.kernels import MATERIALS
from sim.constitutive.prony import PronyHistory
from sim.errors import SimulationDiverged
from sim.integrators.ebm import blocked as ebm_blocked
from sim.integrators.ebm import blocked_step
from sim.integrators.ebm import kernels as ebm_kernels
from sim.integrators.ebm.settings import EBMSettings
from sim.model import Model, State



MAX_STRETCH = 10.0  # |F|_F / sqrt(3) above this after a step: no tissue does that, the iterations failed
# the prediction's backtracking on the velocity (sim.integrators.ebm.kernels.uninverting_fraction): the first of
# 0.9^k that inverts nothing, so little more of the motion is removed than must be (measured on the Zhang 5.3.2
# cylinder at 20 iterations: halving left the stored energy above the spread of the runs that need no cut, 0.9 inside
# it); down to 0.9^200 ~ 7e-10, where the velocity no longer matters
PREDICTION_BACKTRACK = 0.9
PREDICTION_BACKTRACKS = 200


class EBM:
    name = "ebm"

    def __init__(self, model: Model, settings: EBMSettings | dict | None = None):
        settings = EBMSettings.of(settings)
        self.settings = settings
        if models.uses_anp(model):
            raise ValueError("ebm: average nodal pressure is not supported (element energies only)")
        E_ratio = float(model.E.max() / model.E.min())
        if E_ratio > 1.0 + 1e-9:
            raise ValueError(
                f"ebm: Young's modulus varies between elements (max/min = {E_ratio:.3g}), but the energy-balance "
                f"increments (Zhang 5.7-5.8) do not depend on an element's stiffness scale (W_k and dW_k/dx scale "
                f"together), so EBM cannot represent heterogeneous stiffness; use xpbd or reference")
        self.model = model
        self.iterations = settings.iterations
        self.substeps = settings.substeps
        self.update = settings.update
        self.kernel = settings.kernel if model.constitutive in MATERIALS else "numpy"
        self.partial = model.partial()
        if not self.partial.empty and self.kernel == "blocked":
            # nodes held in some components are projected onto their constraint after every iteration, which the
            # blocked kernel (all iterations in one compiled call) cannot do: the scalar kernel, one call per iteration
            self.kernel = "numba"
        self.precision = settings.precision
        if self.precision == "float32" and (self.kernel != "blocked" or model.material_params.get("prony")
                                            or model.constitutive not in ("neo_hookean", "anisotropic_neo_hookean")):
            raise ValueError("ebm: precision float32 needs kernel blocked and neo_hookean or anisotropic_neo_hookean "
                             f"without Prony terms (found kernel {self.kernel!r}, material {model.constitutive!r})")
        self.w = model.inverse_mass()
        counts = np.bincount(model.tets.ravel(), minlength=model.n_nodes).astype(np.float64)
        self.node_scale = 1.0 / np.maximum(counts, 1.0) if self.update == "average" else np.ones(model.n_nodes)
        prony = model.material_params.get("prony")
        self.prony = PronyHistory(prony, model.n_tets) if prony else None
        self.f_ext = model.nodal_external_force()
        self.red_history: list[float] = []
        # the prediction is kept from inverting elements only where the energy is undefined for J <= 0
        self._guard_prediction = model.constitutive in models.SPLIT_MODELS
        self._kinematic = model.kinematic()
        self._prediction_scratch = np.zeros((model.n_nodes, 3))
        self._guard_tets = np.ascontiguousarray(model.tets, dtype=np.int64)
        self.shortened_predictions: list[tuple[float, float]] = []
        self.work_in = 0.0
        self._last_load_force = model.nodal_external_force()  # at rest: no reaction yet
        if self.kernel != "numpy":
            self._prepare_kernels()
        if self.kernel == "blocked":
            self._prepare_blocked()

    # -- numba kernels (sim.integrators.ebm.kernels) --------------------------------------------------------------
    def _prepare_kernels(self):
        """Contiguous per-tet arrays for the kernels and the Prony coefficients' scratch."""
        m = self.model
        name, mu, lam, eta, a0 = models.model_params(m)
        self._code = MATERIALS[name]
        self._tets = np.ascontiguousarray(m.tets, dtype=np.int64)
        self._Dm_inv = np.ascontiguousarray(m.Dm_inv, dtype=np.float64)
        self._volume = np.ascontiguousarray(m.volume, dtype=np.float64)
        self._mu = np.ascontiguousarray(mu, dtype=np.float64)
        self._lam = np.ascontiguousarray(lam, dtype=np.float64)
        self._eta = np.ascontiguousarray(np.zeros(m.n_tets) if eta is None else eta, dtype=np.float64)
        self._fibre = np.ascontiguousarray(np.zeros((m.n_tets, 3)) if a0 is None else a0, dtype=np.float64)
        self._w = np.ascontiguousarray(self.w, dtype=np.float64)
        self._node_scale = np.ascontiguousarray(self.node_scale, dtype=np.float64)
        self._dx = np.zeros((m.n_nodes, 3))
        self._f = np.zeros((m.n_nodes, 3))
        # Prony: S^ = a S - Gamma within a step (sim.integrators.ebm.kernels); placeholders when elastic
        self._relax = (1.0, np.zeros((1, 3, 3)), np.zeros(1))
        self._relax_h = None

    def _prepare_blocked(self):
        """Block layout, incidence lists and boundary data of ``sim.integrators.ebm.blocked``."""
        m = self.model
        kinematic = m.kinematic_mask()
        (self._node_index, self._params, self._free_nodes, self._free_start, self._free_slot, self._kin_nodes,
         self._kin_start, self._kin_slot) = ebm_blocked.pack(self._tets, self._Dm_inv, self._volume, self._mu,
                                                             self._lam, self._eta, self._fibre, self._w, m.n_nodes,
                                                             ~kinematic)
        n_blocks = self._node_index.shape[0]
        self._out = np.zeros((n_blocks, ebm_blocked.N_OUT * ebm_blocked.LANES))
        self._corners = np.zeros((n_blocks, ebm_blocked.N_OUT * ebm_blocked.LANES))
        self._relax_blocks = np.zeros((1, ebm_blocked.N_RELAX * ebm_blocked.LANES))
        # kinematic targets: the model's one routine (Model.kinematic; its nodes are pack's kin_nodes), evaluated
        # inside the step kernel
        kin = m.kinematic()
        self._kin_group, self._kin_displacement = kin.group, kin.displacement
        self._group_t0, self._group_t1 = kin.t_start, kin.t_end
        self._X = np.ascontiguousarray(m.X, dtype=np.float64)
        self._blocked_scale = self._node_scale * self._w  # the sweep's lane loop leaves w_k out of its increments
        single = self.precision == "float32"
        self._params32 = self._params.astype(np.float32) if single else np.zeros((1, 1), np.float32)
        self._out32 = np.zeros(self._out.shape if single else (1, 1), np.float32)
        self._corners32 = np.zeros(self._corners.shape if single else (1, 1), np.float32)
        self._f_ext = np.ascontiguousarray(self.f_ext, dtype=np.float64)
        self._last_load_force = np.ascontiguousarray(self._last_load_force, dtype=np.float64)
        # compiled (on first use) for this material, Prony and precision only; the two-thread variant only when a
        # step takes it (a mesh of PARALLEL_MIN_TETS tets or more and more than one numba thread)
        self._step_kernel, self._sweeps_kernel = blocked_step.variant(self._code, self.prony is not None, single)
        self._large = m.n_tets >= ebm_blocked.PARALLEL_MIN_TETS
        # the step kernel's argument groups that do not change between steps (blocked_step.step)
        self._step_body = (self._X, self._f_ext, self._w, self._last_load_force)
        self._step_kinematic = (self._kin_nodes, self._kin_group, self._kin_displacement, self._group_t0,
                                self._group_t1, self._kin_start, self._kin_slot)
        self._step_blocks32 = (self._params32, self._out32, self._corners32)

    def _blocked_kernels(self):
        """``(step, sweeps, threads)``: the two-thread variant on a large mesh when numba has more than one thread
        (the results do not depend on the choice: sim.integrators.ebm.blocked, tests/sim/integrators/test_threads.py)."""
        threads = numba.get_num_threads() if self._large else 1
        if threads == 1:
            return self._step_kernel, self._sweeps_kernel, 1
        step, sweeps = blocked_step.variant(self._code, self.prony is not None, self.precision == "float32", True)
        return step, sweeps, threads

    def _relaxation(self, h):
        """(a, Gamma, g) of the current Prony history for a step h: ``S^ = a S - Gamma``, ``Psi^ = a Psi - g``."""
        if self.prony is None:
            return False, self._relax
        if self._relax_h != h:  # the history changed (commit) or h did
            a = 1.0
            Gamma = np.zeros(self.prony.gamma.shape[1:])
            g = np.zeros(self.prony.g.shape[1:])
            for i, (alpha, tau) in enumerate(self.prony.terms):
                A, B = h * alpha / (h + tau), tau / (h + tau)
                a -= A
                Gamma += B * self.prony.gamma[i]
                g += B * self.prony.g[i]
            self._relax = (a, np.ascontiguousarray(Gamma), g)
            self._relax_h = h
            if self.kernel == "blocked":
                self._relax_blocks = ebm_blocked.pack_relaxation(Gamma, g, self._node_index.shape[0])
        return True, self._relax

    def _kernel_args(self, h):
        prony, (a, Gamma, g) = self._relaxation(h)
        return (self._tets, self._Dm_inv, self._volume, self._mu, self._lam, self._eta, self._fibre, self._code,
                prony, a, Gamma, g)

    def _forces_and_energy(self, x, h):
        """(internal forces (n, 3), total strain energy [J], largest element stretch |F|_F / sqrt(3)) with the
        current viscoelastic relaxation."""
        if self.kernel == "numpy":
            W, _, _ = self._stress(x, h)
            F = tensor.deformation_gradients(x, self.model.tets, self.model.Dm_inv)
            stretch = float(np.sqrt(np.einsum("mij,mij->m", F, F).max() / 3.0))
            return self.nodal_forces(x, h), float(np.sum(W)), stretch
        f = np.empty_like(x)
        energy, stretch = force_kernels.forces_and_energy(np.ascontiguousarray(x), f, *self._kernel_args(h))
        return f, float(energy), float(stretch)

    def _commit_prony(self, x, h):
        if self.kernel == "numpy":
            self._stress(x, h, commit=True)
            return
        m = self.model
        S = np.empty((m.n_tets, 3, 3))
        psi = np.empty(m.n_tets)
        force_kernels.elastic_stress(np.ascontiguousarray(x), S, psi, self._tets, self._Dm_inv, self._mu, self._lam,
                                   self._eta, self._fibre, self._code)
        self.prony.commit(S, psi, h)
        self._relax_h = None

    # -- element energies and gradients -------------------------------------------------------------
    def _stress(self, x, h, commit=False):
        """(W_k, nodal gradients (m, 4, 3), P) with the viscoelastic relaxation when configured."""
        m = self.model
        name, mu, lam, eta, a0 = models.model_params(m)
        F = tensor.deformation_gradients(x, m.tets, m.Dm_inv)
        with np.errstate(invalid="ignore", divide="ignore"):
            vl = models.model_curves(m)
            psi = models.energy_density_h(name, F, mu, lam, eta, a0, vl=vl)
            P = models.first_piola(name, F, mu, lam, eta, a0, vl=vl)
        if self.prony is not None:
            S = np.linalg.solve(F, P)  # second Piola S = F^-1 P
            if commit:
                self.prony.commit(S, psi, h)
                return None
            S_hat, psi = self.prony.relaxed(S, psi, h)
            P = F @ S_hat
        G = m.volume[:, None, None] * P @ np.swapaxes(m.Dm_inv, 1, 2)  # columns: nodes 1..3
        return m.volume * psi, tensor.node_gradients(G), P

    def nodal_forces(self, x, h=1.0):
        """Internal forces -sum_k dW_k/dx per node (with the current viscoelastic relaxation)."""
        if self.kernel != "numpy":
            return self._forces_and_energy(x, h)[0]
        _, grads, _ = self._stress(x, h)
        f = np.zeros_like(x)
        for a in range(4):
            np.add.at(f, self.model.tets[:, a], -grads[:, a])
        return f

    def _iterate(self, x, h, t=0.0):
        if self.kernel == "blocked":
            x = np.ascontiguousarray(x, dtype=np.float64)
            _, (a, _, _) = self._relaxation(h)
            _, sweeps, threads = self._blocked_kernels()
            if self.precision == "float32":
                done = sweeps(x, self._X, self._node_index, self._params32, self._out32, self._corners32,
                              self._free_nodes, self._free_start, self._free_slot, self._blocked_scale,
                              self.iterations, threads)
            else:
                done = sweeps(x, self._node_index, self._params, self._relax_blocks, self._out, self._corners,
                              self._free_nodes, self._free_start, self._free_slot, self._blocked_scale, a,
                              self.iterations, threads)
            if done < self.iterations:
                raise SimulationDiverged("ebm: non-finite positions during the energy-balance iterations")
            return x
        if self.kernel == "numba":
            x = np.ascontiguousarray(x)
            prony, (a, Gamma, g) = self._relaxation(h)
            calls, per_call = (1, self.iterations) if self.partial.empty else (self.iterations, 1)
            done = 0
            for _ in range(calls):
                done += ebm_kernels.ebm_iterations(x, self._dx, self._tets, self._Dm_inv, self._volume, self._mu,
                                                   self._lam, self._eta, self._fibre, self._code, self._w,
                                                   self._node_scale, prony, a, Gamma, g, per_call)
                self.partial.place(x, t)
            if done < self.iterations:
                raise SimulationDiverged("ebm: non-finite positions during the energy-balance iterations")
            return x
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
            self.partial.place(x, t)
            if not np.isfinite(x).all():
                raise SimulationDiverged("ebm: non-finite positions during the energy-balance iterations")
        return x

    # -- one step -------------------------------------------------------------------------------------
    def step(self, state: State, dt: float) -> State:
        if self.kernel == "blocked":
            return self._step_blocked(state, dt)
        m = self.model
        h = dt / self.substeps
        x, v, t = state.x.copy(), state.v.copy(), state.t
        for _ in range(self.substeps):
            x_old = x.copy()
            t += h
            x = x + h * (self._prediction_fraction(x, v, h, t) * v + h * self.f_ext * self.w[:, None])  # 5.13
            kin, target = m.kinematic_targets(t)
            x_kin_before = x_old[kin]
            x[kin] = target
            self.partial.place(x, t)
            x = self._iterate(x, h, t)  # 5.7-5.9, 5.14
            v = (x - x_old) / h  # 5.15 (our reading)
            stretch = self._account_energy(x, x_old, kin, x_kin_before, h)
            self._check_stretch(stretch, t)
            if self.prony is not None:
                self._commit_prony(x, h)
        return State(x=x, v=v, t=t, private=state.private)

    def _step_blocked(self, state: State, dt: float) -> State:
        """``step`` with each substep in one compiled call (``sim.integrators.ebm.blocked_step.step``)."""
        h = dt / self.substeps
        x = np.ascontiguousarray(state.x, dtype=np.float64)
        v = np.ascontiguousarray(state.v, dtype=np.float64)
        t = state.t
        shape = x.shape
        kernel, _, threads = self._blocked_kernels()
        for _ in range(self.substeps):
            x_old, v_old = x, v
            x, v = np.empty(shape), np.empty(shape)
            t += h
            alpha = self._prediction_fraction(x_old, v_old, h, t)
            if alpha != 1.0:  # the kernel then predicts from alpha v, as uninverting_fraction checked
                v_old = alpha * v_old
            a = 1.0 if self.prony is None else self._relaxation(h)[1][0]
            blocks = (self._node_index, self._params, self._relax_blocks, self._out, self._corners, self._free_nodes,
                      self._free_start, self._free_slot, self._blocked_scale, self.model.n_tets)
            done, work, strain, stretch = kernel(x_old, v_old, x, v, t, h, self._step_body, self._step_kinematic,
                                                 blocks, self._step_blocks32, a, self.iterations, threads)
            if done < self.iterations:
                raise SimulationDiverged("ebm: non-finite positions during the energy-balance iterations")
            self.work_in += work
            self.red_history.append(abs(self.work_in - strain) / max(abs(self.work_in), 1e-300))
            if not stretch <= MAX_STRETCH:
                self._check_stretch(stretch, t)
            if self.prony is not None:
                self._commit_prony(x, h)
        return State(x=x, v=v, t=t, private=state.private)

    def _prediction_fraction(self, x_prev, v_prev, h, t):
        """``alpha``, the share of the velocity the prediction 5.13 extrapolates: 1, or the first of 0.9, 0.81, ...
        for which no element is inverted (``sim.integrators.ebm.kernels.uninverting_fraction``; split models only).
        A shortened step is recorded in ``shortened_predictions``."""
        if not self._guard_prediction:
            return 1.0
        x_prev = np.ascontiguousarray(x_prev, dtype=np.float64)
        v_prev = np.ascontiguousarray(v_prev, dtype=np.float64)
        alpha = ebm_kernels.uninverting_fraction(self._prediction_scratch, x_prev, v_prev, self.f_ext, self.w, h,
                                                 self._kinematic.nodes, self._kinematic.at(t), self._guard_tets,
                                                 PREDICTION_BACKTRACK, PREDICTION_BACKTRACKS)
        if alpha != 1.0:
            self.shortened_predictions.append((float(t), float(alpha)))
        return alpha

    def _check_stretch(self, stretch, t):
        if not stretch <= MAX_STRETCH:
            raise SimulationDiverged(
                f"ebm: an element is stretched {stretch:.3g}x its rest size (|F|/sqrt(3)) at t = {t:.6g} s: the "
                f"energy-balance iterations no longer hold the body together; more iterations per step, "
                f"substeps or a smaller dt may help")

    def _account_energy(self, x, x_old, kin, x_kin_before, h):
        """Accumulate the external work (trapezoidal) and record the relative energy difference."""
        f_int, strain, stretch = self._forces_and_energy(x, h)
        load = np.zeros_like(x)
        load[kin] = -f_int[kin]  # the reaction the prescribed nodes exert on the body
        if not self.partial.empty:  # and the held components' reaction at nodes held in some components only
            p = self.partial
            load[p.nodes] = -(f_int[p.nodes] - np.einsum("kij,kj->ki", p.P, f_int[p.nodes]))
        load += self.f_ext
        dx = x - x_old
        previous = self._last_load_force
        self.work_in += 0.5 * float(np.sum((load + previous) * dx))
        self._last_load_force = load
        self.red_history.append(abs(self.work_in - strain) / max(abs(self.work_in), 1e-300))
        return stretch
