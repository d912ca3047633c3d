"""Long-run soaks (the hard cases of tests/sim/integrators/test_hard_cases.py): an undamped XPBD beam and a backward-Euler cube
run for many steps; neither may gain energy. The test suite runs them short (tests/sim/integrators/
test_hard_cases.py); ``benchmarks/soak.py`` runs them for 10,000 steps."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.constitutive import elastic
from sim.integrators.reference import ReferenceIntegrator
from sim.integrators.xpbd.solver import XPBD
from sim.mesh import procedural, select
from sim.model import Model, State


@dataclass(frozen=True)
class Soak:
    """Energy record of a soak: the total energy at rest ``e0`` and after every step ``energy`` [J], the
    largest displacement from rest at the end [m] and the largest final speed [m/s]."""
    e0: float
    energy: np.ndarray
    max_displacement: float
    max_speed: float


def total_energy(model: Model, state: State) -> float:
    """Kinetic + strain energy - the work of the constant external (gravity) forces [J]."""
    kinetic = 0.5 * np.sum(model.mass[:, None] * state.v**2)
    return float(kinetic + elastic.elastic_energy(model, state.x) - np.sum(model.nodal_external_force() * state.x))


def _soak(integrator, model: Model, dt: float, steps: int) -> Soak:
    state = State.at_rest(model)
    e0 = total_energy(model, state)
    energy = np.empty(steps)
    for k in range(steps):
        state = integrator.step(state, dt)
        energy[k] = total_energy(model, state)
    return Soak(e0, energy, float(np.abs(state.x - model.X).max()), float(np.abs(state.v).max()))


def xpbd_beam_soak(steps: int) -> Soak:
    """A 0.4 m cantilever (4x1x1 cells, E 1 MPa, nu 0.45, stable Neo-Hookean) under gravity, XPBD without
    damping (only its own dissipation), 1 ms steps (1.2x the explicit critical step), 10 iterations."""
    mesh = procedural.box((0.4, 0.1, 0.1), (4, 1, 1))
    model = Model.from_mesh(mesh, E=1e6, nu=0.45, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]),
                            constitutive="stable_neo_hookean")
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    return _soak(XPBD(model, {"substeps": 1, "iterations": 10}), model, 0.001, steps)


def reference_cube_soak(steps: int) -> Soak:
    """A 10 cm cube (E 3 kPa, nu 0.45, stable Neo-Hookean) resting on its clamped base under gravity, the
    dynamic backward-Euler reference with 10 ms steps."""
    mesh = procedural.box((0.1, 0.1, 0.1), (1, 1, 1))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45, density=1000.0, constitutive="stable_neo_hookean",
                            gravity=np.array([0.0, 0.0, -9.81]))
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    return _soak(ReferenceIntegrator(model, {"mode": "dynamic"}), model, 0.01, steps)
