"""XPBD strain limiting on Green-strain entries in a material frame (Qian 4.21–4.22): stretch and shear
bounds, held (bilateral) entries, compliant limits, and the gradient of eq. 4.22 as corrected in docs/design.md ("Qian 4.22: strain-constraint gradient")."""
from __future__ import annotations

import numpy as np
import pytest

from sim.cases.zhang import zhang_cube_shear
from sim.constitutive import tensor
from sim.constitutive.elastic import elastic_gradient
from sim.integrators.xpbd.solver import XPBD
from sim.integrators.xpbd.settings import limit_boxes
from sim.integrators.xpbd.strain import entry_and_gradient, green_strain_in_frame, material_frames
from sim.mesh import procedural, select
from sim.mesh.types import TetMesh
from sim.model import Model, State

U = 2.0**-53  # unit roundoff of float64: one rounding errs by at most U relative

# Hard limits are projected after every sweep in colour order, linearised: after the last sweep a
# bound is exceeded by at most this much in E' (measured: 5e-4 on the hanging column, 4e-6 on the cube).
TOLERANCE = 1e-3


def _column(fibre):
    """Soft column (0.1 x 0.1 x 0.4 m, E = 3 kPa) hanging from its top face: ~4 Green strain at the top
    without limits."""
    mesh = procedural.box((0.1, 0.1, 0.4), (3, 3, 12))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]),
                            fibre=fibre)
    model.fixed[select.nodes_on_side(mesh.points, 2, "max")] = True
    return model


def _settle(model, steps=150, dt=0.01, **settings):
    xpbd = XPBD(model, {"substeps": 10, "iterations": 10, "damping": 20.0, **settings})
    state = State.at_rest(model)
    for _ in range(steps):
        state = xpbd.step(state, dt)
    return state


def _strain(model, x, frame):
    return green_strain_in_frame(x, model.tets, model.Dm_inv, material_frames(model, frame))


@pytest.mark.parametrize("frame", ["rest", "fibre"])
def test_green_strain_entry_gradient_matches_finite_differences(frame):
    model = _column([0.3, 0.5, 0.8])
    R = material_frames(model, frame)
    # R's entries: a normalisation and cross products, ~10 roundings each; R^T R sums 3 products: (3 x 12) U = 4e-15
    assert np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max() <= 36 * U and np.linalg.det(R).min() > 0.999
    A = np.ascontiguousarray(model.Dm_inv @ R)
    tets = model.tets.astype(np.int64)
    rng = np.random.default_rng(1)
    x = model.X + 0.02 * rng.normal(size=model.X.shape)  # 0.033 m cells: strains of tens of %
    E_all = green_strain_in_frame(x, tets, model.Dm_inv, R)
    h = 1e-6
    for t in (0, 17, 200):
        for i in range(3):
            for j in range(i, 3):
                E, g = entry_and_gradient(x, tets, A, t, i, j)
                # two paths to E = (F^T F - I) / 2, |F|^2 <= 2: F ~ 12 roundings, F^T F 5 more, of size 2: 34 U
                assert E == pytest.approx(E_all[t, i, j], abs=34 * U)
                fd = np.zeros((4, 3))
                for a in range(4):
                    for c in range(3):
                        xp, xm = x.copy(), x.copy()
                        xp[tets[t, a], c] += h
                        xm[tets[t, a], c] -= h
                        fd[a, c] = (entry_and_gradient(xp, tets, A, t, i, j)[0]
                                    - entry_and_gradient(xm, tets, A, t, i, j)[0]) / (2 * h)
                # E is quadratic in x: the central difference has no truncation error, only the rounding of the two
                # E's (34 U each, above) over 2h: 34 U / h = 3.8e-9 absolute, 1e-10 of |g| ~ 40 (measured 1e-13)
                assert np.abs(fd - g).max() <= 34 * U / h
                # Qian 4.22 corrected (docs/design.md): in the rest frame the node-k gradient of E_ij is
                # (f_j m_i[k] + f_i m_j[k]) / 2, with m_i the columns of Dm^-1 and node 0 minus the rest
                if frame == "rest":
                    F = tensor.deformation_gradients(x, tets[t:t + 1], model.Dm_inv[t:t + 1])[0]
                    m = model.Dm_inv[t]
                    qian = 0.5 * (np.outer(F[:, j], m[:, i]) + np.outer(F[:, i], m[:, j]))  # columns: nodes 1..3
                    # F (12 roundings) times m (2 products, 1 sum, 1 halving) against the kernel's own order: 32 U |g|
                    tol = 32 * U * np.abs(qian).max()
                    assert np.abs(g[1:] - qian.T).max() <= tol and np.abs(g[0] + qian.sum(axis=1)).max() <= 3 * tol


def test_shear_limit_caps_the_shear_strain_of_zhangs_sheared_cube():
    # Zhang 5.3.2: 2 m cube, bottom (y = 0) fixed, top moved 0.5 m along z: mean E_yz ~ 0.115
    limit = 0.12
    shear = {}
    for settings in ({}, {"shear_max": limit}):
        case = zhang_cube_shear(4)
        model = case.model
        xpbd = XPBD(model, {"substeps": 5, "iterations": 20, "damping": 2.0, **settings})
        state = State.at_rest(model)
        for _ in range(40):
            state = xpbd.step(state, 0.05)
        E = _strain(model, state.x, "rest")
        shear[bool(settings)] = E
        top = model.prescribed[0].nodes
        assert np.allclose(state.x[top, 2] - model.X[top, 2], 0.5)  # the top really is sheared 0.5 m
    assert np.abs(shear[False][:, 1, 2]).max() > limit + 0.04  # measured 0.172 without the limit
    assert np.abs(shear[False][:, 1, 2]).mean() > 0.09
    off = [(0, 1), (0, 2), (1, 2)]
    assert max(np.abs(shear[True][:, i, j]).max() for i, j in off) <= limit + TOLERANCE  # measured 0.120004


