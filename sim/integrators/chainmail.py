"""``cnn_chainmail``: the neural-dynamics ChainMail of Zhang §3.4, a fast geometric deformer.

Every mesh edge (i, j) is a chain link with rest length ``l0`` and strain limits (Zhang 3.53)::

    l_min = (1 - alpha) l0,      l_max = (1 + alpha) l0

A violated link is fixed by moving both ends half-way back to the limit (3.55). Each node is a CNN
cell whose state is its position; summing the pairwise fixes gives the cell dynamics (3.52, 3.60)::

    dP_i/dtau = sum_j mu_ij (P_j - P_i) + I_i

with the templates ``A(i;j) = mu_ij``, ``A(i;i) = 1/R_x - sum_j mu_ij`` (3.63; the 1/R_x term cancels
the cell's own leak as in 4.24) and (3.61–3.62)::

    mu_ij = 1/2 [ (u_ij - l_max)/u_ij delta_max + (u_ij - l_min)/u_ij delta_min ],  u_ij = |P_j - P_i|

(delta_max = 1 if u > l_max, delta_min = 1 if u < l_min, else 0). Fixed and prescribed nodes are
fixed-state cells (Dirichlet, §3.4.3); the current source ``I_i`` is the input displacement of the
contact (prescribed) nodes, which we apply by moving those cells to their targets at the start of the
step. The pseudo-time ``tau`` is integrated by forward Euler, each sweep applying every pairwise fix of
3.55 at once (a Jacobi ChainMail), with the cell capacitance C of 3.50 set to the number of the cell's
violated links: a unit step with C = 1 overshoots and diverges wherever several links of one node are
violated (measured on a pressed cube), and C_i = n_i makes each cell move to the average of its fixes.
Sweeps stop when no link exceeds its limits by more than ``tolerance`` (relative to l0) or after
``iterations`` sweeps.

It has no mass, stiffness or forces: it moves nodes only as far as the strain limits demand, so it is
plausible, not mechanical. Models with external forces or gravity are rejected (use the
prescribed displacements of a probe or a ramp instead). Velocities are the position change over dt.

Cells held in some components only (rollers, sliding faces: ``sim.model.PartialTargets``) are put back on their
constraint after every sweep. Probes (``model.probes``) are input displacements too: nodes inside a tool are pushed to its surface
before the sweeps and after each one.

| name | default | unit | range | equation |
|---|---|---|---|---|
| ``strain_min`` | none: ``1 - alpha`` = 0.8 | – | (0, 1] | 3.53, l_min = strain_min l0 |
| ``strain_max`` | none: ``1 + alpha`` = 1.2 | – | [1, 10] | 3.53, l_max = strain_max l0 |
| ``tolerance`` | 1e-4 | – | (0, 0.1] | largest link excess over l0 that ends the sweeps |
| ``alpha`` | 0.2 | – | (0, 1) | 3.53 (the thesis sets it "according to the spring stiffness") |
| ``iterations`` | 500 | – | >= 1 | sweeps per substep |
| ``substeps`` | 1 | – | >= 1 | h = dt / substeps |

``ChainMailSceneSettings`` is the scene's ``[simulation.cnn_chainmail]`` table; ``ChainMailSettings`` adds
``alpha`` and what the scene sets in ``[simulation]`` (``substeps``, ``iterations``).
"""
from __future__ import annotations

import numpy as np
from pydantic import Field

from sim.errors import SimulationDiverged
from sim.model import Model, State
from sim.probe import resolve_contact
from sim.settings import Settings

LOCAL_EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])


class ChainMailSceneSettings(Settings):
    """The scene's ``[simulation.cnn_chainmail]`` table."""

    strain_min: float | None = Field(None, gt=0.0, le=1.0, description="shortest link over its rest length; none: 1 - alpha")
    strain_max: float | None = Field(None, ge=1.0, le=10.0, description="longest link over its rest length; none: 1 + alpha")
    tolerance: float = Field(1e-4, gt=0.0, le=0.1, description="largest link excess over l0 that ends the sweeps [-]")


class ChainMailSettings(ChainMailSceneSettings):
    """Every parameter of the ``cnn_chainmail`` integrator (the table in the module docstring)."""

    alpha: float = Field(0.2, gt=0.0, lt=1.0, description="symmetric strain limit of eq. 3.53 [-]")
    iterations: int = Field(500, ge=1, le=10000, description="sweeps per substep [-]")
    substeps: int = Field(1, ge=1, le=1000, description="substeps per step [-]")


def mesh_edges(tets: np.ndarray) -> np.ndarray:
    """Unique edges (e, 2) of a tet mesh, i < j."""
    pairs = np.sort(tets[:, LOCAL_EDGES].reshape(-1, 2), axis=1)
    return np.unique(pairs, axis=0)


