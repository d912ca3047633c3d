"""Quadratic (10-node) tets in the reference integrator, 1:8 refinement, and the cantilever of issue 17."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as sla

from sim.cases.cantilever import beam_theory_tip_deflection, levels_to_reach, richardson, small_load_tip_deflection
from sim.integrators.reference import ReferenceIntegrator
from sim.integrators.reference_quadratic import QuadraticReferenceIntegrator, quadratic_model
from sim.mesh import procedural
from sim.mesh.refine import refine, to_quadratic, unique_edges
from sim.model import Model, PrescribedDisplacement, State

MATERIAL = {"E": 1.0e4, "nu": 0.3, "density": 1000.0, "constitutive": "neo_hookean"}


def _boundary(points) -> np.ndarray:
    lo, hi = points.min(axis=0), points.max(axis=0)
    return np.flatnonzero((np.isclose(points, lo) | np.isclose(points, hi)).any(axis=1))


@pytest.mark.parametrize("mesh", [procedural.box((2.0, 1.0, 0.5), (3, 2, 1)), procedural.cylinder(2.0, 0.5, 0.5)],
                         ids=["box", "cylinder"])
def test_refine_1_to_8_preserves_volume_keeps_coarse_nodes_and_conforms(mesh):
    fine = refine(mesh)
    assert fine.n_tets == 8 * mesh.n_tets
    assert fine.n_points == mesh.n_points + unique_edges(mesh.tets)[0].shape[0]
    assert np.array_equal(fine.points[:mesh.n_points], mesh.points)  # the coarse nodes, same indices
    coarse_v = procedural.signed_volumes(mesh.points, mesh.tets)
    fine_v = procedural.signed_volumes(fine.points, fine.tets)
    assert fine_v.min() > 0.0
    # the children tile their parent: the sums agree to rounding (each volume a few ulps, summed over 8 m terms)
    assert abs(fine_v.sum() - coarse_v.sum()) <= 64 * np.finfo(float).eps * coarse_v.sum()
    faces = np.sort(fine.tets[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3), axis=1)
    assert np.unique(faces, axis=0, return_counts=True)[1].max() == 2  # conforming: no face in three tets
    assert np.array_equal(to_quadratic(mesh).points, fine.points)  # the same nodes as the 10-node mesh


def _prescribe_field(model, field):
    """Every boundary node of ``model`` moved to ``field(X)`` (one prescription per node: targets differ)."""
    nodes = _boundary(model.X)
    u = field(model.X[nodes]) - model.X[nodes]
    model.prescribed = [PrescribedDisplacement(np.array([i]), u[k]) for k, i in enumerate(nodes)]
    return nodes


def test_quadratic_patch_test_reproduces_a_linear_field_exactly():
    """A homogeneous deformation F = I + A solves every hyperelastic law with no body force; quadratic tets hold
    it exactly at the interior nodes (the 4-point rule integrates the constant-stress residual exactly)."""
    model = quadratic_model(procedural.box((1.0, 1.0, 1.0), (2, 2, 2)), **MATERIAL)
    A = np.array([[0.1, 0.02, -0.03], [0.01, -0.05, 0.04], [0.0, 0.03, 0.08]])
    c = np.array([0.01, -0.02, 0.005])

    def field(X):
        return X + X @ A.T + c

    boundary = _prescribe_field(model, field)
    interior = np.setdiff1d(np.arange(model.n_nodes), boundary)
    assert interior.size == 27  # 5 x 5 x 5 node grid
    solver = QuadraticReferenceIntegrator(model, {"mode": "quasistatic", "tol": 1e-13})
    x = solver.solve(model.X.copy(), None, 1.0, 0.0)
    exact = field(model.X)
    # Newton converges quadratically: the last step leaves an error at rounding level of |u| ~ 0.1 m
    assert np.abs(x[interior] - exact[interior]).max() <= 1e-10


def _linearised_bending_error(model, solver_cls, kappa=1e-3):
    """Small-strain pure bending (curvature kappa about y): u_x = kappa x z, u_y = -nu kappa y z,
    u_z = -kappa/2 (x^2 + nu (z^2 - y^2)), a linear-elasticity solution with no body force. Boundary nodes take the
    exact field; the interior solves K u = -K_fb u_b with the tangent at rest (linear elasticity for every law).
    Returns max |u - u_exact| over the interior nodes relative to max |u_exact|."""
    nu = MATERIAL["nu"]
    X = model.X - model.X.mean(axis=0)  # the neutral axis through the middle
    u_exact = np.stack([kappa * X[:, 0] * X[:, 2], -nu * kappa * X[:, 1] * X[:, 2],
                        -0.5 * kappa * (X[:, 0] ** 2 + nu * (X[:, 2] ** 2 - X[:, 1] ** 2))], axis=1)
    solver = solver_cls(model, {"mode": "quasistatic"})
    K = solver._hessian(model.X, 1.0, project=False).tocsr()
    fixed = np.zeros(model.n_nodes, dtype=bool)
    fixed[_boundary(model.X)] = True
    b = np.repeat(fixed, 3)
    u = u_exact.ravel().copy()
    u[~b] = sla.spsolve(K[~b][:, ~b].tocsc(), -K[~b][:, b] @ u[b])
    interior = ~fixed
    return np.abs(u.reshape(-1, 3)[interior] - u_exact[interior]).max() / np.abs(u_exact).max()


def _jittered_box():
    """A 4 x 2 x 2-cell box with its interior corner nodes moved by up to 15 % of a cell: on a uniform grid the
    linear-tet stencil is a consistent difference scheme and exact for quadratic fields at the nodes."""
    mesh = procedural.box((1.0, 0.5, 0.5), (4, 2, 2))
    inner = np.setdiff1d(np.arange(mesh.n_points), _boundary(mesh.points))
    rng = np.random.default_rng(17)
    mesh.points[inner] += rng.uniform(-0.15, 0.15, (inner.size, 3)) * 0.25
    assert procedural.signed_volumes(mesh.points, mesh.tets).min() > 0.0
    return mesh


def test_quadratic_tets_reproduce_pure_bending_where_linear_tets_cannot():
    mesh = _jittered_box()
    quadratic = _linearised_bending_error(quadratic_model(mesh, **MATERIAL), QuadraticReferenceIntegrator)
    linear = _linearised_bending_error(Model.from_mesh(refine(mesh), **MATERIAL), ReferenceIntegrator)
    # the exact field is in the quadratic space: Galerkin returns it, up to the solve's rounding (cond ~ 1e3)
    assert quadratic <= 1e-10
    # the same nodes on linear tets (the 1:8 refined mesh) miss it
    assert linear >= 1e-3


def test_quadratic_cantilever_converges_to_beam_theory_under_small_load():
    """Three levels of the cantilever, (3, 1, 1) x 2^k cells, in the small-deflection limit (the tangent at rest):
    the quadratic tip deflection's change between levels falls, the finest and the Richardson extrapolation are
    within 3 % of Euler–Bernoulli + Timoshenko (the fully clamped face and the 3D effects beam theory leaves out make
    up the rest), and linear tets on the same mesh lock: less than half the deflection."""
    base = (3, 1, 1)
    tips = [small_load_tip_deflection(k, True, base=base) for k in range(3)]
    theory = beam_theory_tip_deflection(1.0)
    d = np.abs(np.diff(tips))
    assert d[1] < 0.5 * d[0]  # at least first order; quadratic tets do better
    assert abs(tips[-1] / theory - 1.0) <= 0.03
    extrapolated = richardson(tips, assumed_order=3.0)["extrapolated"]
    assert abs(extrapolated / theory - 1.0) <= 0.03
    assert small_load_tip_deflection(1, False, base=base) < 0.5 * tips[1]


def test_levels_to_reach_extrapolates_from_the_observed_rate():
    # errors halving per level (rate 1): 8 % at level 2 needs three more levels for 1 %
    out = levels_to_reach([0.32, 0.16, 0.08], [0, 1, 2], 0.01)
    assert out["how"] == "extrapolated" and out["rate"] == pytest.approx(1.0) and out["level"] == pytest.approx(5.0)
    assert out["tets"] == 60 * 8**5
    assert levels_to_reach([0.05, 0.009], [0, 1], 0.01) == {"level": 1, "tets": 480, "how": "measured", "rate": None}


def test_quadratic_dynamic_step_moves_the_centre_of_mass_by_g_h_squared():
    """Backward Euler on a free body from rest: internal forces cancel in the sum, so sum_a m_a (x_a - X_a) / h^2
    is the total load; the consistent gravity load (int N_a dV) and the HRZ masses both sum to the body's, so the
    centre of mass moves by g h^2 exactly (to the Newton tolerance) although corners and edge nodes move apart."""
    model = quadratic_model(procedural.box((0.2, 0.1, 0.1), (2, 1, 1)), gravity=np.array([0.0, 0.0, -9.81]),
                            **MATERIAL)
    assert model.mass.sum() == pytest.approx(1000.0 * 0.002, rel=1e-14)
    assert model.nodal_external_force()[:, 2].sum() == pytest.approx(-9.81 * 2.0, rel=1e-14)
    h = 0.01
    solver = QuadraticReferenceIntegrator(model, {"mode": "dynamic", "tol": 1e-12})
    state = solver.step(State.at_rest(model), h)
    shift = (model.mass[:, None] * (state.x - model.X)).sum(axis=0) / model.mass.sum()
    assert shift == pytest.approx([0.0, 0.0, -9.81 * h * h], abs=1e-12)
    assert np.ptp(state.x[:, 2] - model.X[:, 2]) > 1e-9  # not a rigid translation: the element deforms


def test_predicted_start_solves_a_compression_whose_plain_start_inverts_elements():
    """Zhang's cylinder on quadratic tets pressed 0.4 m in one load step: moving only the held face's nodes
    crushes the element layer next to it (the energy is not finite: J < 0), so Newton has no descent direction
    from there. The displacement predictor (``ReferenceIntegrator._predicted``) spreads the move over the body;
    one load step then reaches the equilibrium of four (measured 1.5e-14 m apart at mid-line, both converged to
    a relative gradient of 1e-8)."""
    from sim.cases.zhang import zhang_case
    from sim.integrators.reference_quadratic import reference_for

    case = zhang_case("cylinder_compression", 0.25, 4, 0, True)
    m = case.model
    solver = reference_for(m, {"mode": "quasistatic", "load_steps": 1})
    kin, target = m.kinematic_targets(case.ramp_time)
    plain = m.X.copy()
    plain[kin] = target
    f_ext = m.nodal_external_force()
    with np.errstate(invalid="ignore"):
        assert not np.isfinite(solver._phi(plain, None, case.ramp_time, f_ext))
    predicted = solver._predicted(m.X.copy(), case.ramp_time, case.ramp_time)
    assert np.isfinite(solver._phi(predicted, None, case.ramp_time, f_ext))
    np.testing.assert_array_equal(predicted[kin], target)
    mid = case.line[len(case.line) // 2]
    u = {}
    for steps in (1, 4):
        s = reference_for(m, {"mode": "quasistatic", "load_steps": steps})
        with np.errstate(invalid="ignore"):
            u[steps] = s.step(State.at_rest(m), case.ramp_time).x - m.X
        assert s.last_residual <= 1e-8
    assert abs(u[1][mid, case.component]) > 0.05  # the mid-line moves 6.5 cm
    np.testing.assert_allclose(u[1], u[4], rtol=0, atol=1e-9)
