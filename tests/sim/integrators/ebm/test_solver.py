"""The Energy Balance Method (Zhang ch. 5) on the Zhang 5.3 cases, and the Prony history (5.29-5.32)."""
from __future__ import annotations

import numpy as np
import pytest

from sim.cases.zhang import relative_l2, zhang_cube_shear, zhang_cylinder
from sim.constitutive import elastic
from sim.constitutive.prony import PronyHistory
from sim.errors import SimulationDiverged
from sim.integrators import make_integrator
from sim.integrators.ebm.solver import EBM
from sim.integrators.reference import ReferenceIntegrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State


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
    energy_ref = elastic.elastic_energy(case.model, x_ref)
    errors = {}
    for iterations in (20, 100, 500):
        state, ebm = _ebm_run(case, iterations, steps)
        errors[iterations] = relative_l2(state.x - case.model.X, u_ref)
        # RED recorded once per step, finite; the stored energy is at least the equilibrium's (the reference
        # minimises it under the same boundary displacements) and, measured, 2-3.5x it (docs/ebm.md). At 20
        # iterations the sweeps have not converged and the state is one draw of a chaotic ensemble (the next test):
        # over 20,000 last-ulp realisations of the cylinder extension 2.6-4.52x (0.5 % above 4x; this case gave
        # 4.07x on an AVX-512 host's OpenBLAS), so its bound is past that support; 100 and 500 iterations: 1.9-3.4x
        # over 200 realisations of each case
        assert len(ebm.red_history) == steps and np.isfinite(ebm.red_history).all()
        energy = elastic.elastic_energy(case.model, state.x)
        assert energy_ref < energy < (6.0 if iterations == 20 else 4.0) * energy_ref
        if iterations == 20:
            assert 0.0 < ebm.work_in and ebm.red_history[-1] < 3.0  # measured 0.14-2.5 over the three cases
    # Measured (relative L2): cylinder extension 0.28 / 0.12 / 0.12, compression 0.20 / 0.13 / 0.12-0.16,
    # cube 0.20 / 0.12 / 0.12 (the last digits move with rounding: docs/ebm.md). The element-wise
    # multipliers of eq. 5.7 weight each element's gradient differently, so the fixed point is not the
    # equilibrium: about 12 % away on these meshes however many iterations.
    assert errors[100] < errors[20] and errors[500] < 0.85 * errors[20]
    assert errors[500] < 0.2


def test_ebm_beam_under_load_runs_and_iterations_pull_it_back():
    """Zhang 5.3.1 beam, 2 m x 0.2 m x 0.2 m (480 tets), left face fixed, 0.8 N tension on the right face.
    The load acts through the prediction (5.13) only, once per step, and every iteration projects each
    element towards zero energy: the more iterations, the less the beam stretches, away from the static
    answer (reference 0.013 m; docs/ebm.md). The error does *not* fall with iterations here."""
    mesh = procedural.beam(cells=(20, 2, 2))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.49, density=1000.0, constitutive="neo_hookean")
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    right = select.nodes_on_side(mesh.points, 0, "max")
    model.external_force = np.zeros_like(mesh.points)
    model.external_force[right, 0] = 0.8 / right.size
    stretch = {}
    for iterations in (20, 100, 500):
        integrator = make_integrator("ebm", model, {"iterations": iterations})
        state = State.at_rest(model)
        for _ in range(50):
            state = integrator.step(state, 0.01)
        stretch[iterations] = (state.x[right, 0] - mesh.points[right, 0]).mean()
        # RED per step, finite; the loads did positive work, far less than the strain energy of the static
        # answer, and RED near 1 (measured 0.93 / 0.99 / 0.998)
        assert len(integrator.red_history) == 50 and np.isfinite(integrator.red_history).all()
        assert 0.0 < integrator.work_in and 0.5 < integrator.red_history[-1] <= 1.0
    # measured 7.0e-4 / 7.8e-5 / 1.8e-5 m against 0.013 m static
    assert 0.0 < stretch[500] < stretch[100] < stretch[20] < 0.1 * 0.013


def _cube_x(name, displacement, ramp_time, prony=None, cells=4):
    """Zhang 5.3.3-5.3.4: 2 m cube (4 cells a side, 384 tets), E = 3000 Pa, nu = 0.49, y vertical, bottom fixed,
    top moved ``displacement`` along x over ``ramp_time``; fibre a0 = [0, 0, 1] for the anisotropic model."""
    mesh = procedural.cube(2.0, cells)
    fibre = [0.0, 0.0, 1.0] if name == "anisotropic_neo_hookean" else None
    model = Model.from_mesh(mesh, E=3000.0, nu=0.49, density=1000.0, constitutive=name, fibre=fibre)
    if prony:
        model.material_params["prony"] = prony
    bottom = select.nodes_on_side(mesh.points, 1, "min")
    model.fixed[bottom] = True
    top = select.nodes_on_side(mesh.points, 1, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.array([displacement, 0.0, 0.0]), 0.0, ramp_time))
    return model, bottom


