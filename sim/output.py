"""Simulation frames as .vtu for ParaView (meshio): displacement per node, strain-energy density and
first Piola stress per tet. Written atomically (temporary file, then rename)."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import meshio
import numpy as np

from sim.constitutive import models, tensor
from sim.model import Model, State


def write_vtu(path, model: Model, state: State) -> None:
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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".vtu", dir=path.parent)
    os.close(fd)
    try:
        meshio.write(tmp, mesh, file_format="vtu")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
