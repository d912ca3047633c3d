"""The numba kernels (sim.integrators.ebm.kernels, sim.integrators.cnn.kernels) reproduce the NumPy reference paths
(``kernel = "numpy"``) within bounds from their operation counts for every material: isotropic, fibre, Prony,
with fixed and prescribed nodes; and the EBM energies are accurate near rest (the reason they are written in H = F - I)."""
from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from sim.constitutive import elastic, models
from sim.constitutive.kernels import inverse_cube_root
from sim.constitutive.models import energy_density_h as energy_density
from sim.errors import SimulationDiverged
from sim.forces import Accelerations
from sim.integrators import make_integrator
from sim.integrators.cnn.energy import EnergyPropagation
from sim.integrators.ebm.solver import EBM
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State

MATERIALS = [
    ("stvk", None, None),
    ("neo_hookean", None, None),
    ("stable_neo_hookean", None, None),
    ("anisotropic_neo_hookean", "tilted", None),
    ("neo_hookean", None, [(0.5, 0.05)]),
    ("anisotropic_neo_hookean", "tilted", [(0.3, 0.02), (0.2, 0.5)]),
]
IDS = ["stvk", "neo_hookean", "stable_neo_hookean", "fibre", "neo_hookean_prony", "fibre_prony"]

U = 2.0**-53  # unit roundoff of float64
# Kernel against kernel (NumPy, scalar numba, blocked): the same formulas, sums in another order. One evaluation
# (forces, energy, one sweep of a node) sums <= 24 tets' terms of ~150 flops, each rounding <= U: <= 174 U = 1.9e-14
# of the terms' size (measured 4.8e-15 on the forces).
ONE_EVALUATION = 174 * U
# Three steps of 8 sweeps then amplify a difference at the start as they amplify any perturbation of it: measured by
# perturbing the strained start by 1e-13 of |x| (larger of x and v; a property of the problem, not of the CPU). StVK's
# stiffening under compression makes it the worst conditioned. Every comparison after sweeps: the product.
AMPLIFICATION = {"stvk": 1.2e5, "neo_hookean": 3.7e3, "stable_neo_hookean": 5.2e3, "fibre": 4.1e2,
                 "neo_hookean_prony": 1.6e2, "fibre_prony": 70.0}


def _block(constitutive_name, fibre, prony):
    """0.1 x 0.08 x 0.08 m block, 4 x 3 x 3 cells (216 tets): bottom fixed, top ramped 4 mm down and 2 mm
    sideways over 0.05 s, a 0.05 N load on one free node."""
    mesh = procedural.box((0.1, 0.08, 0.08), (4, 3, 3))
    if fibre == "tilted":  # per-tet fibres, not along an axis
        rng = np.random.default_rng(5)
        fibre = rng.normal(size=(mesh.n_tets, 3)) + [0.0, 0.0, 2.0]
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45, density=1000.0, constitutive=constitutive_name, fibre=fibre)
    if prony:
        model.material_params["prony"] = prony
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    top = select.nodes_on_side(mesh.points, 2, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.array([0.002, 0.0, -0.004]), 0.0, 0.05))
    model.external_force = np.zeros_like(mesh.points)
    model.external_force[int(np.argmax(mesh.points[:, 0] - mesh.points[:, 2] + mesh.points[:, 1])), 1] = 0.05
    return model


def _strained(model):
    """Every element strained (a smooth nonlinear field, up to 4 % strain): no element is at rest, where the
    energy-balance multiplier W / |grad W|^2 amplifies rounding differences (docs/ebm.md)."""
    X = model.X
    u = np.stack([0.004 * np.sin(20 * X[:, 2] + 3 * X[:, 1]), 0.003 * np.cos(25 * X[:, 0]) + 0.02 * X[:, 2],
                  -0.03 * X[:, 2] + 0.002 * np.sin(30 * X[:, 0] * X[:, 1] / 0.08)], axis=1)
    return X + u


def _rel(a, b):
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