def test_fibre_limit_stops_the_stretch_along_the_fibre_and_leaves_cross_fibre_stretch_free():
    limit = {"limit_frame": "fibre", "limit_axes": [1], "green_stretch_max": 0.1}
    along = _column([0.0, 0.0, 1.0])  # fibre along the hanging axis
    free = _settle(along)
    limited = _settle(along, **limit)
    assert _strain(along, free.x, "fibre")[:, 0, 0].max() > 3.0  # measured 4.17: E' = 4 is stretch 3.1
    assert _strain(along, limited.x, "fibre")[:, 0, 0].max() <= 0.1 + TOLERANCE  # measured 0.1005
    assert np.abs(limited.v).max() < 1e-4  # it hangs at rest on the limit
    across = _column([1.0, 0.0, 0.0])  # fibre across: the column stretches along z as if unlimited
    free_x = _settle(across, steps=60)
    limited_x = _settle(across, steps=60, **limit)
    assert _strain(across, limited_x.x, "rest")[:, 2, 2].max() > 1.0
    assert _strain(across, limited_x.x, "fibre")[:, 0, 0].max() <= 0.1  # the fibre shortens (Poisson)
    assert np.array_equal(limited_x.x, free_x.x)  # an inactive limit moves nothing: not even a rounding


def test_held_entry_stays_at_its_value():
    column = _column([0.0, 0.0, 1.0])
    held = _settle(column, limit_frame="fibre", strain_hold={"11": 0.02})
    E = _strain(column, held.x, "fibre")[:, 0, 0]
    assert np.abs(E - 0.02).max() <= TOLERANCE  # measured 0.020000 .. 0.020525 (without: up to 4.17)
    # held at zero across the hanging direction: the fibre neither shortens (Poisson) nor stretches
    across = _column([1.0, 0.0, 0.0])
    state = _settle(across, steps=60, limit_frame="fibre", strain_hold={"11": 0.0})
    assert np.abs(_strain(across, state.x, "fibre")[:, 0, 0]).max() <= 1e-6  # measured 2.4e-8
    assert _strain(across, state.x, "rest")[:, 2, 2].max() > 1.0


def test_compliant_limit_acts_as_a_penalty_energy_of_modulus_one_over_compliance():
    # one tet, three nodes fixed, the fourth pulled along x by 2 N: with a compliant bound E'_11 <= 0.1
    # the static balance is f = dPsi_el/dx + V k (E'_11 - 0.1) dE'_11/dx, k = 1 / limit_compliance
    points = 0.1 * np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    mesh = TetMesh(points=points, tets=np.array([[0, 1, 2, 3]]))
    model = Model.from_mesh(mesh, E=100.0, nu=0.3, density=1000.0)
    model.fixed[[0, 2, 3]] = True
    f = np.array([2.0, 0.0, 0.0])
    model.external_force = np.zeros((4, 3))
    model.external_force[1] = f
    k = 1e4
    state = _settle(model, steps=300, dt=0.01, limit_frame="rest", green_stretch_max=0.1, limit_compliance=1.0 / k,
                    iterations=20)
    x = state.x
    assert np.abs(state.v).max() < 1e-9
    A = np.ascontiguousarray(model.Dm_inv)
    E11, g = entry_and_gradient(x, model.tets.astype(np.int64), A, 0, 0, 0)
    assert E11 > 0.1 + 0.05  # the compliant bound gives way (measured 0.1999; 0.1108 with k = 1e5)
    penalty = model.volume[0] * k * (E11 - 0.1) * g[1]
    elastic = elastic_gradient(model, x)[1]
    assert np.allclose(penalty + elastic, f, rtol=0, atol=2e-3 * np.linalg.norm(f))  # measured 4e-4 |f|
    assert np.linalg.norm(elastic) < 0.05 * np.linalg.norm(f)  # the balance is carried by the limit


def test_settings_are_validated():
    model = _column(None)
    with pytest.raises(ValueError, match="fibred material"):
        XPBD(model, {"limit_frame": "fibre", "shear_max": 0.1})
    with pytest.raises(ValueError, match="conflicts"):
        limit_boxes({"shear_max": 0.1, "strain_hold": {"12": 0.0}})
    with pytest.raises(ValueError, match="strain_hold entries"):
        limit_boxes({"strain_hold": {"21": 0.0}})
    with pytest.raises(ValueError, match="green_stretch_min"):
        limit_boxes({"green_stretch_min": -0.6})
    assert limit_boxes({"strain_max": 1.1}) is None  # the stretch-ratio limits are their own kernel
    i, j, lo, hi = limit_boxes({"limit_axes": [3, 1], "green_stretch_max": 0.2, "shear_max": 0.05,
                                "strain_hold": {"22": 0.01}})
    assert list(zip(i, j)) == [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    assert list(lo) == [-np.inf, 0.01, -np.inf, -0.05, -0.05, -0.05] and list(hi) == [0.2, 0.01, 0.2, 0.05, 0.05, 0.05]
