"""Boundary conditions per component (issue 21 item 1): nodes held along some directions only (rollers, sliding
faces, symmetry planes; ``sim.model.PrescribedDisplacement.held``), honoured by every integrator."""
from __future__ import annotations

import numpy as np
import pytest

from sim.constitutive import models, tensor
from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State, free_projector

SLOPE = np.deg2rad(30.0)
NORMAL = np.array([0.0, -np.sin(SLOPE), np.cos(SLOPE)])  # the plane's normal, tilted 30 degrees about x
DOWNHILL = np.array([0.0, -np.cos(SLOPE), -np.sin(SLOPE)])  # in the plane, the direction gravity pulls along
G = 9.81


def _block(E=1e4, nu=0.3, gravity=True):
    mesh = procedural.box((0.1, 0.1, 0.1), (2, 2, 2))
    return mesh, Model.from_mesh(mesh, E=E, nu=nu, density=1000.0,
                                 gravity=np.array([0.0, 0.0, -G if gravity else 0.0]))


def test_free_projector_removes_the_held_directions_only():
    P = free_projector(np.array([[0.0, 0.0, 2.0]]))
    assert np.allclose(P, np.diag([1.0, 1.0, 0.0]), atol=1e-15)
    P = free_projector(np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))  # a repeated direction
    assert np.allclose(P, np.diag([0.0, 0.0, 1.0]), atol=1e-15)
    assert np.allclose(free_projector(NORMAL[None]) @ NORMAL, 0.0, atol=1e-15)


def test_a_fully_held_prescription_stays_kinematic_and_a_partial_one_does_not():
    mesh, model = _block()
    bottom = select.nodes_on_side(mesh.points, 2, "min")
    model.prescribed.append(PrescribedDisplacement(bottom, np.zeros(3), held=NORMAL[None]))
    assert not model.kinematic_mask().any()
    assert model.partial().nodes.tolist() == sorted(bottom.tolist())
    model.fixed[bottom[0]] = True  # a fixed node is held in every component: kinematic, not partial
    assert bottom[0] not in model.partial().nodes
    assert model.inverse_mass()[bottom[1]] > 0.0