@pytest.mark.parametrize("name, fibre, prony, material", [(*m, i) for m, i in zip(MATERIALS, IDS)], ids=IDS)
def test_ebm_kernels_reproduce_numpy(name, fibre, prony, material):
    runs = {}
    for kernel in ("numpy", "numba"):
        model = _block(name, fibre, prony)
        ebm = EBM(model, {"iterations": 8, "kernel": kernel})
        assert ebm.kernel == kernel
        x = _strained(model)
        f, energy, _ = ebm._forces_and_energy(x, 0.01)
        x_swept = ebm._iterate(x.copy(), 0.01)
        state = State(x=x, v=np.zeros_like(x))
        for _ in range(3):  # prediction, iterations, velocities, RED, Prony history
            state = ebm.step(state, 0.01)
        history = None if ebm.prony is None else (ebm.prony.gamma.copy(), ebm.prony.g.copy())
        runs[kernel] = (f, energy, x_swept, state, np.array(ebm.red_history), history)
    (f0, e0, xs0, s0, red0, h0), (f1, e1, xs1, s1, red1, h1) = runs["numpy"], runs["numba"]
    tol = AMPLIFICATION[material] * ONE_EVALUATION
    assert np.isfinite(f0).all() and e0 > 0.0
    assert _rel(f1, f0) <= ONE_EVALUATION and abs(e1 - e0) <= ONE_EVALUATION * e0
    assert _rel(xs1, xs0) <= tol
    assert _rel(s1.x, s0.x) <= tol and _rel(s1.v, s0.v) <= tol
    # RED: relative energy differences, energies quadratic in displacements off by tol each: 2 tol per energy
    assert np.abs(red1 - red0).max() <= 4 * tol
    if prony:
        assert _rel(h1[0], h0[0]) <= tol and _rel(h1[1], h0[1]) <= tol
        assert np.abs(h0[0]).max() > 0.0  # the history did advance (it starts at zero)


@pytest.mark.parametrize("name, fibre", [("stvk", None), ("neo_hookean", None), ("stable_neo_hookean", None),
                                         ("anisotropic_neo_hookean", "tilted")])
def test_force_kernel_reproduces_constitutive_forces(name, fibre):
    """sim.forces (explicit, cnn) with the numba kernel against sim.constitutive.elastic.elastic_forces."""
    model = _block(name, fibre, None)
    x = _strained(model)
    reference = elastic.elastic_forces(model, x)
    f = Accelerations(model, {}, "explicit")(x, np.zeros_like(x)) * model.mass[:, None]
    free = ~model.kinematic_mask()
    expected = (reference + model.nodal_external_force())[free]
    assert _rel(f[free], expected) <= ONE_EVALUATION + 2 * U  # one evaluation, then / mass * mass


def test_explicit_kernel_steps_match_numpy():
    model = _block("neo_hookean", None, None)
    states = {}
    for kernel in ("numpy", "numba"):
        integrator = make_integrator("explicit", model, {"kernel": kernel, "rayleigh_beta": 0.002, "substeps": 4})
        state = State(x=_strained(model), v=np.zeros_like(model.X))
        for _ in range(5):
            state = integrator.step(state, 0.002)
        states[kernel] = state
    # 20 substeps, one force evaluation each; a stable forward-Euler step adds h^2 a to x without amplifying
    assert _rel(states["numba"].x, states["numpy"].x) <= 20 * ONE_EVALUATION


@pytest.mark.parametrize("name", ["neo_hookean", "stable_neo_hookean", "anisotropic_neo_hookean"])
def test_ebm_energy_density_is_accurate_near_rest(name):
    """Psi evaluated from H = F - I keeps its relative accuracy as F -> I (where the multiplier of 5.7
    divides it by |grad W|^2); the textbook form loses it to cancellation."""
    rng = np.random.default_rng(2)
    G = rng.normal(size=(50, 3, 3))
    mu = np.full(50, 1000.0)
    lam = np.full(50, 30000.0)
    a0 = np.tile([0.0, 0.6, 0.8], (50, 1))
    eta = 2.0 * mu if name == "anisotropic_neo_hookean" else None
    a0 = a0 if name == "anisotropic_neo_hookean" else None
    # at moderate strain both forms agree
    F = np.eye(3) + 0.05 * G
    assert np.allclose(energy_density(name, F, mu, lam, eta, a0), models.energy_density(name, F, mu, lam, eta, a0),
                       rtol=1e-11, atol=0.0)
    # at strain 1e-7 the energy is quadratic in the strain: the 1e-6 / 1e-7 ratio is 100 to O(1e-6)
    small = energy_density(name, np.eye(3) + 1e-7 * G, mu, lam, eta, a0)
    smaller = energy_density(name, np.eye(3) + 1e-8 * G, mu, lam, eta, a0)
    assert np.allclose(small / smaller, 100.0, rtol=1e-5)
    textbook = models.energy_density(name, np.eye(3) + 1e-8 * G, mu, lam, eta, a0)
    assert np.abs(textbook / smaller - 1.0).max() > 1e-3  # the cancellation the EBM had to avoid


