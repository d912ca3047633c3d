"""Contact between a body and a static plane with Coulomb friction (issue 21 item 4; ``sim.contact``, xpbd)."""
from __future__ import annotations

import numpy as np
import pytest

from sim.contact import ContactPlane
from sim.integrators import make_integrator
from sim.mesh import procedural
from sim.model import Model, State

G = 9.81


def _block_on_incline(angle_deg, friction, E=1e5):
    """A 1 kg, 10 cm block (3x3x3 nodes) resting on a plane through the origin tilted by ``angle_deg`` about y (its
    normal (sin, 0, cos)); the block's bottom face lies on the plane."""
    theta = np.radians(angle_deg)
    rot = np.array([[np.cos(theta), 0.0, np.sin(theta)], [0.0, 1.0, 0.0], [-np.sin(theta), 0.0, np.cos(theta)]])
    mesh = procedural.box((0.1, 0.1, 0.1), (2, 2, 2))
    mesh.points = mesh.points @ rot.T
    model = Model.from_mesh(mesh, E=E, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -G]))
    model.contact_planes = [ContactPlane([0.0, 0.0, 0.0], rot[:, 2], friction)]
    return model, rot


def _run(model, settings, steps, dt):
    integrator = make_integrator("xpbd", model, settings)
    state = State.at_rest(model)
    for _ in range(steps):
        state = integrator.step(state, dt)
    return integrator, state


def test_a_block_resting_on_a_flat_plane_presses_it_with_its_weight():
    model, rot = _block_on_incline(0.0, 0.0)
    integrator, state = _run(model, {"substeps": 10, "iterations": 8, "damping": 10.0}, 60, 0.01)
    weight = model.mass.sum() * G
    force = integrator.plane_loads[0]
    assert force[2] == pytest.approx(-weight, rel=0.01)  # measured -9.80975 N: 2.5e-5
    assert np.abs(force[:2]).max() < 1e-9 * weight
    # the weight acts through the block's centre (0.05, 0.05): torque about the plane's point (the origin)
    # r x F = (0.05 fz, -0.05 fz, 0) (measured 1.7e-4 relative: the tet pattern is not symmetric, and it still settles)
    np.testing.assert_allclose(integrator.plane_loads[0, 3:], [0.05 * force[2], -0.05 * force[2], 0.0],
                               rtol=1e-3, atol=1e-3 * abs(force[2]) * 0.05)
    # the plane's projection runs last in every sweep: no node below it, up to rounding (coordinates ~0.1 m: 1e-15)
    assert state.x[:, 2].min() > -1e-12


def test_on_an_incline_steeper_than_friction_allows_the_block_slides_else_it_sticks():
    angle = 20.0  # tan 20 deg = 0.364
    theta = np.radians(angle)
    settings = {"substeps": 10, "iterations": 8, "damping": 0.0}
    model, rot = _block_on_incline(angle, 0.6, E=1e6)
    integrator, state = _run(model, settings | {"damping": 10.0}, 30, 0.01)
    weight = model.mass.sum() * G
    # sticks: nodes move along the plane only by the block's elastic shear under its tangential weight
    # (rho g sin H / G ~ 1e-3 strain: ~1e-4 m; measured 1.25e-4 m); sliding at mu = 0.2 it would go 5 cm in 0.3 s
    assert np.abs(((state.x - model.X) @ rot[:, 0])).max() < 3e-4
    # sticking, the plane carries the whole weight (normal reaction plus static friction), within 1 %
    np.testing.assert_allclose(integrator.plane_loads[0, :3], [0.0, 0.0, -weight], atol=0.01 * weight)

    model, rot = _block_on_incline(angle, 0.2, E=1e6)
    T = 0.4
    integrator, state = _run(model, settings, 40, 0.01)
    downhill = rot[:, 0]  # the plane's x axis points downhill (gravity's tangential part is +g sin along it)
    mass = model.mass[:, None]
    v = (state.v * mass).sum(axis=0) / mass.sum()
    expected = G * (np.sin(theta) - 0.2 * np.cos(theta)) * T
    # the centre of mass moves by gravity and the plane's impulses only; kinetic friction mu d_n per substep is
    # Coulomb's impulse mu N h exactly, so the error is the block's vibration: measured +0.2 %
    assert v @ downhill == pytest.approx(expected, rel=0.01)
    assert abs(v @ rot[:, 2]) < 0.01 * expected  # stays on the plane