# Centre-of-mass displacement along the slope after N steps of h with the acceleration a = g sin(30 deg): internal
# forces sum to zero and the plane's reactions are along its normal, so the downhill motion is the integrator's
# update of a constant acceleration: forward Euler (explicit, cnn) x_N = a h^2 N (N - 1) / 2, symplectic / backward
# Euler (xpbd with one substep, reference, ebm's prediction 5.13) x_N = a h^2 N (N + 1) / 2. Tolerances: 1e-9 for the
# explicit updates (25 steps of sums of O(1e-3) values plus the elastic forces' rounding, far below), the reference's
# Newton tolerance 1e-10 on the forces.
CASES = {
    "explicit": ({}, -1, 1e-9),
    "cnn": ({"K": 1e4}, -1, 1e-9),
    "xpbd": ({"damping": 0.0, "iterations": 20, "substeps": 1}, +1, 1e-9),
    "reference": ({"tol": 1e-10}, +1, 1e-6),
    # ebm's default "average" update scales each node's increment by its tet count, which does not conserve momentum
    # exactly: measured 1.03e-6 relative (the literal "sum" update conserves it to 5e-14 but needs fewer iterations)
    "ebm": ({}, +1, 1e-5),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_block_on_a_frictionless_slope_slides_down_at_g_sin_30(name):
    """The block's bottom nodes may only slide in a plane tilted 30 degrees (one held direction, not an axis): each
    stays on its plane to rounding, and the centre of mass moves down the slope as a constant g sin(30 deg) = 4.905
    m/s^2 integrates in that integrator's update (a fully fixed or an axis-aligned support would not move it)."""
    settings, sign, rel = CASES[name]
    mesh, model = _block()
    bottom = select.nodes_on_side(mesh.points, 2, "min")
    model.prescribed.append(PrescribedDisplacement(bottom, np.zeros(3), held=NORMAL[None]))
    integrator = make_integrator(name, model, settings)
    state = State.at_rest(model)
    h, N = 0.002, 25
    for _ in range(N):
        state = integrator.step(state, h)
    u = state.x - model.X
    assert np.abs(u[bottom] @ NORMAL).max() <= 1e-12  # on the plane: one projection of O(1e-3 m) values
    com = (model.mass @ u) / model.mass.sum()
    expected = G * np.sin(SLOPE) * h * h * N * (N + sign) / 2.0
    assert com @ DOWNHILL == pytest.approx(expected, rel=rel)
    assert np.abs(u[bottom] @ DOWNHILL).min() > 0.5 * expected  # the support itself slid


def _roller_compression(model, mesh, strain=-0.1, ramp=0.0):
    """Bottom held in z only, top pressed along z only, symmetry planes x = 0 and y = 0: uniaxial stress."""
    size = np.ptp(mesh.points, axis=0)
    bottom = select.nodes_on_side(mesh.points, 2, "min")
    top = select.nodes_on_side(mesh.points, 2, "max")
    z = np.array([[0.0, 0.0, 1.0]])
    model.prescribed += [
        PrescribedDisplacement(bottom, np.zeros(3), held=z),
        PrescribedDisplacement(top, np.array([0.0, 0.0, strain * size[2]]), 0.0, ramp, held=z),
        PrescribedDisplacement(select.nodes_on_side(mesh.points, 0, "min"), np.zeros(3), held=np.eye(3)[:1]),
        PrescribedDisplacement(select.nodes_on_side(mesh.points, 1, "min"), np.zeros(3), held=np.eye(3)[1:2])]
    return bottom, top


def test_reference_roller_compression_is_uniaxial_stress():
    """With rollers instead of clamps, a compressed block deforms homogeneously with stress-free sides: every node's
    displacement is F - I applied to its rest position, and P_xx = P_yy = 0 in every tet (a clamped bottom would
    barrel the block and fail both)."""
    mesh, model = _block(gravity=False)
    model.constitutive = "neo_hookean"
    _roller_compression(model, mesh)
    reference = make_integrator("reference", model, {"mode": "quasistatic", "tol": 1e-10})
    x = reference.step(State.at_rest(model), 1.0).x
    F = tensor.deformation_gradients(x, model.tets, model.Dm_inv)
    assert np.abs(F - F[0]).max() <= 1e-8  # homogeneous (Newton's tolerance 1e-10 on forces of ~10 N)
    assert F[0, 2, 2] == pytest.approx(0.9, abs=1e-12)
    assert F[0, 0, 0] == pytest.approx(F[0, 1, 1], abs=1e-10) and F[0, 0, 0] > 1.0
    name, mu, lam, eta, a0 = models.model_params(model)
    P = models.first_piola(name, F, mu, lam, eta, a0)
    assert np.abs(P[:, 0, 0]).max() <= 1e-6 * np.abs(P[:, 2, 2]).max()
    assert np.abs(P[:, 1, 1]).max() <= 1e-6 * np.abs(P[:, 2, 2]).max()


def test_chainmail_keeps_rollers_on_their_planes_and_lets_them_slide():
    mesh, model = _block(gravity=False)
    bottom, top = _roller_compression(model, mesh, strain=-0.3)
    chainmail = make_integrator("cnn_chainmail", model, {"alpha": 0.1})
    x = chainmail.step(State.at_rest(model), 0.1).x
    u = x - model.X
    assert np.abs(u[bottom, 2]).max() == 0.0
    assert np.allclose(u[top, 2], -0.03, atol=1e-15)
    assert np.abs(u[bottom][:, :2]).max() > 1e-3  # slid outwards where a clamp would hold them


def test_scene_fixed_components_and_prescribed_normal_build_partial_constraints(scene_dict, write_scene):
    """``fixed.components`` and ``prescribed.normal`` (tissuerender.scene.bc_schema) reach the model; a clamp stays a
    clamp (kinematic), so old scenes build the same model."""
    from tissuerender import load_scene
    from tissuerender.bodies import build_body

    body = scene_dict["objects"][0]
    body["fixed"] = [{"side": "z_min", "components": ["z"]}, {"side": "x_min"}]
    body["prescribed"] = [{"side": "z_max", "normal": [0.0, 0.0, 2.0], "displacement": [0.01, 0.0, -0.005],
                           "t_end": 1.0}]
    scene_dict["simulation"] = {"integrator": "xpbd"}
    scene = load_scene(write_scene(scene_dict))
    model = build_body(scene.objects[0], 0, scene).model
    x_min = select.nodes_on_side(model.X, 0, "min")
    assert np.array_equal(np.flatnonzero(model.kinematic_mask()), np.sort(x_min))
    partial = model.partial()
    z_min = select.nodes_on_side(model.X, 2, "min")
    z_max = select.nodes_on_side(model.X, 2, "max")
    expected = np.setdiff1d(np.union1d(z_min, z_max), x_min)
    assert np.array_equal(partial.nodes, expected)
    assert np.allclose(partial.P, np.diag([1.0, 1.0, 0.0]), atol=1e-15)
    # the prescribed normal moves the top only along z, half-way at t = 0.5 s (the x part is not imposed)
    top = np.isin(partial.nodes, z_max)
    assert np.allclose(partial.at(0.5)[top] - partial.rest[top], [0.0, 0.0, -0.0025], atol=1e-15)


@pytest.mark.parametrize("entry, message", [
    ({"components": ["z"], "normal": [0.0, 0.0, 1.0]}, "either 'components' or 'normal'"),
    ({"components": ["z", "z"]}, "lists a component twice"),
    ({"normal": [0.0, 0.0, 0.0]}, "non-zero vector"),
    ({"components": ["w"]}, "components"),
])
def test_bad_component_keys_exit_2_naming_the_key(scene_dict, write_scene, entry, message):
    from tissuerender.errors import UserError
    from tissuerender import load_scene

    scene_dict["objects"][0]["fixed"] = [{"side": "z_min", **entry}]
    with pytest.raises(UserError) as error:
        load_scene(write_scene(scene_dict))
    text = str(error.value)
    assert "fixed" in text and message in text and "\n" not in text.strip()
