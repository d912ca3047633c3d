"""The reference integrator on quadratic (10-node) tetrahedra: the same Newton solver, line search, boundary
conditions and constitutive laws as ``sim.integrators.reference``, with the element energy integrated at Gauss points.

Shape functions in the barycentric coordinates ``L_0..L_3`` of the (straight-edged) tet: corner ``a``
``N_a = L_a (2 L_a - 1)``, edge ``ab`` ``N_ab = 4 L_a L_b``; ``grad N = sum_k dN/dL_k grad L_k`` with ``grad L_k`` the
rows of ``Dm^-1`` (``grad L_0`` minus their sum), constant per tet. Per Gauss point q (4-point rule, barycentric
``(a, b, b, b)`` and its permutations, ``a = (5 + 3 sqrt 5) / 20``, ``b = (5 - sqrt 5) / 20``, weights ``V / 4``:
exact for polynomials of degree 2, so the small-strain stiffness ``int grad N . C grad N`` of a straight-edged
element is exact)::

    F_q = sum_a x_a (x) grad N_a(q)
    E   = sum_q w_q Psi(F_q),     dE/dx_a = sum_q w_q P(F_q) grad N_a(q),     H = sum_q w_q B_q^T (dP/dF)_q B_q

``Psi``, ``P`` and ``dP/dF`` come from ``sim.constitutive.models`` (every model but Valanis–Landel curves need
nothing per element; Prony viscoelasticity and average nodal pressure are linear-tet only and rejected).

Loads: gravity is the consistent body force ``rho g int N_a dV`` (corner ``-V/20``, edge ``V/5``: the corners'
share is negative, as it is for every complete quadratic element), so a quadratic mesh carries exactly the
weight of its body. Mass for the dynamic mode: HRZ lumping (Hinton, Rock & Zienkiewicz 1976): the consistent mass
matrix's diagonal (corner ``V/70``, edge ``8V/105``) scaled to the element's mass: corner ``rho V / 36``, edge
``4 rho V / 27``.

The PSD-projected Hessian that Newton falls back on far from equilibrium clamps the tangent ``dP/dF`` at each Gauss
point (linear tets clamp the element Hessian).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.linalg import spsolve

from sim.constitutive import models, tensor
from sim.integrators.reference import ReferenceIntegrator, ReferenceSettings
from sim.mesh.refine import TET_EDGES, QuadraticTetMesh, to_quadratic
from sim.mesh.types import TetMesh
from sim.model import Model

_A = (5.0 + 3.0 * np.sqrt(5.0)) / 20.0
_B = (5.0 - np.sqrt(5.0)) / 20.0
GAUSS_POINTS = np.full((4, 4), _B) + np.eye(4) * (_A - _B)  # (q, 4) barycentric coordinates, weights V/4 each

LOAD_WEIGHTS = np.array([-1.0 / 20.0] * 4 + [1.0 / 5.0] * 6)  # int N_a dV / V
HRZ_MASS = np.array([1.0 / 36.0] * 4 + [4.0 / 27.0] * 6)  # lumped mass / (rho V)


def shape_gradients_barycentric(L: np.ndarray) -> np.ndarray:
    """``dN_a / dL_k`` (10, 4) at the barycentric point ``L`` (4,)."""
    d = np.zeros((10, 4))
    for a in range(4):
        d[a, a] = 4.0 * L[a] - 1.0
    for e, (a, b) in enumerate(TET_EDGES):
        d[4 + e, a] = 4.0 * L[b]
        d[4 + e, b] = 4.0 * L[a]
    return d


def shape_gradients(Dm_inv: np.ndarray) -> np.ndarray:
    """``grad N_a`` at every Gauss point of every tet, (m, q, 10, 3) [1/m]."""
    grad_L = np.concatenate([-Dm_inv.sum(axis=1, keepdims=True), Dm_inv], axis=1)  # (m, 4, 3): rows grad L_k
    dN_dL = np.stack([shape_gradients_barycentric(L) for L in GAUSS_POINTS])  # (q, 10, 4)
    return np.einsum("qak,mkj->mqaj", dN_dL, grad_L)


@dataclass
class QuadraticModel(Model):
    """A :class:`Model` on 10-node tets: ``X`` holds every node (corners first), ``tets`` the corner tets (their
    ``Dm_inv`` and ``volume`` are the element's, straight edges), ``tets10 (m, 10)`` the element nodes, ``mass`` the
    HRZ-lumped masses and ``load_volume`` each node's ``int N_a dV`` for the consistent gravity load."""

    tets10: np.ndarray | None = None
    load_volume: np.ndarray | None = None

    def nodal_external_force(self) -> np.ndarray:
        f = self.density * self.load_volume[:, None] * np.asarray(self.gravity, dtype=np.float64)[None, :]
        if self.external_force is not None:
            f = f + self.external_force
        return f


def quadratic_model(mesh: TetMesh | QuadraticTetMesh, **material) -> QuadraticModel:
    """The 10-node model of a linear mesh (or of its :func:`sim.mesh.refine.to_quadratic` form); ``material`` as for
    :meth:`Model.from_mesh` (``E``, ``nu``, ``density``, ``constitutive``, ``fibre``, ``gravity``, ...). Boundary
    conditions are set on the returned model's nodes, all of them (corners and edge nodes)."""
    quad = mesh if isinstance(mesh, QuadraticTetMesh) else to_quadratic(mesh)
    linear = Model.from_mesh(quad.linear, **material)
    fields = {k: getattr(linear, k) for k in linear.__dataclass_fields__}
    n = quad.points.shape[0]
    weights = np.zeros(n)
    np.add.at(weights, quad.tets.ravel(), (linear.volume[:, None] * LOAD_WEIGHTS[None, :]).ravel())
    mass = np.zeros(n)
    np.add.at(mass, quad.tets.ravel(), (linear.density * linear.volume[:, None] * HRZ_MASS[None, :]).ravel())
    fields.update(X=quad.points.copy(), mass=mass, fixed=np.zeros(n, dtype=bool))
    if linear.external_force is not None:
        raise ValueError("quadratic_model: give external nodal forces on the quadratic model's nodes, after building it")
    return QuadraticModel(**fields, tets10=np.ascontiguousarray(quad.tets, dtype=np.int64), load_volume=weights)


class QuadraticReferenceIntegrator(ReferenceIntegrator):
    """:class:`ReferenceIntegrator` on a :class:`QuadraticModel` (module docstring): only the elastic energy, its
    gradient and the element Hessians (30 x 30) differ."""

    name = "reference"

    def __init__(self, model: QuadraticModel, settings: ReferenceSettings | dict | None = None):
        settings = ReferenceSettings.of(settings)
        if settings.anp:
            raise ValueError("reference on quadratic tets: average nodal pressure is a linear-tet treatment of locking; "
                             "quadratic tets take no anp")
        if model.material_params.get("prony"):
            raise ValueError("reference on quadratic tets: Prony viscoelasticity is supported on linear tets only")
        super().__init__(model, settings)
        tets10 = model.tets10
        idx = np.repeat(tets10, 3, axis=1) * 3 + np.tile(np.arange(3), 10)[None, :]  # (m, 30) dof ids
        self.rows = np.repeat(idx, 30, axis=1).ravel()
        self.cols = np.tile(idx, (1, 30)).ravel()
        self.grad_N = shape_gradients(model.Dm_inv)  # (m, q, 10, 3)
        self.weight = model.volume / 4.0  # per Gauss point
        name, mu, lam, eta, a0 = models.model_params(model)
        q = GAUSS_POINTS.shape[0]
        # the material per Gauss point: each tet's parameters repeated q times
        self.params = (name, np.repeat(mu, q), np.repeat(lam, q), None if eta is None else np.repeat(eta, q, axis=0),
                       None if a0 is None else np.repeat(a0, q, axis=0))
        self.curves = models.model_curves(model)

    def _newton_step(self, K, g):
        # minimum degree on K + K^T: 3x faster than SuperLU's default COLAMD on the 30-dof elements' pattern
        # (measured on the 1,152-tet quadratic beam, 5,832 dofs: 1.8 s against 5.6 s on a loaded machine)
        return -spsolve(K.tocsc(), g, permc_spec="MMD_AT_PLUS_A")

    def deformation_gradients(self, x: np.ndarray) -> np.ndarray:
        """``F`` at every Gauss point, (m q, 3, 3)."""
        F = np.einsum("mai,mqaj->mqij", x[self.model.tets10], self.grad_N)
        return F.reshape(-1, 3, 3)

    def _elastic_energy(self, x, h):
        name, mu, lam, eta, a0 = self.params
        psi = models.energy_density(name, self.deformation_gradients(x), mu, lam, eta, a0, vl=self.curves)
        return float(np.sum(np.repeat(self.weight, GAUSS_POINTS.shape[0]) * psi))

    def _elastic_gradient(self, x, h):
        name, mu, lam, eta, a0 = self.params
        m = self.model.n_tets
        P = models.first_piola(name, self.deformation_gradients(x), mu, lam, eta, a0, vl=self.curves)
        ge = np.einsum("m,mqij,mqaj->mai", self.weight, P.reshape(m, -1, 3, 3), self.grad_N)  # (m, 10, 3)
        g = np.zeros_like(x)
        np.add.at(g, self.model.tets10, ge)
        return g

    def _element_hessians(self, x, h, project):
        name, mu, lam, eta, a0 = self.params
        m = self.model.n_tets
        T = models.tangent(name, self.deformation_gradients(x), mu, lam, eta, a0, vl=self.curves)
        if project:
            # PSD per Gauss point (the 9 x 9 tangent), which makes every element Hessian, a positive sum of
            # B^T T B, PSD too; clamping the 30 x 30 element Hessians instead costs one LAPACK eigen-solve per
            # element, which threaded BLAS makes far slower than the 9 x 9 projections (docs/report.md,
            # "Discretisation error")
            T = tensor.project_psd(T)
        T = T.reshape(m, -1, 3, 3, 3, 3)  # (m, q, i, j, k, l): dP_ij / dF_kl
        # two plain einsums (no BLAS: see above): sum_j grad N_a,j T_ijkl, then sum_q,l w ... grad N_b,l
        GT = np.einsum("mqaj,mqijkl->mqaikl", self.grad_N, T)
        H = np.einsum("m,mqaikl,mqbl->maibk", self.weight, GT, self.grad_N)
        return H.reshape(m, 30, 30)


def reference_for(model: Model, settings: ReferenceSettings | dict | None = None) -> ReferenceIntegrator:
    """The reference integrator for ``model``: on quadratic tets for a :class:`QuadraticModel`, else on linear ones."""
    return (QuadraticReferenceIntegrator if isinstance(model, QuadraticModel) else ReferenceIntegrator)(model, settings)