def _pressed_cube(cells=5):
    mesh = procedural.box((1.0, 1.0, 1.0), (cells, cells, cells))
    model = Model.from_mesh(mesh, E=3500.0, nu=0.45, density=1060.0)
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    model.external_force = np.zeros_like(mesh.points)
    top = np.argsort(np.linalg.norm(mesh.points - [0.5, 0.5, 1.0], axis=1))[:2]
    model.external_force[top] = [[0.0, 1.0, -10.0], [0.5, 0.0, -6.0]]  # two contacts, not parallel
    return model


def _propagation_tol(n_nodes, n_sub):
    """Modal form: the symmetric eigen-decomposition of the N x N operator (backward error ~ N U), the powers
    (1 + h lam)^n and V diag V^T (2 N roundings an entry): 3 N U. Sub-step kernel: a node's rate sums <= 30
    neighbour terms, and a forward-Euler sub-step of the stable diffusion adds it without amplifying: 30 n U.
    Either path's bound, summed (measured 7.9e-15 modal, 0 sub-steps, against 2.2e-13 at n = 45)."""
    return (3 * n_nodes + 30 * n_sub) * U


@pytest.mark.parametrize("propagation", ["modal", "substeps"])
def test_cnn_potential_kernels_reproduce_the_euler_substeps(propagation):
    """The closed-form modal propagation and the numba sub-step kernel give the NumPy forward-Euler
    sub-steps' potential (Zhang 4.12, 4.24) within :func:`_propagation_tol`, in the transient and with fixed
    cells held non-zero."""
    model = _pressed_cube()
    reference = EnergyPropagation(model, {"kernel": "numpy"})
    fast = EnergyPropagation(model, {})
    assert fast.propagation == "modal"
    fast.propagation = propagation
    rng = np.random.default_rng(1)
    phi0 = rng.normal(size=model.X.shape) * np.abs(reference.steady_potential()).max()
    for dt in (0.01, 0.05, 0.2):
        assert reference.substeps(dt) > 1
        tol = _propagation_tol(model.n_nodes, reference.substeps(dt))
        expected = reference.evolve(phi0.copy(), dt)
        got = fast.evolve(phi0.copy(), dt)
        assert _rel(got, expected) <= tol
        # stepping on from its own result (the modal path reuses its modal coordinates): twice the bound
        assert _rel(fast.evolve(got, dt), reference.evolve(expected, dt)) <= 2 * tol
    assert np.abs(reference.evolve(phi0.copy(), 0.05) - reference.steady_potential()).max() > 0.1 * np.abs(phi0).max()  # a transient
    # fixed cells held at a non-zero potential during the call (the coupling term of the modal form)
    held = np.zeros_like(phi0)
    held[model.fixed] = phi0[model.fixed]
    n = reference.substeps(0.05)
    h = 0.05 / n
    expected = held.copy()
    for _ in range(n):
        expected = expected + h * reference.rate(expected)
    expected[model.fixed] = 0.0  # evolve() returns the fixed-state cells at phi = 0 (4.26)
    assert _rel(fast.evolve(held.copy(), 0.05), expected) <= _propagation_tol(model.n_nodes, n)
    assert _rel(reference.evolve(held.copy(), 0.05), expected) <= 30 * n * U  # the same sub-steps, summed as written


