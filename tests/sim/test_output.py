"""Simulation frames round-trip through .vtu with the physical fields ParaView shows."""
from __future__ import annotations

import meshio
import numpy as np
import pytest

from sim.mesh import procedural
from sim.model import Model, State
from sim.output import write_vtu


def test_vtu_holds_displacement_energy_and_stress(tmp_path):
    mesh = procedural.cube(1.0, 2)
    model = Model.from_mesh(mesh, E=3000.0, nu=0.3, density=1000.0, constitutive="stvk")
    state = State.at_rest(model)
    state.x = mesh.points * np.array([1.01, 1.0, 1.0])  # 1 % uniaxial stretch along x
    write_vtu(tmp_path / "f.vtu", model, state)
    back = meshio.read(tmp_path / "f.vtu")
    assert np.allclose(back.point_data["displacement"][:, 0], 0.01 * mesh.points[:, 0])
    e = 0.5 * (1.01**2 - 1.0)
    mu, lam = model.mu[0], model.lam[0]
    assert np.allclose(back.cell_data["strain_energy_density"][0], mu * e * e + 0.5 * lam * e * e)
    P = back.cell_data["first_piola_stress"][0].reshape(-1, 3, 3)
    assert P[:, 0, 0] == pytest.approx(np.full(len(P), 1.01 * (2 * mu + lam) * e))
    assert not list(tmp_path.glob(".*"))  # no temporary file left
