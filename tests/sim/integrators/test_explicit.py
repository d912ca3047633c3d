"""Forward Euler (``explicit``) and the CNN on a Model: substeps, kinematic nodes, gravity, divergence."""
from __future__ import annotations

import numpy as np
import pytest

from sim.errors import SimulationDiverged
from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State

G = np.array([0.0, 0.0, -9.81])
U = 2.0**-53  # unit roundoff of float64: one correctly rounded operation errs by at most U relative


def _bar(E=2000.0):
    mesh = procedural.box((0.4, 0.1, 0.1), (4, 1, 1))
    return Model.from_mesh(mesh, E=E, nu=0.3, density=1000.0, constitutive="stvk")


@pytest.mark.parametrize("name", ["explicit", "cnn"])
def test_free_fall_is_forward_euler_exactly(name):
    """No supports, gravity only, stress-free: x_n = x_0 + h^2 g n (n - 1) / 2 (the position lags one
    step behind the velocity); the CNN (K = 4 m/s, not reached) is identical."""
    model = _bar()
    model.gravity = G
    integrator = make_integrator(name, model, {"substeps": 5, "iterations": 99})  # iterations ignored
    state = State.at_rest(model)
    for _ in range(4):
        state = integrator.step(state, 0.01)
    n, h = 20, 0.002
    assert state.t == pytest.approx(0.04, rel=n * U)  # n additions of h, each rounded once
    # n substeps each add h v to x (|x| <= 0.41 m) and h g to v: 2 roundings per substep, each <= U of the
    # result, plus the rounding of h = dt / 5 and of the closed form (a few U): 2 (n + 2) U of the magnitudes
    drop = h * h * G * n * (n - 1) / 2
    assert np.abs(state.x - model.X - drop).max() <= 2 * (n + 2) * U * np.abs(state.x).max()
    assert np.abs(state.v - G * n * h).max() <= 2 * (n + 2) * U * np.abs(state.v).max()


def test_substeps_equal_smaller_steps():
    model = _bar()
    model.fixed = np.zeros(model.n_nodes, dtype=bool)
    model.fixed[select.nodes_on_side(model.X, 0, "min")] = True
    model.gravity = G
    a = make_integrator("explicit", model, {"substeps": 4, "rayleigh_beta": 0.001})
    b = make_integrator("explicit", model, {"substeps": 1, "rayleigh_beta": 0.001})
    sa = sb = State.at_rest(model)
    for _ in range(10):
        sa = a.step(sa, 0.004)
    for _ in range(40):
        sb = b.step(sb, 0.001)
    # dt / 4 = 0.004 / 4 is the double nearest 0.001 (division by 4 is exact): the same h, the same t sequence
    # and the same operations in the same order, so the results are identical bit for bit
    assert np.array_equal(sa.x, sb.x) and np.array_equal(sa.v, sb.v)
    assert sa.x[:, 2].min() < model.X[:, 2].min() - 1e-5  # the cantilever sags


@pytest.mark.parametrize("name", ["explicit", "cnn"])
def test_prescribed_nodes_follow_their_ramp(name):
    model = _bar()
    left = select.nodes_on_side(model.X, 0, "min")
    right = select.nodes_on_side(model.X, 0, "max")
    model.fixed = np.zeros(model.n_nodes, dtype=bool)
    model.fixed[left] = True
    model.prescribed = [PrescribedDisplacement(nodes=right, displacement=np.array([0.02, 0.0, 0.0]), t_end=0.1)]
    integrator = make_integrator(name, model, {"substeps": 2, "rayleigh_beta": 0.002})
    state = State.at_rest(model)
    for k in range(1, 8):
        state = integrator.step(state, 0.01)
        assert np.array_equal(state.x[left], model.X[left])
        # target X + d (t / 0.1): t summed from 2k substeps (error <= 2k U t), one multiply, one add to X
        # (|X| <= 0.4): (2k + 2) U |x| absolute
        x_tol = (2 * k + 2) * U * np.abs(state.x[right]).max()
        assert np.abs(state.x[right] - model.X[right] - [0.02 * k * 0.1, 0.0, 0.0]).max() <= x_tol
        # the speed (x - x_old) / h: the difference of two positions each off by x_tol, divided by h = 5 ms
        assert np.abs(state.v[right] - [0.2, 0.0, 0.0]).max() <= 2 * x_tol / 0.005 + 2 * U * 0.2
    middle = np.flatnonzero(np.abs(model.X[:, 0] - 0.2) < 1e-9)
    assert np.all(state.x[middle, 0] > model.X[middle, 0])  # the stretch travels into the bar


def test_divergence_is_reported_never_nan():
    """A stiff bar at 10x its explicit critical step: SimulationDiverged with a clear message."""
    model = _bar(E=1e6)
    model.fixed = np.zeros(model.n_nodes, dtype=bool)
    model.fixed[select.nodes_on_side(model.X, 0, "min")] = True
    model.gravity = G
    integrator = make_integrator("explicit", model, {})
    state = State.at_rest(model)
    with pytest.raises(SimulationDiverged,
                       match=r"explicit: (non-finite positions|displacement|the integration diverged: \d+ elements "
                             r"inverted) .*reduce dt"):
        for _ in range(2000):
            state = integrator.step(state, 0.01)
            assert np.isfinite(state.x).all()


@pytest.mark.parametrize("name", ["explicit", "cnn"])
def test_bad_settings_are_clear_errors(name):
    model = _bar()
    with pytest.raises(ValueError, match="substeps"):
        make_integrator(name, model, {"substeps": 0})
    with pytest.raises(ValueError, match="force_model"):
        make_integrator(name, model, {"force_model": "magic"})