@pytest.mark.parametrize("displacement", [0.3, -0.3], ids=["extension", "compression"])
def test_ebm_anisotropic_cube_deforms_less_along_the_fibre(displacement):
    """Zhang 5.3.3: with a0 = [0, 0, 1] the cube's sideways motion along z is smaller than the isotropic
    one's (RMS u_z ratio measured 0.74 / 0.68 at 100 iterations; 0.51 for the converged reference)."""
    rms_uz = {}
    for name in ("neo_hookean", "anisotropic_neo_hookean"):
        model, _ = _cube_x(name, displacement, 1.0)
        ebm = EBM(model, {"iterations": 100})
        state = State.at_rest(model)
        for _ in range(4):
            state = ebm.step(state, 0.25)
        u = state.x - model.X
        rms_uz[name] = float(np.sqrt(np.mean(u[:, 2] ** 2)))
        assert np.isfinite(ebm.red_history).all()
    assert rms_uz["neo_hookean"] > 1e-3  # the isotropic cube does bulge along z
    assert rms_uz["anisotropic_neo_hookean"] < 0.85 * rms_uz["neo_hookean"]


def _cube_reactions(name, prony, seed, dt=0.05, steps=100):
    """Bottom-face x reaction per step of the 5.3.4 cube (top ramped 0.3 m in -x over 0.5 s, then held), 100
    iterations; ``seed`` > 0 moves the free nodes of the start by ~1e-13 m (rounding level)."""
    model, bottom = _cube_x(name, -0.3, 0.5, prony)
    ebm = EBM(model, {"iterations": 100})
    state = State.at_rest(model)
    if seed:
        free = ~model.kinematic_mask()
        state.x[free] += 1e-13 * np.random.default_rng(seed).normal(size=(int(free.sum()), 3))
    R = []
    for _ in range(steps):
        state = ebm.step(state, dt)
        R.append(-ebm.nodal_forces(state.x, dt)[bottom, 0].sum())  # x force the cube puts on its base
    return np.array(R)


def test_ebm_viscoelastic_cube_relaxes_and_the_anisotropic_one_pushes_harder():
    """Zhang 5.3.4: alpha_1 = 0.5, tau_1 = 0.58 s; top ramped 0.3 m in -x over 0.5 s, held 4.5 s (4-cell cube,
    384 tets, 100 iterations, dt = 0.05 s). The bottom-face reaction peaks at the end of the ramp, then
    relaxes towards the long-term modulus, about 1 - alpha_1 = 0.5 of the elastic model's.

    The EBM reaction fluctuates by about 5 % from step to step (its fixed point is not an equilibrium) and the
    iteration amplifies rounding (docs/ebm.md): a 1e-13 m perturbation of the start moves one run's
    anisotropic/isotropic ratio anywhere between 0.91 and 1.11 (measured, every kernel). So the averages are
    taken over an ensemble of such perturbations; per run only the robust properties are asserted."""
    dt, steps = 0.05, 100
    t = dt * np.arange(1, steps + 1)
    hold, after_ramp = t > 3.0, t >= 0.5
    ratios = {"visco_over_elastic": [], "visco_hold_over_peak": [], "elastic_hold_over_peak": [], "aniso_over_iso": []}
    peak_times = []
    for seed in range(16):
        visco = {}
        for name in ("neo_hookean", "anisotropic_neo_hookean"):
            visco[name] = R = _cube_reactions(name, [(0.5, 0.58)], seed, dt, steps)
            assert np.isfinite(R).all() and R.min() > 0.0
            # the peak near the end of the ramp (0.5 s): a single run's step-to-step fluctuation (~5 %) can put
            # it a step or two early or late (measured 0.4-0.8 s), the ensemble's median sits on the ramp's end
            peak_times.append(t[np.argmax(R)])
            assert 0.3 <= peak_times[-1] <= 1.0
            ratios["visco_hold_over_peak"].append(R[hold].mean() / R.max())
            if seed < 4:
                elastic = _cube_reactions(name, None, seed, dt, steps)
                ratios["elastic_hold_over_peak"].append(elastic[hold].mean() / elastic.max())
                ratios["visco_over_elastic"].append(R[hold].mean() / elastic[hold].mean())
        ratios["aniso_over_iso"].append(visco["anisotropic_neo_hookean"][after_ramp].mean()
                                        / visco["neo_hookean"][after_ramp].mean())
    assert 0.45 <= np.median(peak_times) <= 0.6
    mean = {key: float(np.mean(value)) for key, value in ratios.items()}
    # stress relaxation: measured 0.63-0.65 of the peak over the last 2 s (0.57-0.71 per run); the elastic
    # model's fluctuating reaction stays at 0.84 of its peak
    assert mean["visco_hold_over_peak"] < 0.72 < mean["elastic_hold_over_peak"]
    # towards 1 - alpha_1 = 0.5 of the elastic model's (measured 0.56-0.58 on average, 0.47-0.68 per run)
    assert 0.45 < mean["visco_over_elastic"] < 0.7
    # the fibre along z stiffens the sheared cube: the anisotropic reaction is above the isotropic one on average
    # (measured 1.03-1.04 over 16-run ensembles of both kernels, single runs 0.91-1.11)
    assert mean["aniso_over_iso"] > 1.0


