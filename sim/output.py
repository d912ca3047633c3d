"""Simulation frames as .vtu for ParaView (meshio): displacement and velocity per node, strain-energy density,
first Piola stress and J per tet. ``write_vtu`` writes the file it is given; the application makes the write
atomic (its one atomic-write helper hands a temporary path, then renames)."""
from __future__ import annotations

import meshio
import numpy as np

from sim.constitutive import models, tensor
from sim.model import Model, State


def write_vtu(path, model: Model, state: State) -> None:
    """Write one frame to ``path`` in the VTU format (whatever the path's suffix)."""
    name, mu, lam, eta, a0 = models.model_params(model)
    F = tensor.deformation_gradients(state.x, model.tets, model.Dm_inv)
    with np.errstate(invalid="ignore", divide="ignore"):
        vl = models.model_curves(model)
        psi = models.energy_density(name, F, mu, lam, eta, a0, vl=vl)
        P = models.first_piola(name, F, mu, lam, eta, a0, vl=vl)
    mesh = meshio.Mesh(
        state.x,
        [("tetra", model.tets)],
        point_data={"displacement": state.x - model.X, "velocity": state.v},
        cell_data={"strain_energy_density": [psi], "first_piola_stress": [P.reshape(-1, 9)],
                   "J": [np.linalg.det(F)]},
    )
    meshio.write(path, mesh, file_format="vtu")
