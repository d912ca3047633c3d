"""Zhang §4.3.2: the mass–spring–damper and the cube, explicit (forward Euler) against the CNN."""
from __future__ import annotations

import numpy as np
import pytest

from sim.cases.msd import MassSpringDamper, saturate, simulate
from sim.cases.zhang import zhang_cnn_cube
from sim.errors import SimulationDiverged
from sim.integrators import make_integrator
from sim.model import State

MSD = MassSpringDamper()  # m = 0.2 kg, k = 400 N/m, d = 2, l0 = 1 m, y0 = -1 m, v0 = -5 m/s


def _max_error(dt, scheme, K=np.inf, saturation="state", t_end=1.0):
    t, y = simulate(MSD, dt, t_end, scheme, K, saturation)
    return float(np.max(np.abs(y - MSD.analytic(t)))), y


def test_analytic_solution_solves_the_ode():
    t = np.linspace(0.0, 1.0, 20001)
    y = MSD.analytic(t)
    dt = t[1] - t[0]
    v = np.gradient(y, dt)
    a = np.gradient(v, dt)
    residual = MSD.m * a[5:-5] + MSD.d * v[5:-5] + MSD.k * (y[5:-5] - MSD.y_rest)
    assert np.abs(residual).max() < 1e-3 * MSD.k * 0.1
    assert y[0] == pytest.approx(-1.0) and v[1] == pytest.approx(-5.0, rel=1e-3)


def test_saturation_is_eq_4_33():
    v = np.array([-10.0, -4.0, -1.0, 0.0, 2.5, 7.0])
    assert np.allclose(saturate(v, 4.0), np.clip(v, -4.0, 4.0))


def test_small_step_explicit_and_cnn_match_the_analytic_solution():
    # dt = 0.0008 s: forward Euler's error stays below 1 cm over 1 s (measured 7.2 mm, 0.7 % of the
    # 1 m swing scale); the CNN with K = 5 never saturates (|v| <= 5) and is identical to it
    err_explicit, y_explicit = _max_error(0.0008, "explicit")
    err_cnn, y_cnn = _max_error(0.0008, "cnn", K=5.0)
    assert err_explicit < 0.01 and err_cnn < 0.01
    # up to the rounding of eq. 4.33's |.| form: <= 2 extra roundings a step over 1250 steps, of |y| <= 1 m, and
    # forward Euler on an oscillator at omega h << 1 grows a difference by (1 + omega^2 h^2)^(n/2) ~ 1: 2.8e-13 m
    assert np.abs(y_cnn - y_explicit).max() < 1e-12


@pytest.mark.parametrize("saturation", ["state", "output"])
def test_large_step_explicit_diverges_and_cnn_stays_bounded_better_with_smaller_K(saturation):
    err_explicit, y_explicit = _max_error(0.01, "explicit", t_end=3.0)
    assert err_explicit > 100.0  # forward Euler amplifies each step by |1 + h lambda| = 1.049
    errors = [_max_error(0.01, "cnn", K=K, saturation=saturation, t_end=3.0)[0] for K in (5.0, 4.0, 2.0)]
    assert max(errors) < 0.3  # bounded (measured state 0.14/0.11/0.055, output 0.23/0.19/0.12)
    assert errors[0] > errors[1] > errors[2]  # closer to the analytic solution as K gets smaller


SETTINGS = {"force_model": "linear_fem", "rayleigh_beta": 0.002}


def _run(model, name, dt, t_end, **extra):
    integrator = make_integrator(name, model, {**SETTINGS, **extra})
    state = State.at_rest(model)
    peak = 0.0
    for _ in range(int(round(t_end / dt))):
        state = integrator.step(state, dt)
        peak = max(peak, float(np.abs(state.x - model.X).max()))
    return state, peak


def test_cube_small_step_cnn_and_explicit_agree():
    model, centre = zhang_cnn_cube()
    assert model.n_nodes == 1331 and model.n_tets == 6000
    explicit, _ = _run(model, "explicit", 0.001, 1.0)
    cnn, _ = _run(model, "cnn", 0.001, 1.0, K=4.0)
    # no cell reaches K: the same forward-Euler steps up to 4.33's rounding (2 u a step, 1000 steps, |x| <= 1 m)
    assert np.abs(cnn.x - explicit.x).max() < 1e-12
    sag = model.X[centre, 2] - explicit.x[centre, 2]
    # between the fully confined (p / (lam + 2 mu)) and the free uniaxial (p / E) static answers,
    # allowing a dynamic overshoot of 2 (measured 1.2 cm)
    assert 100.0 / 13276.0 * 0.9 < sag < 2 * 100.0 / 3500.0


@pytest.mark.parametrize("saturation", ["state", "output"])
def test_cube_large_step_explicit_blows_up_and_cnn_stays_finite(saturation):
    model, centre = zhang_cnn_cube()
    with pytest.raises(SimulationDiverged, match="diverged|non-finite"):
        _run(model, "explicit", 0.02, 2.0)
    state, peak = _run(model, "cnn", 0.02, 2.0, K=4.0, saturation=saturation)
    assert np.isfinite(state.x).all()
    # bounded, though not accurate: a bounded oscillation (measured peak 0.19 m with state saturation,
    # 0.56 m with output saturation, on a 1 m cube whose static sag is 1.2 cm)
    assert peak < 1.0
    assert np.abs(state.v).max() <= 4.0 + 1e-12