def test_ebm_literal_sum_diverges_and_says_so():
    case = zhang_cube_shear(2)
    ebm = EBM(case.model, {"iterations": 50, "update": "sum"})
    with pytest.raises(SimulationDiverged, match="ebm: non-finite positions"):
        ebm.step(State.at_rest(case.model), 1.0)


def test_ebm_cylinder_at_20_iterations_stays_finite_under_last_ulp_changes_of_dm_inv():
    """The 20-iteration cylinder extension of the test above, over 200 realisations of its rounding: Dm_inv moved by
    0 or +-1 ulp per entry (what another BLAS's np.linalg.inv gives). The sweeps do not converge and amplify such a
    change about 2-3x per sweep, so each realisation ends on a different state (docs/design.md, "Zhang ch. 5: EBM");
    before the prediction was kept from inverting elements, 4 of 200 stopped with "non-finite positions" (the
    prediction of step 7 or 8 inverted an element near z = 1.5 m). Measured over 400: 1.5 % of the runs shorten a
    prediction (alpha 0.66-0.9), relative L2 error 0.26-0.30. Stored energy over 20,000 realisations (an AVX-512
    host's OpenBLAS): median 3.46x the reference's, 2.6-4.52x, 0.5 % above 4x: a run is asserted within 6x (past that
    support, a blow-up is far beyond), the ensemble's median and tail against those figures."""
    case = zhang_cylinder(h=0.25, displacement=0.4)
    model = case.model
    x_ref = ReferenceIntegrator(model, {"mode": "quasistatic", "load_steps": 4}).step(
        State.at_rest(model), case.ramp_time).x
    energy_ref = elastic.elastic_energy(model, x_ref)
    Dm_inv = model.Dm_inv.copy()
    shortened, energies = 0, []
    for seed in range(200):
        ulps = np.random.default_rng(seed).integers(-1, 2, Dm_inv.shape)
        model.Dm_inv = np.ascontiguousarray(Dm_inv + ulps * np.spacing(np.abs(Dm_inv)))
        state, ebm = _ebm_run(case, 20, 8)
        assert np.isfinite(state.x).all() and np.isfinite(ebm.red_history).all()
        assert relative_l2(state.x - model.X, x_ref - model.X) < 0.35
        energies.append(elastic.elastic_energy(model, state.x) / energy_ref)
        assert 1.0 < energies[-1] < 6.0
        shortened += bool(ebm.shortened_predictions)
    assert shortened < 20  # the guard is a rare event, not the scheme
    # measured over 20,000: median 3.46, 0.47 % above 4 (200 draws: the median within about 0.03)
    assert 3.2 < np.median(energies) < 3.7 and np.mean(np.array(energies) > 4.0) < 0.05


@pytest.mark.parametrize("kernel", ["blocked", "numba", "numpy"])
def test_ebm_prediction_that_would_invert_an_element_is_shortened(kernel):
    """A free node whose velocity would carry it through the opposite face of its tets in one step: the full
    prediction 5.13 inverts them and Neo-Hookean 5.35 is undefined there (the step used to stop with "non-finite
    positions"). The velocity term is shortened by 0.9 at a time until nothing is inverted, and the step says so."""
    mesh = procedural.cube(1.0, 2)
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45, density=1000.0, constitutive="neo_hookean")
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    centre = int(np.argmin(np.linalg.norm(mesh.points - 0.5, axis=1)))
    v = np.zeros_like(mesh.points)
    v[centre] = [0.0, 0.0, 0.8 / 0.01]  # 0.8 m in one step of 0.01 s, through the cube's top (cells of 0.5 m)
    ebm = EBM(model, {"iterations": 20, "kernel": kernel})
    state = ebm.step(State(x=mesh.points.copy(), v=v), 0.01)
    assert len(ebm.shortened_predictions) == 1
    t, alpha = ebm.shortened_predictions[0]
    assert t == pytest.approx(0.01) and 0.0 < alpha < 1.0
    assert np.isfinite(state.x).all()
    D = state.x[model.tets[:, 1:]] - state.x[model.tets[:, :1]]  # rows: x_a - x_0
    assert (np.linalg.det(D) > 0.0).all()
    # without the velocity nothing is shortened and the step is the unguarded one
    quiet = EBM(model, {"iterations": 20, "kernel": kernel})
    quiet.step(State.at_rest(model), 0.01)
    assert quiet.shortened_predictions == []
