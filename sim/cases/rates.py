"""The step-rate cases of Zhang's timing figures (Fig. 5.12/5.13: EBM blocks; Fig. 4.17: the CNN with energy
propagation), shared by ``benchmarks/zhang_rates.py`` and ``tissuerender report accuracy``, and the one way
both measure a rate (median steps per second after a warm-up step, so compilation is not counted)."""
from __future__ import annotations

import statistics
import time

import numpy as np

from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State


def ebm_block(constitutive: str, fibre=None, cells=(5, 4, 4)) -> Model:
    """A block of 2 cm cells, 6 tets each (default 5 x 4 x 4 cells: 480 tets), bottom fixed, top pressed 5 mm."""
    mesh = procedural.box(tuple(0.02 * c for c in cells), cells)
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45, density=1000.0, constitutive=constitutive, fibre=fibre)
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    top = select.nodes_on_side(mesh.points, 2, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.array([0.0, 0.0, -0.005]), 0.0, 0.1))
    return model


def cnn_cube(cells=(10, 10, 10)) -> Model:
    """A 1 cm-cell block (default 10^3 cells: 1,331 nodes, 6,000 tets), sides fixed, a 1 N load on the node
    nearest the top centre (the contact)."""
    mesh = procedural.box(tuple(0.01 * c for c in cells), cells)
    model = Model.from_mesh(mesh, E=3500.0, nu=0.45, density=1060.0)
    for axis in (0, 1):
        for side in ("min", "max"):
            model.fixed[select.nodes_on_side(mesh.points, axis, side)] = True
    model.external_force = np.zeros_like(mesh.points)
    top = np.array([0.005 * cells[0], 0.005 * cells[1], 0.01 * cells[2]])
    model.external_force[int(np.argmin(np.linalg.norm(mesh.points - top, axis=1))), 2] = -1.0
    return model


def step_rate(name: str, model: Model, settings: dict, dt: float, steps: int, repeats: int):
    """(median steps per second over ``repeats`` runs of ``steps`` steps, the integrator); one warm-up step
    first, so numba compilation or cache loading is not timed."""
    integrator = make_integrator(name, model, settings)
    state = integrator.step(State.at_rest(model), dt)
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            state = integrator.step(state, dt)
        rates.append(steps / (time.perf_counter() - start))
    return statistics.median(rates), integrator
