"""Poly6 stiffness painting (Qian 4.26-4.28)."""
from __future__ import annotations

import numpy as np
import pytest

from sim.integrators.reference import ReferenceIntegrator
from sim.mesh import procedural, select
from sim.model import Model, State
from sim.painting import Stroke, apply_painting, paint_weights, poly6


def test_poly6_is_a_normalised_smooth_kernel():
    h = 0.3
    r = np.linspace(0.0, h, 20001)
    # integral over the ball of radius h is 1 (a density kernel)
    assert np.trapezoid(4 * np.pi * r**2 * poly6(r, h), r) == pytest.approx(1.0, rel=1e-6)
    assert poly6(np.array([h, 2 * h]), h).max() == 0.0 and np.all(np.diff(poly6(r, h)) <= 0)


def test_stroke_weights_peak_at_the_centre_and_vanish_outside():
    points = np.array([[0.0, 0, 0], [0.05, 0, 0], [0.1, 0, 0], [0.2, 0, 0]])
    W = paint_weights(points, [Stroke((0.0, 0.0, 0.0), 0.1, 4.0)])
    assert W[0] == pytest.approx(4.0) and W[1] == pytest.approx(4.0 * (1 - 0.25) ** 3)
    assert W[2] == 0.0 and W[3] == 0.0


def test_painted_region_is_stiffer_and_deforms_less():
    mesh = procedural.box((0.4, 0.1, 0.1), (8, 2, 2))

    def sag(strokes):
        model = Model.from_mesh(mesh, E=3e4, nu=0.45, density=1000.0, constitutive="stable_neo_hookean",
                                gravity=np.array([0.0, 0.0, -9.81]))
        model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
        factor = apply_painting(model, strokes)
        x = ReferenceIntegrator(model, {"mode": "quasistatic"}).step(State.at_rest(model), 1.0).x
        tip = select.nodes_on_side(mesh.points, 0, "max")
        return -(x[tip, 2] - mesh.points[tip, 2]).mean(), factor, model

    plain, factor, _ = sag([])
    assert np.all(factor == 1.0)
    painted, factor, model = sag([Stroke((0.05, 0.05, 0.05), 0.15, 9.0)])  # stiffen the clamped end
    assert factor.max() > 5.0 and factor.min() == 1.0
    assert np.allclose(model.nu, 0.45)  # Poisson ratio untouched
    assert painted < 0.8 * plain  # the cantilever's root carries the bending: stiffer root, less sag
    with pytest.raises(ValueError, match="non-positive"):
        apply_painting(model, [Stroke((0.0, 0.0, 0.0), 0.1, -5.0)])