def strain_limits(X: np.ndarray, edges: np.ndarray, alpha: float, strain_min: float | None = None,
                  strain_max: float | None = None):
    """Zhang 3.53: ``l_min = (1 - alpha) l0``, ``l_max = (1 + alpha) l0`` [m] per edge; ``strain_min`` /
    ``strain_max`` (stretch ratios) replace ``1 - alpha`` / ``1 + alpha`` for asymmetric limits."""
    l0 = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
    lo = 1.0 - alpha if strain_min is None else strain_min
    hi = 1.0 + alpha if strain_max is None else strain_max
    return l0, lo * l0, hi * l0


def mu(u: np.ndarray, l_min: np.ndarray, l_max: np.ndarray) -> np.ndarray:
    """The template weights of Zhang 3.61–3.62 per edge (zero where the link is within its limits)."""
    over = u > l_max
    under = u < l_min
    safe = np.maximum(u, 1e-300)
    return 0.5 * (np.where(over, (u - l_max) / safe, 0.0) + np.where(under, (u - l_min) / safe, 0.0))


class CNNChainMail:
    name = "cnn_chainmail"

    def __init__(self, model: Model, settings: ChainMailSettings | dict | None = None):
        settings = ChainMailSettings.of(settings)
        self.settings = settings
        self.model = model
        self.alpha = settings.alpha
        lo, hi = settings.strain_min, settings.strain_max
        self.iterations = settings.iterations
        self.tolerance = settings.tolerance
        self.substeps = settings.substeps
        f = model.nodal_external_force()
        if np.abs(f).max(initial=0.0) > 0.0:
            raise ValueError("cnn_chainmail: the ChainMail is geometric and has no forces, but the model has external "
                             "forces or gravity; drive it with prescribed displacements (a probe or a ramp) instead")
        self.edges = mesh_edges(model.tets)
        self.l0, self.l_min, self.l_max = strain_limits(model.X, self.edges, self.alpha, lo, hi)
        self.fixed_state = model.kinematic_mask()
        self.partial = model.partial()  # cells held in some components: put back on their constraint after each sweep
        self.inv_mass = model.inverse_mass()  # zero on kinematic nodes: probes do not move them
        self.last_sweeps = 0
        self.last_violation = 0.0

    def violation(self, x: np.ndarray) -> float:
        """Largest relative excess of any link over its limits, ``max(u - l_max, l_min - u, 0) / l0``."""
        u = np.linalg.norm(x[self.edges[:, 1]] - x[self.edges[:, 0]], axis=1)
        return float(np.max(np.maximum(np.maximum(u - self.l_max, self.l_min - u), 0.0) / self.l0, initial=0.0))

    def relax(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Sweep the CNN (3.52 with 3.60–3.63) until every link is within its limits; nodes a probe
        touches are pushed back to its surface after every sweep (the probe is an input displacement)."""
        i, j = self.edges[:, 0], self.edges[:, 1]
        free = ~self.fixed_state
        for sweep in range(1, self.iterations + 1):
            d = x[j] - x[i]
            u = np.linalg.norm(d, axis=1)
            m = mu(u, self.l_min, self.l_max)
            active = m != 0.0
            excess = np.max(np.abs(m[active]) * 2.0 * u[active] / self.l0[active], initial=0.0)
            if excess <= self.tolerance:
                self.last_sweeps, self.last_violation = sweep - 1, excess
                return x
            dp = m[:, None] * d  # 3.55: Delta P_i = mu_ij (P_j - P_i), Delta P_j = -mu_ij (P_j - P_i)
            delta = np.zeros_like(x)
            np.add.at(delta, i, dp)
            np.add.at(delta, j, -dp)
            count = np.bincount(i[active], minlength=x.shape[0]) + np.bincount(j[active], minlength=x.shape[0])
            step = free / np.maximum(count, 1)  # tau_i = 1 / C_i; fixed-state cells never move
            x = x + delta * step[:, None]
            for probe in self.model.probes:
                resolve_contact(x, probe, t, self.inv_mass)
            self.partial.place(x, t)
        self.last_sweeps, self.last_violation = self.iterations, self.violation(x)
        return x

    def step(self, state: State, dt: float) -> State:
        h = dt / self.substeps
        x, t = state.x.copy(), state.t
        for _ in range(self.substeps):
            t += h
            idx, target = self.model.kinematic_targets(t)
            x[idx] = target  # the input displacement (current source, §3.4.3) and the fixed cells
            self.partial.place(x, t)
            for probe in self.model.probes:
                resolve_contact(x, probe, t, self.inv_mass)
            x = self.relax(x, t)
            if not np.isfinite(x).all():
                raise SimulationDiverged(f"cnn_chainmail: non-finite positions at t = {t:.6g} s")
        v = (x - state.x) / dt
        return State(x=x, v=v, t=t, private=state.private)
