"""CNN energy propagation (Zhang 4.4, 4.7–4.12, 4.24, 4.28–4.30 signed) and the CNN with
``force_model = "energy"``. The augmented CNN on the MSD and the Zhang cube: test_zhang_cnn.py."""
from __future__ import annotations

import numpy as np
import pytest

from sim.integrators import make_integrator
from sim.integrators.cnn.energy import EnergyPropagation, flux_matrix, median_dual, shape_gradients
from sim.mesh import procedural, select
from sim.model import Model, State

LOAD = np.array([0.0, 0.0, -10.0])  # [N] at the top centre


def _pressed_cube(cells=6):
    """1 m cube, bottom fixed (Dirichlet cells), a 10 N point load pressing down on the top centre."""
    mesh = procedural.box((1.0, 1.0, 1.0), (cells, cells, cells))
    model = Model.from_mesh(mesh, E=3500.0, nu=0.45, density=1060.0)
    model.fixed = np.zeros(model.n_nodes, dtype=bool)
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    contact = int(np.argmin(np.linalg.norm(mesh.points - [0.5, 0.5, 1.0], axis=1)))
    model.external_force = np.zeros_like(mesh.points)
    model.external_force[contact] = LOAD
    return model, contact


def _interior(X):
    return np.all((X > 1e-9) & (X < 1.0 - 1e-9), axis=1)


def test_median_dual_geometry():
    mesh = procedural.box((1.0, 0.5, 0.8), (4, 3, 5))
    X, tets = mesh.points, mesh.tets
    omega, S, V = median_dual(X, tets)
    # control volumes tile the body (V_T / 4 each); summing 4 x 360 positive terms: <= 1440 u = 1.6e-13 relative
    assert omega.sum() == pytest.approx(0.4, rel=4 * tets.shape[0] * 2.0**-53)
    # the dual faces of node a inside a tet close its quarter with the tet's faces: sum = -V grad N_a
    G = shape_gradients(X, tets)
    from sim.integrators.cnn.energy import TET_EDGES
    out = np.zeros((tets.shape[0], 4, 3))
    for e, (i, j, _, _) in enumerate(TET_EDGES):
        out[:, i] += S[:, e]
        out[:, j] -= S[:, e]
    assert np.abs(out + V[:, None, None] * G).max() < 1e-14


def test_flux_is_the_laplacian_on_control_volumes():
    """(L phi)_i / Omega_i reproduces laplacian(phi) = 6 for phi = |x|^2 at every interior node, and
    rows sum to zero (a constant potential carries no flux)."""
    mesh = procedural.box((1.0, 1.0, 1.0), (5, 5, 5))
    L, omega = flux_matrix(mesh.points, mesh.tets, rho=2.5)
    phi = (mesh.points**2).sum(axis=1)
    lap = (L @ phi) / omega
    inner = _interior(mesh.points)
    # exact in exact arithmetic; a row of k terms sums with error <= k u sum|terms| (Higham 4.2), then / Omega_i
    k = np.diff(L.tocsr().indptr).max()
    u = 2.0**-53
    bound = (k + 2) * u * (abs(L) @ np.abs(phi)) / omega  # + the division and the entries' own rounding
    assert np.all(np.abs(lap[inner] - 2.5 * 6.0) <= bound[inner])
    assert np.all(np.abs(L @ np.ones(mesh.points.shape[0])) <= k * u * (abs(L) @ np.ones(mesh.points.shape[0])))


def test_cnn_potential_converges_to_the_discrete_poisson_solution():
    model, contact = _pressed_cube()
    ep = EnergyPropagation(model, {"energy_rho": 1.0})
    # source 4.4: sigma^2 / (2E) along the load at the contact node only
    sigma = 10.0 / ep.omega[contact] ** (2.0 / 3.0)
    assert ep.Q[contact] == pytest.approx([0.0, 0.0, -sigma**2 / 7000.0])
    assert np.count_nonzero(np.abs(ep.Q).sum(axis=1)) == 1
    steady = ep.steady_potential()
    scale = np.abs(ep.Q).max()
    assert np.abs(ep.residual(steady)).max() < 1e-10 * scale
    # the CNN array (4.22/4.24) evolved by forward Euler (4.12) from phi = 0 (4.25), 2 s in 10 ms steps
    phi = np.zeros_like(model.X)
    for _ in range(200):
        phi = ep.evolve(phi, 0.01)
    assert np.abs(ep.residual(phi)).max() < 1e-4 * scale  # the Poisson equation holds per control volume
    assert np.abs(phi - steady).max() < 5e-3 * np.abs(steady).max()
    assert np.all(phi[model.fixed] == 0.0)  # fixed-state cells (4.26)
    # the potential is lowest at the source (4.2's sign) and rises monotonically towards the fixed base
    psi = phi @ ep.direction
    column = np.flatnonzero(np.all(np.abs(model.X[:, :2] - 0.5) < 1e-9, axis=1))
    column = column[np.argsort(model.X[column, 2])]
    assert np.all(np.diff(psi[column]) < 0.0)  # psi (along -z) decreases going up to the contact


