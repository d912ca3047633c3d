"""Neural-dynamics ChainMail (Zhang 3.4): strain limits 3.53, pairwise fixes 3.55, templates 3.61–3.63,
fixed-state cells; its error against the quasi-static reference."""
from __future__ import annotations

import numpy as np
import pytest

from sim.integrators import make_integrator
from sim.integrators.chainmail import mesh_edges, mu, strain_limits
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State

PRESS = np.array([0.0, 0.0, -0.08])  # [m], ramped over 0.5 s on the 3 x 3 top-centre nodes


def _pressed_cube():
    """1 m cube (6^3 cells), bottom fixed, the top-centre patch pressed 8 cm down (no forces)."""
    mesh = procedural.box((1.0, 1.0, 1.0), (6, 6, 6))
    X = mesh.points
    model = Model.from_mesh(mesh, E=3500.0, nu=0.45, density=1060.0)
    model.fixed = np.zeros(model.n_nodes, dtype=bool)
    model.fixed[select.nodes_on_side(X, 2, "min")] = True
    top = select.nodes_on_side(X, 2, "max")
    patch = top[np.all(np.abs(X[top, :2] - 0.5) <= 1.0 / 6.0 + 1e-9, axis=1)]
    model.prescribed = [PrescribedDisplacement(nodes=patch, displacement=PRESS, t_start=0.0, t_end=0.5)]
    return model, patch


def test_pairwise_fix_restores_a_link_to_its_limit():
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    edges = np.array([[0, 1]])
    l0, l_min, l_max = strain_limits(X, edges, 0.1)
    assert (l_min[0], l_max[0]) == pytest.approx((0.9, 1.1))  # 3.53
    for length, limit in ((1.5, 1.1), (0.5, 0.9), (1.05, None)):
        P = np.array([[0.2, 0.3, 0.0], [0.2 + length * 0.6, 0.3 + length * 0.8, 0.0]])
        u = np.linalg.norm(P[1] - P[0])
        m = mu(np.array([u]), l_min, l_max)[0]  # 3.61
        Pi = P[0] + m * (P[1] - P[0])  # 3.55 / 3.60
        Pj = P[1] - m * (P[1] - P[0])
        if limit is None:
            assert m == 0.0  # within its limits: no adjustment
        else:
            assert np.linalg.norm(Pj - Pi) == pytest.approx(limit, rel=1e-14)
            assert np.allclose(0.5 * (Pi + Pj), 0.5 * (P[0] + P[1]))  # both ends move equally


def test_every_link_ends_within_its_strain_limits():
    model, patch = _pressed_cube()
    cm = make_integrator("cnn_chainmail", model, {"alpha": 0.1, "tolerance": 1e-4})
    edges = mesh_edges(model.tets)
    l0, l_min, l_max = strain_limits(model.X, edges, 0.1)
    state = State.at_rest(model)
    base = model.fixed
    for _ in range(5):
        state = cm.step(state, 0.1)
        u = np.linalg.norm(state.x[edges[:, 1]] - state.x[edges[:, 0]], axis=1)
        assert np.all(u <= l_max + 1e-4 * l0) and np.all(u >= l_min - 1e-4 * l0)
        assert np.array_equal(state.x[base], model.X[base])  # fixed-state cells
    assert np.allclose(state.x[patch], model.X[patch] + PRESS)  # the input displacement, fully applied
    assert cm.last_violation <= 1e-4 and cm.last_sweeps < 500
    # the press is felt beyond the contact: some links besides the patch's own are at their limit
    moved = np.linalg.norm(state.x - model.X, axis=1) > 1e-3
    assert moved.sum() > 2 * patch.size
    assert state.t == pytest.approx(0.5)


def test_error_against_the_reference():
    """Relative L2 displacement error against the quasi-static Neo-Hookean reference (measured
    0.72 / 0.82 / 0.88 for alpha = 0.1 / 0.2 / 0.4): plausible, not mechanical; tighter strain limits
    spread the press further and come closer to elasticity; all beat moving only the patch (0.90)."""
    model, patch = _pressed_cube()
    reference = make_integrator("reference", model, {"mode": "quasistatic"})
    u_ref = reference.step(State.at_rest(model), 0.5).x - model.X
    norm = np.linalg.norm(u_ref)
    kin = model.kinematic_mask()
    patch_only = np.linalg.norm(np.where(kin[:, None], u_ref, 0.0) - u_ref) / norm
    errors = []
    for alpha in (0.1, 0.2, 0.4):
        cm = make_integrator("cnn_chainmail", model, {"alpha": alpha})
        state = State.at_rest(model)
        for _ in range(5):
            state = cm.step(state, 0.1)
        errors.append(np.linalg.norm(state.x - model.X - u_ref) / norm)
    assert errors[0] < errors[1] < errors[2] < patch_only
    assert errors[0] < 0.8


def test_chainmail_rejects_forces_and_bad_parameters():
    model, _ = _pressed_cube()
    with pytest.raises(ValueError, match="alpha"):
        make_integrator("cnn_chainmail", model, {"alpha": 1.5})
    model.gravity = np.array([0.0, 0.0, -9.81])
    with pytest.raises(ValueError, match="prescribed displacements"):
        make_integrator("cnn_chainmail", model, {})


def test_probe_pushes_the_chainmail_and_scene_strain_keys():
    """A sphere probe pressing 6 cm into the top: no node ends inside it, the links obey the scene's
    asymmetric stretch limits [0.85, 1.1], and the dent spreads beyond the touched nodes."""
    from sim.probe import Probe
    mesh = procedural.box((1.0, 1.0, 1.0), (6, 6, 6))
    model = Model.from_mesh(mesh, E=3500.0, nu=0.45, density=1060.0)
    model.fixed = np.zeros(model.n_nodes, dtype=bool)
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    radius = 0.25
    model.probes = [Probe(kind="sphere", radius=radius, times=[0.0, 0.5],
                          positions=[[0.5, 0.5, 1.0 + radius], [0.5, 0.5, 1.0 + radius - 0.06]])]
    cm = make_integrator("cnn_chainmail", model, {"strain_min": 0.85, "strain_max": 1.1, "tolerance": 1e-4})
    state = State.at_rest(model)
    for _ in range(5):
        state = cm.step(state, 0.1)
    centre = np.array([0.5, 0.5, 1.0 + radius - 0.06])
    assert np.linalg.norm(state.x - centre, axis=1).min() >= radius - 1e-9
    edges = mesh_edges(model.tets)
    l0 = np.linalg.norm(model.X[edges[:, 1]] - model.X[edges[:, 0]], axis=1)
    u = np.linalg.norm(state.x[edges[:, 1]] - state.x[edges[:, 0]], axis=1)
    assert np.all(u / l0 >= 0.85 - 2e-4) and np.all(u / l0 <= 1.1 + 2e-4)
    dz = model.X[:, 2] - state.x[:, 2]
    assert dz.max() == pytest.approx(0.06, abs=1e-3)  # the top centre follows the sphere's lowest point
    assert np.count_nonzero(dz > 1e-3) > 5  # and drags a neighbourhood down with it
