"""The buckling variant of Zhang's compressed cylinder (a hard case, issue 21): the cylinder of
``sim.cases.zhang.zhang_cylinder`` (2 m long, radius 0.5 m, E = 3000 Pa, nu = 0.49) with its left face fixed and its
right face a *roller*: only the axial component is prescribed (compressed by up to 0.4 m), the face may slide
sideways (``PrescribedDisplacement.held``). Its rotation is blocked (all of its nodes share one z), so the column is
fixed at one end and guided at the other: Euler's load ``P_cr = pi^2 E I / L^2`` with ``I = pi r^4 / 4`` is 363 N
and, divided by the axial stiffness ``E A / L`` = 1178 N/m, buckles at about 0.31 m of compression (an independent
FE solver agrees).

:func:`buckling_path` follows the quasi-static equilibria of the reference integrator along the load path and reports
per load step the compression, the sideways deflection of the loaded face and the smallest eigenvalue of the reduced
tangent stiffness ``T^T K T`` (the held components eliminated, ``sim.integrators.reference``): the column buckles
where it crosses zero. The imperfection is a small lateral load at mid-span (plus the tet pattern's own asymmetry).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as sla

from sim.cases.zhang import Case, zhang_cylinder
from sim.integrators.reference import ReferenceIntegrator
from sim.model import State

EULER_COMPRESSION = 0.31  # [m]: pi^2 E I / L^2 / (E A / L) = pi^2 r^2 / (4 L) for the fixed-guided column


@dataclass
class BucklingPath:
    compression: np.ndarray  # (s,) [m] at the end of each load step
    deflection: np.ndarray  # (s,) [m] sideways displacement of the loaded face's centroid
    smallest_eigenvalue: np.ndarray  # (s,) [N/m] of the reduced tangent stiffness (NaN where not computed)
    x: np.ndarray | None = None  # (n, 3) [m] the positions at the end of the path

    def critical_compression(self) -> float:
        """Compression [m] where the smallest eigenvalue crosses zero (linear between load steps); NaN if it does
        not within the path."""
        ev, c = self.smallest_eigenvalue, self.compression
        known = np.flatnonzero(np.isfinite(ev))
        for a, b in zip(known, known[1:]):
            if ev[a] > 0.0 >= ev[b]:
                return float(c[a] + (c[b] - c[a]) * ev[a] / (ev[a] - ev[b]))
        return float("nan")


def buckling_cylinder(h: float = 0.25, compression: float = 0.4, imperfection: float = 0.01) -> Case:
    """The roller-loaded cylinder; ``imperfection`` [N]: the lateral (+x) load spread over the mid-span nodes."""
    case = zhang_cylinder(h=h, displacement=-compression, slide=True)
    model = case.model
    mid = np.flatnonzero(np.abs(model.X[:, 2] - 1.0) <= 0.26 * h)
    force = np.zeros_like(model.X)
    force[mid, 0] = imperfection / mid.size
    model.external_force = force
    case.name = "cylinder_buckling"
    return case


def smallest_eigenvalue(reference: ReferenceIntegrator, x: np.ndarray) -> float:
    """The smallest eigenvalue [N/m] of the reduced tangent stiffness at ``x`` (exact element Hessians)."""
    free = ~np.repeat(reference.model.kinematic_mask(), 3)
    T = reference._free_basis(free)
    K = (T.T @ reference._hessian(x, 1.0, project=False) @ T).tocsc()
    # shift-invert below the spectrum: the eigenvalue nearest the shift is the smallest
    values = sla.eigsh(K, k=1, sigma=-1.0, which="LM", return_eigenvectors=False)
    return float(values[0])


def buckling_path(case: Case, load_steps: int = 10, eigen_every: int = 1, anp: bool = True) -> BucklingPath:
    """Quasi-static equilibria in ``load_steps`` equal steps of the ramp (reference integrator, average nodal
    pressure by default: linear tets at nu = 0.49 lock in bending otherwise and buckle late); the smallest
    eigenvalue every ``eigen_every`` steps and at the last one."""
    model = case.model
    reference = ReferenceIntegrator(model, {"mode": "quasistatic", "load_steps": 1, "anp": anp})
    end = model.partial().nodes
    state = State.at_rest(model)
    compression, deflection, eigen = [], [], []
    for k in range(load_steps):
        state = reference.step(state, case.ramp_time / load_steps)
        u = state.x[end] - model.X[end]
        compression.append(-float(u[:, 2].mean()))
        deflection.append(float(np.hypot(u[:, 0].mean(), u[:, 1].mean())))
        last = k == load_steps - 1
        eigen.append(smallest_eigenvalue(reference, state.x) if (k + 1) % eigen_every == 0 or last else np.nan)
    return BucklingPath(np.array(compression), np.array(deflection), np.array(eigen), state.x)
