"""Valanis-Landel curve materials (Qian 4.15-4.20): exact for Neo-Hookean curves, derivatives,
rest correction, and curve editing that stiffens tension only."""
from __future__ import annotations

import numpy as np
import pytest

from sim.constitutive import elastic
from sim.constitutive.valanis_landel import ValanisLandel, neo_hookean_curves
from sim.integrators.reference import ReferenceIntegrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State

MU, LAM = 1000.0, 5000.0


def _log_neo_hookean(F):
    J = np.linalg.det(F)
    I1 = np.einsum("mij,mij->m", F, F)
    psi = MU / 2 * (I1 - 3) - MU * np.log(J) + LAM / 2 * np.log(J) ** 2
    FinvT = np.linalg.inv(F).transpose(0, 2, 1)
    P = MU * (F - FinvT) + LAM * np.log(J)[:, None, None] * FinvT
    return psi, P


def _random_F(seed, m=30, spread=0.2):
    rng = np.random.default_rng(seed)
    F = np.eye(3) + spread * rng.normal(size=(m, 3, 3))
    return F[np.linalg.det(F) > 0.4]


def test_neo_hookean_curves_reproduce_neo_hookean():
    vl = ValanisLandel(**neo_hookean_curves(MU, LAM, np.linspace(0.2, 3.0, 120)))
    F = _random_F(0)
    psi, P = _log_neo_hookean(F)
    assert np.allclose(vl.energy(F), psi, rtol=1e-4, atol=1e-4 * MU)
    assert np.allclose(vl.piola(F), P, rtol=1e-4, atol=1e-4 * MU)


def test_piola_and_tangent_are_derivatives_also_when_inverted():
    vl = ValanisLandel(f_prime=[[0.2, 200.0], [1.0, 1000.0], [2.0, 4000.0], [3.0, 9000.0]],
                       h_prime=[[0.05, -5000.0], [1.0, -1000.0], [3.0, 6000.0]])
    F = _random_F(1, spread=0.15)
    F[:5, :, 0] *= -1  # some inverted (smallest stretch negative); h' extrapolates there
    P = vl.piola(F)
    h = 1e-6
    for k in range(9):
        E = np.zeros((3, 3))
        E.flat[k] = h
        fd = (vl.energy(F + E) - vl.energy(F - E)) / (2 * h)
        assert np.allclose(P.reshape(-1, 9)[:, k], fd, rtol=1e-5, atol=1e-5 * np.abs(P).max())
    T = vl.tangent(F[5:])
    for k in range(9):
        E = np.zeros((3, 3))
        E.flat[k] = 1e-5
        fd = (vl.piola(F[5:] + E) - vl.piola(F[5:] - E)).reshape(-1, 9) / 2e-5
        assert np.allclose(T[:, :, k], fd, rtol=1e-3, atol=1e-4 * np.abs(T).max())


def test_rest_correction_keeps_psi_zero_and_stress_free_rest_is_enforced():
    # an edited f' whose antiderivative would not vanish at 1: the correction (4.18) subtracts it
    vl = ValanisLandel(f_prime=[[0.5, 300.0], [1.0, 1000.0], [2.0, 5000.0]], h_prime=[[0.5, -3000.0], [1.0, -1000.0], [2.0, 3000.0]])
    assert vl.energy(np.eye(3)[None])[0] == pytest.approx(0.0, abs=1e-9)
    assert np.abs(vl.piola(np.eye(3)[None])).max() < 1e-9
    with pytest.raises(ValueError, match="stress free"):
        ValanisLandel(f_prime=[[0.5, 500.0], [1.0, 1000.0], [2.0, 2000.0]])  # f'(1) = 1000, nothing balances it
    with pytest.raises(ValueError, match="strictly increasing"):
        ValanisLandel(f_prime=[[1.0, 0.0], [0.5, 1.0]])


def test_editing_the_tension_branch_stiffens_tension_only():
    mesh = procedural.box((0.4, 0.1, 0.1), (4, 1, 1))
    base = neo_hookean_curves(MU, LAM)
    edited = {k: [list(p) for p in v] for k, v in base.items()}
    # Fig. 4.6, third row: stiffer when stretched, unchanged in compression
    edited["f_prime"] = [[x, y * (1.0 + 2.0 * max(x - 1.0, 0.0) ** 2)] for x, y in base["f_prime"]]

    def reaction(curves, strain):
        model = Model.from_mesh(mesh, E=3000.0, nu=0.4, density=1000.0, constitutive="valanis_landel",
                                material_params={"valanis_landel": curves})
        model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
        right = select.nodes_on_side(mesh.points, 0, "max")
        model.prescribed.append(PrescribedDisplacement(right, np.array([0.4 * strain, 0.0, 0.0])))
        ref = ReferenceIntegrator(model, {"mode": "quasistatic", "load_steps": 4})
        x = ref.step(State.at_rest(model), 1.0).x
        assert ref.last_residual <= 1e-8
        return -elastic.elastic_forces(model, x)[right, 0].sum()

    assert reaction(edited, 0.3) > 1.2 * reaction(base, 0.3)
    assert reaction(edited, -0.1) == pytest.approx(reaction(base, -0.1), rel=0.02)
