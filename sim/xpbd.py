"""XPBD (Macklin et al. 2016; Qian §4.4, eqs. 4.36–4.44) with stable Neo-Hookean tet constraints
(Macklin & Müller 2021).

Per tet, with ``F = Ds Dm^-1``, two constraints with compliances from the Lamé parameters:

- deviatoric ``C_D = ||F||_F`` (``dC/dF = F / ||F||``), compliance ``1 / (mu V)``;
- hydrostatic ``C_H = det F - gamma``, ``gamma = 1 + mu / lam`` (the rest-stability shift),
  ``dC/dF = cof F``, compliance ``1 / (lam V)``.

Each substep: predict ``x* = x + dt v + dt^2 M^-1 f_ext``; reset the multipliers; for every
iteration, for every colour (tets sharing no node, projected in parallel), project
``dlambda = (-C - alpha~ lambda) / (sum_i w_i |grad_i C|^2 + alpha~)``, ``alpha~ = alpha / dt^2``,
``x_i += w_i grad_i C dlambda`` (Qian 4.42–4.44; its eq. 4.22 gradient typo is noted in DESIGN.md);
then tool contact, then ``v = (x - x_prev) / dt``. The ``jacobi`` solver averages the corrections of all
tets per iteration (with relaxation) instead.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from sim.coloring import colour_tets
from sim.integrators import SimulationDiverged
from sim.model import Model, State
from sim.probe import resolve_contact


@njit(cache=True, inline="always")
def _deformation_gradient(x, i0, i1, i2, i3, B, F):
    """F = Ds Dm^-1 of one tet into ``F`` (3, 3)."""
    for r in range(3):
        a = x[i1, r] - x[i0, r]
        b = x[i2, r] - x[i0, r]
        c = x[i3, r] - x[i0, r]
        for col in range(3):
            F[r, col] = a * B[0, col] + b * B[1, col] + c * B[2, col]


@njit(cache=True, inline="always")
def _project_tet(t, x, tets, Dm_inv, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, dt2, out, accumulate, scale):
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    B = Dm_inv[t]
    F = np.empty((3, 3))
    _deformation_gradient(x, i0, i1, i2, i3, B, F)
    w0, w1, w2, w3 = w[i0], w[i1], w[i2], w[i3]
    for which in range(2):
        G = np.empty((3, 3))  # dC/dF
        if which == 0:
            norm = np.sqrt((F * F).sum())
            if norm < 1e-12:
                continue
            C = norm
            for r in range(3):
                for col in range(3):
                    G[r, col] = F[r, col] / norm
            alpha = alpha_dev[t]
            lam_acc = lam_dev
        else:
            # cofactor columns: f2 x f3, f3 x f1, f1 x f2 (f = columns of F)
            G[0, 0] = F[1, 1] * F[2, 2] - F[2, 1] * F[1, 2]
            G[1, 0] = F[2, 1] * F[0, 2] - F[0, 1] * F[2, 2]
            G[2, 0] = F[0, 1] * F[1, 2] - F[1, 1] * F[0, 2]
            G[0, 1] = F[1, 2] * F[2, 0] - F[2, 2] * F[1, 0]
            G[1, 1] = F[2, 2] * F[0, 0] - F[0, 2] * F[2, 0]
            G[2, 1] = F[0, 2] * F[1, 0] - F[1, 2] * F[0, 0]
            G[0, 2] = F[1, 0] * F[2, 1] - F[2, 0] * F[1, 1]
            G[1, 2] = F[2, 0] * F[0, 1] - F[0, 0] * F[2, 1]
            G[2, 2] = F[0, 0] * F[1, 1] - F[1, 0] * F[0, 1]
            C = F[0, 0] * G[0, 0] + F[1, 0] * G[1, 0] + F[2, 0] * G[2, 0] - gamma[t]
            alpha = alpha_hyd[t]
            lam_acc = lam_hyd
        # grad wrt x1..x3 = G B^T (columns); x0 = -sum
        g = np.zeros((4, 3))
        for k in range(3):
            for r in range(3):
                g[k + 1, r] = G[r, 0] * B[k, 0] + G[r, 1] * B[k, 1] + G[r, 2] * B[k, 2]
        for r in range(3):
            g[0, r] = -(g[1, r] + g[2, r] + g[3, r])
        denom = (w0 * (g[0] ** 2).sum() + w1 * (g[1] ** 2).sum() + w2 * (g[2] ** 2).sum()
                 + w3 * (g[3] ** 2).sum())
        at = alpha / dt2
        if denom + at < 1e-30:
            continue
        dl = scale * (-C - at * lam_acc[t]) / (denom + at)
        lam_acc[t] += dl
        ids = (i0, i1, i2, i3)
        ws = (w0, w1, w2, w3)
        for k in range(4):
            for r in range(3):
                delta = ws[k] * g[k, r] * dl
                if accumulate:
                    out[ids[k], r] += delta
                else:
                    x[ids[k], r] += delta
        if not accumulate:
            # refresh F after the first constraint so the second sees the corrected positions
            _deformation_gradient(x, i0, i1, i2, i3, B, F)


@njit(cache=True, parallel=True)
def _gauss_seidel_colour(idx, x, tets, Dm_inv, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, dt2, dummy):
    for j in prange(idx.shape[0]):
        _project_tet(idx[j], x, tets, Dm_inv, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, dt2, dummy, False, 1.0)


@njit(cache=True)
def _jacobi_sweep(x, tets, Dm_inv, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, dt2, tet_scale):
    # Every tet sees the same positions; its step is scaled by relaxation / (most tets sharing one of
    # its nodes), and its multiplier takes the same scaled step, so lambda stays consistent with x.
    out = np.zeros_like(x)
    for t in range(tets.shape[0]):
        _project_tet(t, x, tets, Dm_inv, w, alpha_dev, alpha_hyd, gamma, lam_dev, lam_hyd, dt2, out, True,
                     tet_scale[t])
    for i in range(x.shape[0]):
        for r in range(3):
            x[i, r] += out[i, r]


class XPBD:
    """XPBD integrator; settings: ``substeps``, ``iterations``, ``solver`` ("gauss_seidel" | "jacobi"),
    ``relaxation`` (Jacobi), ``damping`` [1/s] (velocity decay ``exp(-damping dt)``)."""

    name = "xpbd"

    def __init__(self, model: Model, settings: dict):
        self.model = model
        self.substeps = int(settings.get("substeps", 10))
        self.iterations = int(settings.get("iterations", 10))
        self.solver = settings.get("solver", "gauss_seidel")
        self.relaxation = float(settings.get("relaxation", 1.0))
        self.damping = float(settings.get("damping", 0.0))
        if self.solver not in ("gauss_seidel", "jacobi"):
            raise ValueError(f"xpbd solver must be 'gauss_seidel' or 'jacobi', found {self.solver!r}")
        m = model
        self.tets = np.ascontiguousarray(m.tets, dtype=np.int64)
        self.Dm_inv = np.ascontiguousarray(m.Dm_inv)
        self.alpha_dev = 1.0 / (m.mu * m.volume)
        # lam = 0 (nu = 0): no volume term; an effectively infinite compliance switches it off.
        has_lam = m.lam > 0.0
        self.alpha_hyd = np.where(has_lam, 1.0 / np.where(has_lam, m.lam, 1.0) / m.volume, 1e30)
        self.gamma = np.where(has_lam, 1.0 + m.mu / np.where(has_lam, m.lam, 1.0), 1.0)
        self.w = m.inverse_mass()
        self.kinematic, _ = m.kinematic_targets(0.0)
        self.colours = colour_tets(self.tets, m.n_nodes) if self.solver == "gauss_seidel" else None
        counts = np.bincount(self.tets.ravel(), minlength=m.n_nodes).astype(np.float64)
        self.tet_scale = self.relaxation / counts[self.tets].max(axis=1)
        self.f_ext_acc = m.nodal_external_force() * np.where(self.w > 0, self.w, 0.0)[:, None]

    def step(self, state: State, dt: float) -> State:
        m = self.model
        h = dt / self.substeps
        x = state.x.copy()
        v = state.v.copy()
        t = state.t
        lam_dev = np.zeros(m.n_tets)
        lam_hyd = np.zeros(m.n_tets)
        dummy = np.zeros((1, 3))
        for _ in range(self.substeps):
            t_next = t + h
            x_prev = x.copy()
            x += h * v + h * h * self.f_ext_acc
            idx, target = m.kinematic_targets(t_next)
            x[idx] = target
            lam_dev[:] = 0.0
            lam_hyd[:] = 0.0
            for _ in range(self.iterations):
                if self.colours is not None:
                    for colour in self.colours:
                        _gauss_seidel_colour(colour, x, self.tets, self.Dm_inv, self.w, self.alpha_dev,
                                             self.alpha_hyd, self.gamma, lam_dev, lam_hyd, h * h, dummy)
                else:
                    _jacobi_sweep(x, self.tets, self.Dm_inv, self.w, self.alpha_dev, self.alpha_hyd, self.gamma,
                                  lam_dev, lam_hyd, h * h, self.tet_scale)
                for probe in m.probes:
                    resolve_contact(x, probe, t_next, self.w)
            v = (x - x_prev) / h
            if self.damping > 0.0:
                v *= np.exp(-self.damping * h)
            t = t_next
            if not np.isfinite(x).all():
                raise SimulationDiverged(f"xpbd: non-finite positions at t = {t:.6g} s")
        return State(x=x, v=v, t=t, private=state.private)
