"""Prony viscoelasticity in the implicit reference: a held stretch relaxes to the long-term modulus."""
from __future__ import annotations

import numpy as np
import pytest

from sim.constitutive.elastic import elastic_gradient
from sim.integrators.reference import ReferenceIntegrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State


def test_held_stretch_relaxes_towards_the_long_term_modulus():
    alpha, tau = 0.5, 0.58  # Zhang 5.3.3's viscoelastic cube terms
    mesh = procedural.box((0.4, 0.1, 0.1), (4, 1, 1))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.3, density=1000.0, constitutive="neo_hookean",
                            material_params={"prony": [(alpha, tau)]})
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    right = select.nodes_on_side(mesh.points, 0, "max")
    model.prescribed.append(PrescribedDisplacement(right, np.array([0.004, 0.0, 0.0])))  # a 1 % step
    ref = ReferenceIntegrator(model, {"mode": "quasistatic"})
    state = State.at_rest(model)
    reactions = []
    for _ in range(60):
        state = ref.step(state, 0.05)
        assert ref.last_residual <= 1e-8
        reactions.append(ref._elastic_gradient(state.x, 0.05)[right, 0].sum())
    elastic = elastic_gradient(model, state.x)[right, 0].sum()
    ratio = np.array(reactions) / elastic
    assert np.all(np.diff(ratio) < 0)  # relaxes monotonically
    assert ratio[-1] == pytest.approx(1.0 - alpha, abs=0.01)  # to the long-term modulus after 3 s (5 tau)
    assert ratio[0] > 0.9  # nearly the instantaneous modulus right after the step


def test_prony_gradient_and_hessian_are_consistent():
    mesh = procedural.box((0.2, 0.1, 0.1), (2, 1, 1))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.3, density=1000.0, constitutive="neo_hookean",
                            material_params={"prony": [(0.4, 0.3), (0.2, 2.0)]})
    ref = ReferenceIntegrator(model, {"mode": "quasistatic"})
    rng = np.random.default_rng(0)
    x = model.X + 0.01 * rng.normal(size=model.X.shape)
    ref._commit(x, 0.1)  # some history
    x = x + 0.005 * rng.normal(size=x.shape)
    g = ref._elastic_gradient(x, 0.1)
    H = ref._hessian(x, 0.1, project=False).toarray()
    h = 1e-6
    for j in range(0, x.size, 5):
        xp, xm = x.copy(), x.copy()
        xp.ravel()[j] += h
        xm.ravel()[j] -= h
        fd = (ref._elastic_energy(xp, 0.1) - ref._elastic_energy(xm, 0.1)) / (2 * h)
        assert g.ravel()[j] == pytest.approx(fd, rel=1e-5, abs=1e-9)
        fd_H = (ref._elastic_gradient(xp, 0.1) - ref._elastic_gradient(xm, 0.1)).ravel() / (2 * h)
        assert np.allclose(H[:, j], fd_H, rtol=1e-5, atol=1e-6 * np.abs(H).max())
