"""XPBD with the model's own energy (``material = "model"``): a tet whose energy is not finite is reported."""
from __future__ import annotations

import re

import numpy as np
import pytest

from sim.constitutive import tensor
from sim.errors import SimulationDiverged
from sim.integrators.xpbd.solver import XPBD
from sim.mesh import procedural
from sim.model import Model, State


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_an_inverted_tet_of_a_split_model_stops_the_step_naming_it(kernel):
    # Zhang's Neo-Hookean 5.35 has J^(-2/3): no energy for J <= 0. Before, such tets were skipped and stayed
    # inverted unseen. One free corner of a unit cube (6 tets) pushed through the cube inverts some of its tets.
    mesh = procedural.box((1.0, 1.0, 1.0), (1, 1, 1))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45, constitutive="neo_hookean")
    corner = int(np.argmax(mesh.points.sum(axis=1)))  # (1, 1, 1)
    model.fixed[:] = True
    model.fixed[corner] = False
    state = State.at_rest(model)
    state.x[corner] = [-0.5, -0.5, -0.5]
    J = np.linalg.det(tensor.deformation_gradients(state.x, model.tets, model.Dm_inv))
    inverted = np.flatnonzero(J <= 0.0)
    assert inverted.size > 0
    xpbd = XPBD(model, {"substeps": 1, "iterations": 2, "material": "model", "energy_kernel": kernel})
    with pytest.raises(SimulationDiverged) as e:
        xpbd.step(state, 0.01)
    msg = str(e.value)
    reported = int(re.search(r"tet (\d+) has a non-finite energy or stress", msg).group(1))
    assert reported in inverted and "inverted" in msg and "neo_hookean" in msg


def test_the_stable_neo_hookean_energy_is_finite_for_inverted_tets_and_restores_them():
    mesh = procedural.box((1.0, 1.0, 1.0), (1, 1, 1))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.3, constitutive="stable_neo_hookean")
    corner = int(np.argmax(mesh.points.sum(axis=1)))
    model.fixed[:] = True
    model.fixed[corner] = False
    state = State.at_rest(model)
    state.x[corner] = [0.5, 0.5, -0.3]  # through the bottom face: inverts tets through the corner
    J = np.linalg.det(tensor.deformation_gradients(state.x, model.tets, model.Dm_inv))
    assert J.min() < 0.0
    xpbd = XPBD(model, {"substeps": 10, "iterations": 20, "damping": 20.0, "material": "model"})
    for _ in range(100):
        state = xpbd.step(state, 0.05)
    J = np.linalg.det(tensor.deformation_gradients(state.x, model.tets, model.Dm_inv))
    assert J.min() > 0.5  # the corner came back out (the rest state J = 1 is the only minimum)