@pytest.mark.parametrize("gradient", ["median_dual", "edge"])
def test_cnn_energy_force_kernel_and_steps_match_numpy(gradient):
    model = _pressed_cube()
    runs = {}
    for kernel in ("numpy", "numba"):
        cnn = make_integrator("cnn", model, {"force_model": "energy", "energy_gradient": gradient, "kernel": kernel,
                                             "rayleigh_beta": 0.01, "K": 4.0})
        ep = cnn.energy
        x = model.X + 0.01 * np.sin(7 * model.X)
        forces = ep.forces(ep.steady_potential(), x)
        state = State.at_rest(model)
        for _ in range(5):
            state = cnn.step(state, 0.004)
        runs[kernel] = (ep.gain, forces, state)
    (g0, f0, s0), (g1, f1, s1) = runs["numpy"], runs["numba"]
    assert abs(g1 - g0) < 1e-12 * g0
    assert _rel(f1, f0) < 1e-10
    assert _rel(s1.x - model.X, s0.x - model.X) < 1e-10
    assert _rel(s1.private["cnn_potential"], s0.private["cnn_potential"]) < 1e-10


# -- the blocked kernel (sim.integrators.ebm.blocked, the default) against the scalar numba kernel -------------------------

@pytest.mark.parametrize("name, fibre, prony, material", [(*m, i) for m, i in zip(MATERIALS, IDS)], ids=IDS)
def test_ebm_blocked_kernel_reproduces_the_scalar_kernel(name, fibre, prony, material):
    """Fixed bottom, prescribed top, an external load, every material, Prony: one sweep set and three whole steps
    (prediction, iterations, velocities, RED, Prony history) equal to the scalar kernel to 1e-10."""
    runs = {}
    for kernel in ("numba", "blocked"):
        model = _block(name, fibre, prony)
        ebm = EBM(model, {"iterations": 8, "kernel": kernel})
        assert ebm.kernel == kernel
        x = _strained(model)
        x_swept = ebm._iterate(x.copy(), 0.01)
        state = State(x=x, v=np.zeros_like(x))
        for _ in range(3):
            state = ebm.step(state, 0.01)
        history = None if ebm.prony is None else (ebm.prony.gamma.copy(), ebm.prony.g.copy())
        runs[kernel] = (x_swept, state, np.array(ebm.red_history), ebm.work_in, history, model.X)
    (xs0, s0, red0, w0, h0, X), (xs1, s1, red1, w1, h1, _) = runs["numba"], runs["blocked"]
    tol = AMPLIFICATION[material] * ONE_EVALUATION  # relative to the displacements (|u| ~ 1e-3 |x|): a stricter test
    assert _rel(xs1 - X, xs0 - X) <= tol
    assert _rel(s1.x - X, s0.x - X) <= tol and _rel(s1.v, s0.v) <= tol and s1.t == s0.t
    assert np.abs(s0.x - X).max() > 1e-3  # the body did move
    assert abs(w1 - w0) <= 2 * tol * abs(w0) and np.abs(red1 - red0).max() <= 4 * tol  # energies: quadratic
    if prony:
        assert _rel(h1[0], h0[0]) <= tol and _rel(h1[1], h0[1]) <= tol


