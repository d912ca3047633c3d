"""nu = 0 (lam = 0): the stable Neo-Hookean energy and stress are finite (no 1 + mu/lam), every path either
simulates finitely or rejects the material with a message naming nu (issue 16, "nu = 0 passes validation")."""
from __future__ import annotations

import sys

import meshio
import numpy as np
import pytest

from sim.constitutive import elastic, models, tensor
from sim.constitutive.kernels import MATERIALS, energy_piola
from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, State
from sim.output import write_vtu

EPS = sys.float_info.epsilon
MU = 1000.0


def _gradients(n=200, seed=7):
    """Deformation gradients from near rest to large and inverted (det < 0 for some)."""
    rng = np.random.default_rng(seed)
    scale = np.repeat([1e-6, 1e-2, 0.3, 1.2], n // 4)[:, None, None]
    return np.eye(3) + scale * rng.standard_normal((n, 3, 3))


def _kernel(F, mu, lam):
    out = [energy_piola(MATERIALS["stable_neo_hookean"], tuple(f.ravel()), m, l, 0.0, 0.0, 0.0, 0.0)
           for f, m, l in zip(F, mu, lam)]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out]).reshape(-1, 3, 3)


def _magnitudes(F, mu, lam):
    """Sizes of the terms P = mu F + (lam (J - 1) - mu) cof F is summed from, per tet: a bound on the rounding."""
    J = np.linalg.det(F)
    cof = tensor.cofactor(F)
    return mu * np.abs(F).max(axis=(1, 2)) + (lam * (np.abs(J) + 1.0) + 2.0 * mu) * np.abs(cof).max(axis=(1, 2))


def test_stable_neo_hookean_at_nu_0_is_finite_and_its_stress_is_the_energy_gradient():
    F = _gradients()
    mu, lam = np.full(len(F), MU), np.zeros(len(F))
    psi = models.energy_density("stable_neo_hookean", F, mu, lam)
    P = models.first_piola("stable_neo_hookean", F, mu, lam)
    psi_k, P_k = _kernel(F, mu, lam)
    assert np.isfinite(psi).all() and np.isfinite(P).all() and np.isfinite(psi_k).all() and np.isfinite(P_k).all()
    # dPsi/dF by complex step (exact to rounding, Squire & Trapp 1998) against P: both are sums of about 20
    # rounded products of terms no larger than _magnitudes, so they agree to 32 eps times that
    h = 1e-30
    dpsi = np.zeros_like(F)
    for k in range(3):
        for l in range(3):
            G = F.astype(complex)
            G[:, k, l] += 1j * h
            dpsi[:, k, l] = models.energy_density("stable_neo_hookean", G, mu, lam).imag / h
    bound = 32 * EPS * _magnitudes(F, mu, lam)[:, None, None]
    assert (np.abs(dpsi - P) <= bound).all()
    assert (np.abs(P_k - P) <= bound).all()  # the numba kernel: the same stress
    # the energies: NumPy's textbook form against the kernel's displacement-gradient form, each within a few
    # eps of mu (I1 + |J| + 1)
    I1 = np.einsum("mij,mij->m", F, F)
    assert (np.abs(psi_k - psi) <= 16 * EPS * MU * (I1 + np.abs(np.linalg.det(F)) + 1.0)).all()
    # and the rest state is stress free, exactly
    rest_psi, rest_P = _kernel(np.eye(3)[None], [MU], [0.0])
    assert rest_psi[0] == 0.0 and not rest_P.any()


