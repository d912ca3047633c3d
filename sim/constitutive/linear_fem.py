"""The linear FEM stiffness of a model: K, the Hessian of linear elasticity at rest (St Venant–Kirchhoff's
at F = I). The lumped mass is ``Model.mass``; ``sim.forces`` applies Rayleigh damping ``D = alpha M + beta K``
without assembling D.

Zhang's CNN (§4.3.2.2) takes M, D and K "per Duan et al.", which the thesis does not reproduce; these
are the standard linear-tet matrices it stands for (docs/design.md, "Linear FEM matrices (Duan et al.)").
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from sim.constitutive import elastic


def stiffness_matrix(model) -> sp.csr_matrix:
    """(3n, 3n) sparse linear-elastic stiffness at the rest shape [N/m]."""
    linear = dataclasses.replace(model, constitutive="stvk", pressure="element")
    H = elastic.element_hessians(linear, model.X, project=False)
    idx = np.repeat(model.tets, 3, axis=1) * 3 + np.tile(np.arange(3), 4)[None, :]
    rows = np.repeat(idx, 12, axis=1).ravel()
    cols = np.tile(idx, (1, 12)).ravel()
    n = 3 * model.n_nodes
    return sp.coo_matrix((H.ravel(), (rows, cols)), shape=(n, n)).tocsr()