def test_ebm_blocked_kernel_with_overlapping_groups_and_substeps():
    """Kinematic targets computed in the kernel: a fixed face that a later prescribed group overrides in part
    (the last group wins, as Model.kinematic_targets), an instantaneous group, substeps; not a multiple of the
    block size in tets. Three iterations per substep: with ten, the body relaxes to near rest within nine
    substeps, where the iteration amplifies rounding differences (measured: the scalar kernel and NumPy then
    differ by 0.39 of the displacement; docs/ebm.md)."""
    mesh = procedural.box((0.1, 0.08, 0.08), (3, 3, 2))
    assert mesh.n_tets % 16 != 0
    states = {}
    for kernel in ("numba", "blocked"):
        model = Model.from_mesh(mesh, E=3000.0, nu=0.45, density=1000.0, constitutive="neo_hookean",
                                gravity=np.array([0.0, 0.0, -9.81]))
        bottom = select.nodes_on_side(mesh.points, 2, "min")
        model.fixed[bottom] = True
        top = select.nodes_on_side(mesh.points, 2, "max")
        left = select.nodes_on_side(mesh.points, 0, "min")
        model.prescribed.append(PrescribedDisplacement(top, np.array([0.0, 0.003, -0.004]), 0.01, 0.05))
        model.prescribed.append(PrescribedDisplacement(left, np.array([-0.002, 0.0, 0.0]), 0.02, 0.02))
        ebm = EBM(model, {"iterations": 3, "substeps": 3, "kernel": kernel})
        x = _strained(model)  # no element near rest, where rounding differences are amplified (docs/ebm.md)
        state = State(x=x, v=np.zeros_like(x))
        for _ in range(3):
            state = ebm.step(state, 0.01)
        kin, target = model.kinematic_targets(state.t)
        assert np.array_equal(state.x[kin], target)  # kinematic nodes exactly at their targets
        states[kernel] = state, np.array(ebm.red_history)
    (s0, red0), (s1, red1) = states["numba"], states["blocked"]
    u0, u1 = s0.x - mesh.points, s1.x - mesh.points
    assert np.abs(u0).max() > 1e-3 and _rel(u1, u0) < 1e-10 and _rel(s1.v, s0.v) < 1e-10
    assert red1.size == red0.size == 9 and np.abs(red1 - red0).max() < 1e-9 * np.abs(red0).max()


@pytest.mark.parametrize("kernel", ["numba", "blocked"])
def test_ebm_inverted_neo_hookean_element_is_reported(kernel):
    """5.35 is undefined for J <= 0: an inverted element makes the sweep non-finite, and both kernels say so."""
    model = _block("neo_hookean", None, None)
    x = model.X.copy()
    t = int(np.flatnonzero(~model.kinematic_mask()[model.tets].any(axis=1))[0])  # a tet with four free nodes
    i0, i1 = model.tets[t, 0], model.tets[t, 1]
    x[i1] = x[i0] - 0.5 * (x[i1] - x[i0])  # through the opposite face: J < 0
    ebm = EBM(model, {"iterations": 5, "kernel": kernel})
    with pytest.raises(SimulationDiverged, match="non-finite positions"):
        ebm.step(State(x=x, v=np.zeros_like(x)), 0.01)


def test_inverse_cube_root_is_accurate_over_the_range():
    """The branch-free J^(-1/3) of the blocked kernel within 2 u (u = 2^-53, the unit roundoff) of the exact
    value from 1e-250 to 1e250, exact at powers of 8, NaN for J <= 0 (as 5.35 is undefined there).

    The bound follows from the last iteration ``y += y r p(r)``, ``r = 1 - J y^3``: J y^3 takes three roundings
    (relative error <= 3u) and ``1 - J y^3`` is exact (Sterbenz), so r is off by <= 3u and y by <= 3u / 3 = u;
    the final addition rounds once more (<= u); the product y r p(r) (|r| ~ 1e-5) and the series' truncation
    (35/243 r^4) add below 1e-19. The reference is cbrt in x87 extended precision (unit roundoff 2^-64), so
    neither libm's float64 cbrt (which differs between CPUs) nor the product's rounding enters the bound."""
    @njit
    def roots(J):
        out = np.empty_like(J)
        for i in range(J.shape[0]):
            out[i] = inverse_cube_root(J[i])
        return out

    assert np.finfo(np.longdouble).nmant >= 63, "needs x87 extended precision for the reference"
    rng = np.random.default_rng(7)
    J = np.concatenate([np.exp(rng.uniform(-575.0, 575.0, 20000)), 1.0 + 1e-9 * rng.normal(size=2000),
                        rng.uniform(0.2, 5.0, 20000)])
    u = 2.0 ** -53
    error = np.abs(roots(J).astype(np.longdouble) * np.cbrt(J.astype(np.longdouble)) - 1)
    assert float(error.max()) <= 2 * u + 1e-18
    assert np.array_equal(roots(np.array([1.0, 8.0, 0.125, 64.0])), [1.0, 0.5, 2.0, 0.25])
    assert np.isnan(roots(np.array([0.0, -1.0, -1e-300]))).all()


# -- the float32 sweeps (precision = "float32", an option of the blocked kernel) -----------------------------------

@pytest.mark.parametrize("name, fibre", [("neo_hookean", None), ("anisotropic_neo_hookean", "tilted")],
                         ids=["neo_hookean", "fibre"])
