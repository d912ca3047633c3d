"""The Energy Balance Method (Zhang ch. 5) on the Zhang 5.3 cases, and the Prony history (5.29-5.32)."""
from __future__ import annotations

import numpy as np
import pytest

from sim import constitutive
from sim.cases import relative_l2, zhang_cube_shear, zhang_cylinder
from sim.ebm import EBM
from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, State
from sim.prony import PronyHistory
from sim.reference import ReferenceIntegrator


def test_prony_history_relaxes_a_step_strain_to_the_long_term_modulus():
    alpha, tau, dt = 0.5, 0.58, 0.01
    history = PronyHistory([(alpha, tau)], 1)
    S = np.eye(3)[None] * 100.0
    psi = np.array([10.0])
    relaxed = []
    for _ in range(500):
        S_hat, _ = history.relaxed(S, psi, dt)
        relaxed.append(S_hat[0, 0, 0])
        history.commit(S, psi, dt)
    t = dt * np.arange(1, 501)
    # backward Euler on tau dgamma/dt + gamma = alpha S: within 1 % of 1 - alpha (1 - exp(-t/tau))
    exact = 100.0 * (1.0 - alpha * (1.0 - np.exp(-t / tau)))
    assert np.abs(np.array(relaxed) - exact).max() < 1.0
    assert relaxed[-1] == pytest.approx(100.0 * (1 - alpha), rel=1e-3)


def test_bad_prony_terms_are_rejected():
    with pytest.raises(ValueError, match="sum alpha_i < 1"):
        PronyHistory([(0.7, 1.0), (0.4, 2.0)], 3)


def _ebm_run(case, iterations, steps=4):
    ebm = EBM(case.model, {"iterations": iterations})
    state = State.at_rest(case.model)
    for _ in range(steps):
        state = ebm.step(state, case.ramp_time / steps)
    return state, ebm


@pytest.mark.parametrize("make_case, steps", [(lambda: zhang_cylinder(h=0.25, displacement=0.4), 8),
                                              (lambda: zhang_cylinder(h=0.25, displacement=-0.4), 8),
                                              (lambda: zhang_cube_shear(4), 4)],
                         ids=["cylinder_extension", "cylinder_compression", "cube_shear"])
def test_ebm_error_against_the_reference_falls_with_iterations(make_case, steps):
    """Zhang 5.3.2 (cylinder 656 tets, h = 0.25 m; cube 384 tets), against the quasi-static reference."""
    case = make_case()
    x_ref = ReferenceIntegrator(case.model, {"mode": "quasistatic", "load_steps": 4}).step(
        State.at_rest(case.model), case.ramp_time).x
    u_ref = x_ref - case.model.X
    energy_ref = constitutive.elastic_energy(case.model, x_ref)
    errors = {}
    for iterations in (20, 100, 500):
        state, ebm = _ebm_run(case, iterations, steps)
        errors[iterations] = relative_l2(state.x - case.model.X, u_ref)
        # RED recorded once per step, finite; the stored energy is at least the equilibrium's (the reference
        # minimises it under the same boundary displacements) and, measured, 2-3x it (docs/ebm.md)
        assert len(ebm.red_history) == steps and np.isfinite(ebm.red_history).all()
        energy = constitutive.elastic_energy(case.model, state.x)
        assert energy_ref < energy < 4.0 * energy_ref
        if iterations == 20:
            assert 0.0 < ebm.work_in and ebm.red_history[-1] < 3.0  # measured 0.14-2.5 over the three cases
    # Measured (relative L2): cylinder extension 0.28 / 0.12 / 0.12, compression 0.20 / 0.13 / 0.12-0.16,
    # cube 0.20 / 0.12 / 0.12 (the last digits move with rounding: docs/ebm.md). The element-wise
    # multipliers of eq. 5.7 weight each element's gradient differently, so the fixed point is not the
    # equilibrium: about 12 % away on these meshes however many iterations.
    assert errors[100] < errors[20] and errors[500] < 0.85 * errors[20]
    assert errors[500] < 0.2


def test_ebm_beam_under_load_runs_and_bends_the_right_way():
    # Zhang 5.3.1 beam, 2 m x 0.2 m x 0.2 m, left face fixed, 0.8 N tension on the right face
    mesh = procedural.beam(cells=(20, 2, 2))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.49, density=1000.0, constitutive="neo_hookean")
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    right = select.nodes_on_side(mesh.points, 0, "max")
    model.external_force = np.zeros_like(mesh.points)
    model.external_force[right, 0] = 0.8 / right.size
    integrator = make_integrator("ebm", model, {"iterations": 20})
    state = State.at_rest(model)
    for _ in range(50):
        state = integrator.step(state, 0.01)
    stretch = (state.x[right, 0] - mesh.points[right, 0]).mean()
    # the load acts through the prediction (5.13) only: the beam stretches (positive, finite), by
    # far less than the static answer 0.8 N * 2 m / (E A) = 0.013 m (docs/ebm.md)
    assert 0.0 < stretch < 0.013
    assert len(integrator.red_history) == 50


def test_ebm_literal_sum_diverges_and_says_so():
    case = zhang_cube_shear(2)
    ebm = EBM(case.model, {"iterations": 50, "update": "sum"})
    with pytest.raises(Exception, match="non-finite"):
        ebm.step(State.at_rest(case.model), 1.0)