@pytest.mark.parametrize("gradient", ["median_dual", "edge"])
def test_forces_point_away_from_the_contact_source(gradient):
    model, contact = _pressed_cube()
    ep = EnergyPropagation(model, {"energy_gradient": gradient})
    f = ep.forces(ep.steady_potential(), model.X)
    r = model.X - model.X[contact]
    mag = np.linalg.norm(f, axis=1)
    dist = np.linalg.norm(r, axis=1)
    outward = np.einsum("ij,ij->i", f, r) / np.maximum(dist, 1e-300)
    # at the source itself the force pushes along the load (straight down) ...
    assert -f[contact, 2] > 0.85 * mag[contact]  # (measured 0.999 median-dual, 0.89 edge)
    # ... elsewhere away from it: magnitude-weighted, the outward component is most of the force's size
    # (measured 0.84 median-dual, 0.78 edge), and every force above 5 % of the largest points outward
    assert outward.sum() > 0.75 * mag.sum()
    big = (mag > 0.05 * mag.max()) & (dist > 0.0)
    assert big.sum() > 100 and np.all(outward[big] > 0.0)
    # the load is redistributed, not created: resultant along the contact force = 10 N
    assert f[:, 2].sum() == pytest.approx(-10.0, rel=1e-9)
    if gradient == "median_dual":  # symmetric load: no sideways resultant (the edge form is biased)
        assert np.abs(f[:, :2].sum(axis=0)).max() < 1e-3


def test_median_dual_gradient_is_exact_for_a_linear_potential():
    model, _ = _pressed_cube(4)
    ep = EnergyPropagation(model, {})
    ep.gain = 1.0
    g = np.array([0.3, -0.2, 0.7])
    phi = (model.X @ g)[:, None] * ep.direction[None, :]
    f = ep.forces(phi, model.X)
    inner = _interior(model.X)
    assert np.abs(f[inner] - ep.omega[inner, None] * g).max() < 1e-15


def test_cnn_with_energy_propagation_spreads_the_contact_load():
    """CNN dynamics (4.31–4.33) with the propagated load: the body settles under the same total load
    as the concentrated one, pressing down, with a much smaller dent at the contact."""
    model, contact = _pressed_cube()
    base = select.nodes_on_side(model.X, 2, "min")
    results = {}
    for force_model in ("linear_fem", "energy"):
        cnn = make_integrator("cnn", model, {"force_model": force_model, "rayleigh_alpha": 8.0, "rayleigh_beta": 0.01, "K": 4.0})
        state = State.at_rest(model)
        for _ in range(3000):
            state = cnn.step(state, 0.002)
        assert np.abs(state.v).max() < 1e-3  # settled
        u = state.x - model.X
        reaction = -(cnn.accel.K @ u.ravel()).reshape(u.shape)[base].sum(axis=0)  # force the body exerts
        results[force_model] = (u, reaction)
    u_fem, r_fem = results["linear_fem"]
    u_en, r_en = results["energy"]
    for r in (r_fem, r_en):  # the base carries the 10 N load (within the residual motion)
        assert r[2] == pytest.approx(-10.0, rel=0.002)  # measured 9.996 N both
    assert u_en[contact, 2] < 0.0
    assert 0.05 < u_en[contact, 2] / u_fem[contact, 2] < 0.5  # measured 0.16: no point dent
    assert "cnn_potential" in state.private


def test_energy_force_model_errors_are_clear():
    model, _ = _pressed_cube(3)
    with pytest.raises(ValueError, match="energy_rho"):
        make_integrator("cnn", model, {"force_model": "energy", "energy_rho": -1.0})
    with pytest.raises(ValueError, match="energy_gradient"):
        make_integrator("cnn", model, {"force_model": "energy", "energy_gradient": "sideways"})
    model.fixed[:] = False
    with pytest.raises(ValueError, match="Dirichlet"):
        make_integrator("cnn", model, {"force_model": "energy"})
