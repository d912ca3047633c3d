"""Zhang §5.3.4's viscoelastic cube (Fig. 5.9): a stress-relaxation test, and the reaction force it is read by.

The cube of §5.3.3: 2 m, rho = 1,000 kg/m^3, E = 3,000 Pa, nu = 0.49 (the Neo-Hookean form of Zhang eq. 5.35
here), one Prony term ``alpha_1 = 0.5``, ``tau_1 = 0.58 s`` (Zhang 5.29-5.32). The face x = 0 is held, the face
x = 2 m is moved by -0.3 m in x over 0.5 s (a linear ramp) and held for 4.5 s. §5.3.3 calls these faces "bottom"
and "top" while moving the top face "in both positive and negative x directions to extend and compress the cube",
and Fig. 5.8 shows the isotropic cube's sides bulging evenly in y and z: the load is along x, the x = 0 and x = 2 m
faces are its "bottom" and "top" (uniaxial compression with free sides, not a shear).

Measured: the **reaction force** F(t) at the held face, the x component of the sum over its nodes of the
viscoelastic energy's gradient, positive in compression [N] (:func:`reaction_force`).

**Prediction** (linear viscoelasticity, quasi-static, every point relaxing alike): with the ramp fraction s(t) and
the elastic reaction F_el of the final shape, Zhang 5.31 gives ``F(t) = F_el int_0^t alpha(t - s') ds/ds' ds'``,
alpha(t) = 1 - alpha_1 (1 - exp(-t / tau_1)) (5.30); for a linear ramp over T_r and t >= T_r::

    F(t) = F_inf + (F(T_r) - F_inf) exp(-(t - T_r) / tau_1),   F_inf = (1 - alpha_1) F_el,
    F(T_r) / F_el = 1 - alpha_1 + alpha_1 (tau_1 / T_r) (1 - exp(-T_r / tau_1))

(:func:`continuous_relaxation`). The reference and EBM advance the history with the incremental update below
5.32 (backward Euler of the history, ``sim.constitutive.prony``): held, the excess ``F - F_inf`` shrinks by
``B = tau / (tau + dt)`` per step, an effective time constant ``dt / ln(1 + dt / tau)`` (:func:`discrete_tau`),
larger than tau by ``dt / (2 tau)`` to first order; :func:`discrete_relaxation` is the recursion itself.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.constitutive import models, tensor
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement

ALPHA, TAU = 0.5, 0.58  # Zhang §5.3.4, one Prony term [-], [s]
RAMP_S, HOLD_S = 0.5, 4.5  # the stress-relaxation protocol [s]
SIDE_M = 2.0


@dataclass
class ViscoelasticCube:
    model: Model
    held: np.ndarray  # the nodes of the face x = 0 (its reaction is measured)
    moved: np.ndarray  # the nodes of the face x = 2 m
    ramp_s: float
    end_s: float


def zhang_viscoelastic_cube(n_cells: int = 4, displacement: float = -0.3, ramp_s: float = RAMP_S,
                            hold_s: float = HOLD_S, alpha: float = ALPHA, tau: float = TAU,
                            constitutive: str = "neo_hookean", E: float = 3000.0, nu: float = 0.49,
                            density: float = 1000.0) -> ViscoelasticCube:
    """The cube with ``n_cells`` cells per edge (6 tets each); ``displacement`` [m] of the face x = 2 m along x."""
    mesh = procedural.cube(SIDE_M, n_cells)
    model = Model.from_mesh(mesh, E=E, nu=nu, density=density, constitutive=constitutive,
                            material_params={"prony": [(alpha, tau)]})
    held = select.nodes_on_side(mesh.points, 0, "min")
    moved = select.nodes_on_side(mesh.points, 0, "max")
    model.fixed[held] = True
    model.prescribed.append(PrescribedDisplacement(moved, np.array([displacement, 0.0, 0.0]), 0.0, ramp_s))
    return ViscoelasticCube(model, held, moved, ramp_s, ramp_s + hold_s)


def stress_reaction(tets, Dm_inv, volume, P, nodes, n_nodes: int) -> np.ndarray:
    """Sum over ``nodes`` of the energy gradient ``V P Dm^-T`` of first Piola stresses ``P`` (m, 3, 3): the force
    (3,) [N] the supports holding ``nodes`` exert on the body."""
    G = volume[:, None, None] * P @ np.swapaxes(Dm_inv, 1, 2)
    grads = tensor.node_gradients(G)
    g = np.zeros((n_nodes, 3))
    for a in range(4):
        np.add.at(g, tets[:, a], grads[:, a])
    return g[nodes].sum(axis=0)


def _piola(model, F, tet_order=None):
    name, mu, lam, eta, a0 = models.model_params(model)
    if tet_order is not None:
        mu, lam = mu[tet_order], lam[tet_order]
        eta = None if eta is None else eta[tet_order]
        a0 = None if a0 is None else a0[tet_order]
    return models.first_piola(name, F, mu, lam, eta, a0, vl=models.model_curves(model))


def reaction_force(integrator, x: np.ndarray, nodes: np.ndarray) -> float:
    """The x reaction at ``nodes``, positive in compression [N], of the viscoelastic stress ``integrator`` holds
    after its last step: with a ``PronyHistory`` (``reference``, ``ebm``) ``S^ = S - sum_i gamma_i`` (Zhang 5.31,
    the history committed with this step's S), with Maxwell branches (``xpbd``) the gradient of
    ``(1 - sum a_i) Psi(F) + sum_i a_i Psi(F Fv_i^-1)`` (``sim.integrators.xpbd.prony``)."""
    m = integrator.model
    branches = getattr(integrator, "branches", None)
    if branches is not None:
        order = integrator.tet_order
        volume = m.volume[order]
        total = np.zeros(3)
        for weight, rest in branches.sets():
            F = tensor.deformation_gradients(x, branches.tets, rest)
            total += weight * stress_reaction(branches.tets, rest, volume, _piola(m, F, order), nodes, m.n_nodes)
        return float(total[0])
    F = tensor.deformation_gradients(x, m.tets, m.Dm_inv)
    P = _piola(m, F)
    history = getattr(integrator, "prony", None)
    if history is not None:
        S = np.linalg.solve(F, P)
        P = F @ (S - history.gamma.sum(axis=0))
    return float(stress_reaction(m.tets, m.Dm_inv, m.volume, P, nodes, m.n_nodes)[0])


def elastic_reaction(model, x: np.ndarray, nodes: np.ndarray) -> float:
    """The purely elastic x reaction at ``nodes`` (no relaxation), positive in compression [N]: ``F_el``."""
    F = tensor.deformation_gradients(x, model.tets, model.Dm_inv)
    return float(stress_reaction(model.tets, model.Dm_inv, model.volume, _piola(model, F), nodes, model.n_nodes)[0])


def continuous_relaxation(t, ramp_s: float = RAMP_S, alpha: float = ALPHA, tau: float = TAU) -> np.ndarray:
    """``F(t) / F_el`` of linear viscoelasticity under a linear ramp over ``ramp_s`` then a hold (Zhang 5.30-5.31)."""
    t = np.asarray(t, dtype=np.float64)
    during = ((1.0 - alpha) * t + alpha * tau * (1.0 - np.exp(-t / tau))) / ramp_s
    peak = 1.0 - alpha + alpha * tau / ramp_s * (1.0 - np.exp(-ramp_s / tau))
    after = (1.0 - alpha) + (peak - (1.0 - alpha)) * np.exp(-(t - ramp_s) / tau)
    return np.where(t <= ramp_s, during, after)


def discrete_relaxation(t, dt: float, ramp_s: float = RAMP_S, alpha: float = ALPHA, tau: float = TAU) -> np.ndarray:
    """``F(t_n) / F_el`` at ``t_n = n dt`` (``t``: those times) of the incremental history update below Zhang 5.32
    applied to a stress that follows the ramp fraction s_n: ``F_n = s_n - g_n``, ``g_n = A s_n + B g_(n-1)``."""
    A, B = dt * alpha / (dt + tau), tau / (dt + tau)
    t = np.asarray(t, dtype=np.float64)
    g, out = 0.0, []
    for s in np.clip(t / ramp_s, 0.0, 1.0):
        g = A * s + B * g
        out.append(s - g)
    return np.array(out)


def discrete_tau(dt: float, tau: float = TAU) -> float:
    """The time constant [s] of the held relaxation under the backward-Euler history: ``dt / ln(1 + dt / tau)``."""
    return float(dt / np.log1p(dt / tau))


def fit_relaxation(t, force, elastic: float, ramp_s: float = RAMP_S, alpha: float = ALPHA, tau: float = TAU,
                   span: float = 3.0) -> dict:
    """The relaxation the history ``force`` (at times ``t``) shows during the hold: ``ratio`` = the last force over
    ``elastic`` (F_el; Prony: ``1 - alpha``), ``peak_ratio`` = F(T_r) / F_el, and ``tau_s``: the least-squares
    slope of ``ln(F - (1 - alpha) F_el)`` against time over the first ``span`` tau of the hold (where the excess
    is above exp(-span) of its start, far above the solver's tolerance)."""
    t, force = np.asarray(t, dtype=np.float64), np.asarray(force, dtype=np.float64)
    hold = (t >= ramp_s - 1e-9) & (t <= ramp_s + span * tau + 1e-9)
    excess = force[hold] - (1.0 - alpha) * elastic
    ok = excess > 0.0
    if ok.sum() < 2:
        slope = np.nan
    else:
        slope = float(np.polyfit(t[hold][ok], np.log(excess[ok]), 1)[0])
    peak = force[np.argmin(np.abs(t - ramp_s))]
    return {"ratio": float(force[-1] / elastic), "peak_ratio": float(peak / elastic),
            "tau_s": float(-1.0 / slope) if slope < 0.0 else float("nan"), "elastic_N": float(elastic)}