def test_ebm_float32_sweeps_follow_the_float64_kernel(name, fibre):
    """The float32 lane loops (sweeps and energy accounting; positions in float64, node sums in float64 over float32
    pairs) against the float64 blocked kernel on the strained block: measured 4.8e-7 / 2.9e-7 after one set of
    sweeps, 2.6e-5 / 1.9e-6 after three steps, RED within 8e-7 (Neo-Hookean / fibre). Kinematic nodes stay exactly at
    their targets."""
    runs = {}
    for precision in ("float64", "float32"):
        model = _block(name, fibre, None)
        ebm = EBM(model, {"iterations": 8, "precision": precision})
        x = _strained(model)
        x_swept = ebm._iterate(x.copy(), 0.01)
        state = State(x=x, v=np.zeros_like(x))
        for _ in range(3):
            state = ebm.step(state, 0.01)
        kin, target = model.kinematic_targets(state.t)
        assert np.array_equal(state.x[kin], target)
        runs[precision] = (x_swept, state, np.array(ebm.red_history), model.X)
    (xs0, s0, red0, X), (xs1, s1, red1, _) = runs["float64"], runs["float32"]
    assert np.abs(s0.x - X).max() > 1e-3  # the body did move
    assert 0.0 < _rel(xs1 - X, xs0 - X) < 5e-6  # float32 (not the same code path by accident) yet close
    assert _rel(s1.x - X, s0.x - X) < 3e-4 and _rel(s1.v, s0.v) < 3e-4
    assert np.abs(red1 - red0).max() < 1e-5 * np.abs(red0).max()


def test_ebm_float32_is_refused_where_it_is_not_implemented():
    for name, prony, kernel in [("stvk", None, "blocked"), ("neo_hookean", [(0.5, 0.05)], "blocked"),
                                ("neo_hookean", None, "numba")]:
        with pytest.raises(ValueError, match="precision float32"):
            EBM(_block(name, None, prony), {"precision": "float32", "kernel": kernel})
    with pytest.raises(ValueError, match="precision must be one of"):
        EBM(_block("neo_hookean", None, None), {"precision": "half"})


def test_ebm_float32_inverted_element_is_reported():
    model = _block("neo_hookean", None, None)
    x = model.X.copy()
    t = int(np.flatnonzero(~model.kinematic_mask()[model.tets].any(axis=1))[0])
    i0, i1 = model.tets[t, 0], model.tets[t, 1]
    x[i1] = x[i0] - 0.5 * (x[i1] - x[i0])  # through the opposite face: J < 0
    ebm = EBM(model, {"iterations": 5, "precision": "float32"})
    with pytest.raises(SimulationDiverged, match="non-finite positions"):
        ebm.step(State(x=x, v=np.zeros_like(x)), 0.01)


@pytest.mark.parametrize("kernel, precision", [("numba", "float64"), ("blocked", "float64"), ("blocked", "float32")])
def test_ebm_inverted_element_with_kinematic_nodes_only_is_reported(kernel, precision):
    """Every node kinematic (no free node, so no position can turn NaN), one node prescribed through the opposite
    face of a tet: only the NaN multiplier says so. The float32 sweeps count NaN denominators after the last sweep
    instead of in every sweep (sim.integrators.ebm.blocked.sweeps_f32); the step must still fail."""
    model = _block("neo_hookean", None, None)
    t = int(np.flatnonzero(~model.kinematic_mask()[model.tets].any(axis=1))[0])
    i0, i1 = model.tets[t, 0], model.tets[t, 1]
    rest = np.setdiff1d(np.arange(model.n_nodes), [i1])
    model.prescribed = [PrescribedDisplacement(rest, np.zeros(3), 0.0, 0.0),
                        PrescribedDisplacement(np.array([i1]), -1.5 * (model.X[i1] - model.X[i0]), 0.0, 0.0)]
    assert model.kinematic_mask().all()
    ebm = EBM(model, {"iterations": 5, "kernel": kernel, "precision": precision})
    with pytest.raises(SimulationDiverged, match="non-finite positions"):
        ebm.step(State.at_rest(model), 0.01)