@pytest.mark.parametrize("nu", [0.2, 0.45, 0.499])
def test_stable_neo_hookean_for_nu_above_0_is_unchanged(nu):
    F = _gradients(seed=11)
    mu_s, lam_s = models_lame(3.0 * MU, nu)
    mu, lam = np.full(len(F), mu_s), np.full(len(F), lam_s)
    # the published form with gamma = 1 + mu / lam (Macklin & Müller 2021), as the code evaluated it before
    gamma = 1.0 + mu / lam
    J = tensor.det(F)
    C = np.einsum("mki,mkj->mij", F, F)
    P_gamma = mu[:, None, None] * F + (lam * (J - gamma))[:, None, None] * tensor.cofactor(F)
    psi_gamma = (0.5 * mu * (np.einsum("mii->m", C) - 3.0) + 0.5 * lam * (J - gamma) ** 2
                 - 0.5 * lam * (1.0 - gamma) ** 2)
    assert np.array_equal(models.first_piola("stable_neo_hookean", F, mu, lam), P_gamma)  # bit for bit
    assert np.array_equal(models.energy_density("stable_neo_hookean", F, mu, lam), psi_gamma)
    # the numba kernel (J from its own cofactor, Psi from H = F - I): the same stress to the rounding of
    # about 20 operations on terms no larger than _magnitudes plus lam gamma |cof|
    psi_k, P_k = _kernel(F, mu, lam)
    cof_max = np.abs(tensor.cofactor(F)).max(axis=(1, 2))
    bound = 32 * EPS * (_magnitudes(F, mu, lam) + lam * gamma * cof_max)[:, None, None]
    assert (np.abs(P_k - P_gamma) <= bound).all()


def models_lame(E, nu):
    from sim.model import lame_from_young_poisson
    mu, lam = lame_from_young_poisson(E, nu)
    return float(mu), float(lam)


def _block(nu, constitutive):
    mesh = procedural.box((0.04, 0.04, 0.04), (2, 2, 2))
    model = Model.from_mesh(mesh, E=30000.0, nu=nu, density=1000.0, constitutive=constitutive,
                            gravity=np.array([0.0, 0.0, -9.81]))
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    return model


def test_vtu_of_a_stable_neo_hookean_body_at_nu_0_is_finite(tmp_path):
    model = _block(0.0, "stable_neo_hookean")
    state = State.at_rest(model)
    state.x = state.x + 0.002 * np.random.default_rng(3).standard_normal(state.x.shape) * ~model.fixed[:, None]
    write_vtu(tmp_path / "f.vtu", model, state)
    cells = meshio.read(tmp_path / "f.vtu").cell_data
    for name in ("strain_energy_density", "first_piola_stress"):
        assert np.isfinite(cells[name][0]).all() and np.abs(cells[name][0]).max() > 0.0


INTEGRATORS = [("reference", {}), ("explicit", {"substeps": 20}), ("cnn", {}), ("ebm", {}),
               ("xpbd", {"material": "model"})]


@pytest.mark.parametrize("name, settings", INTEGRATORS)
@pytest.mark.parametrize("nu", [0.0, 0.125])
def test_stable_neo_hookean_without_a_stable_rest_state_is_rejected(name, settings, nu):
    # linearised at rest it is linear elasticity with Lamé (lam - mu, mu): bulk modulus lam - mu/3 <= 0 for
    # nu <= 1/8, and the body collapses (docs/design.md); each integrator refuses it, naming nu
    with pytest.raises(ValueError, match=rf"nu > 1/8 .* found nu = {nu:g} in 48 tet\(s\) \(first: tet 0\)"):
        make_integrator(name, _block(nu, "stable_neo_hookean"), settings)
    make_integrator(name, _block(0.13, "stable_neo_hookean"), settings)


def test_xpbd_constraints_need_nu_above_an_eighth_whatever_the_model():
    with pytest.raises(ValueError, match=r"xpbd's stable Neo-Hookean constraints .*found nu = 0 "):
        make_integrator("xpbd", _block(0.0, "neo_hookean"), {})
    make_integrator("xpbd", _block(0.0, "neo_hookean"), {"material": "model"})


@pytest.mark.parametrize("name, settings", INTEGRATORS)
def test_each_integrator_simulates_a_nu_0_body_finitely(name, settings):
    # Zhang's Neo-Hookean 5.35 at nu = 0: kappa = 2 mu / 3 > 0, a stable material with no lam division
    model = _block(0.0, "neo_hookean")
    integrator = make_integrator(name, model, settings)
    state = State.at_rest(model)
    for _ in range(5):
        state = integrator.step(state, 0.002)
    energy = elastic.elastic_energy(model, state.x)
    assert np.isfinite(state.x).all() and np.isfinite(energy)
    sag = model.X[:, 2] - state.x[:, 2]
    assert sag.max() > 0.0 and energy > 0.0  # gravity moved it and strained it
