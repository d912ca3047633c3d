"""CNN energy propagation (Zhang §4.1–4.2.1): the contact load as a Poisson energy source, propagated
over median-dual control volumes by an autonomous CNN, and nodal forces from the potential.

Equations (Zhang ch. 4, with the readings documented in docs/integrators-zhang.md):

- **Source (4.4)**: ``Q_c = (integral sigma d eps) F_c / |F_c|`` at each contact node c (a node carrying a
  constant external force ``model.external_force``), zero elsewhere. For linear elasticity the strain
  energy density is ``sigma^2 / (2 E)`` [J/m^3] with ``sigma = |F_c| / A_c`` and the contact patch
  ``A_c = Omega_c^(2/3)`` [m^2].
- **Median-dual control volumes (4.7, Fig. 4.1)**: ``Omega_i = sum_T V_T / 4``; the dual face between
  nodes i and j inside tet T is the two triangles (M_ij, F_ijk, C) and (M_ij, C, F_ijl) with area
  vector ``S_ij^T`` oriented from i to j (4.8).
- **Flux (4.7–4.9)**: ``(1 / Omega_i) sum_j (rho grad phi)|_M_ij . S_ij``. The gradient at the edge
  midpoint is the linear interpolation of phi over the tet (4.8); this keeps the CNN template radius 1
  (4.16). Zhang's nodal Green–Gauss average (4.9 with 4.11) would couple neighbours of neighbours, and his
  two-point form (4.21, ``(phi_j - phi_i) / l_ij sum S_n``) is consistent only where S_ij is parallel to
  the edge (not on Kuhn-split boxes); our flux reproduces ``laplacian(phi)`` exactly for quadratic phi on
  a uniform Kuhn grid (tests/sim/integrators/cnn/test_energy.py).
- **CNN templates (4.22–4.24)**: ``d phi_i / dt = A(i;i) phi_i + sum_j A(i;j) phi_j + I_i`` with
  ``A = Omega^-1 L`` (L the assembled flux matrix; 1/R_x cancels as in 4.24), ``I_i = -Q_i``; three layers,
  one per component of the vector potential (4.3). Fixed-state cells hold ``phi = 0`` on kinematic nodes
  (Dirichlet, 4.26); the initial state is zero (4.25). Time evolution: forward Euler (4.12), subdivided
  so each sub-step is below the explicit diffusion limit ``2 / lambda_max(A)``.
- **Forces (4.28–4.30, signed)**: ``f_i = g sum_j w_ij (psi_j - psi_i) / l_ij e_ij`` with ``e_ij`` the unit
  edge vector, ``psi = phi . d`` the potential along the load direction d, and ``w_ij`` the edge's share of
  volume (``sum_T V_T / 6`` over the tets holding the edge) so that f is in newtons. Zhang writes
  ``|phi_j - phi_i|``, which always pulls towards the neighbour and is undefined for a vector phi; we use
  the signed difference (docs/design.md, "Zhang 4.28-4.30: CNN potential forces"). With 4.2's sign convention the steady potential is lowest at the
  source, so these forces point away from it. The gain g is fixed once from the steady potential so
  that the propagated load's resultant along d equals the total contact force: energy propagation
  redistributes the load, it does not create it.

Settings (``force_model = "energy"`` in ``cnn``; ``sim.integrators.cnn.settings``): ``energy_rho``,
``energy_gradient`` and ``kernel`` (``"numpy"``: the reference below).

Speed (``kernel = "numba"``): the potential's ODE is linear with constant templates, so the n forward-Euler
sub-steps of one call are evaluated in closed form on the eigenmodes of the free cells' template
(``ModalPropagation``: ``A_ff = Omega^-1 L_ff`` is similar to the symmetric ``Omega^-1/2 L_ff Omega^-1/2``,
so ``(I + h A_ff)^n`` is diagonal in its eigenbasis): the same iterate as the sub-step loop (to rounding,
tested), at the cost of two dense products per call instead of n sparse ones. Models with more than
``MODAL_MAX_CELLS`` free cells run the sub-steps in the numba kernel (``sim.integrators.cnn.kernels``); forces use
the numba edge kernel.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from sim.integrators.cnn import kernels
from sim.integrators.cnn.settings import CNNSettings

# the six edges of a tet as (i, j, k, l): edge i-j, the two other vertices k and l
TET_EDGES = np.array([(0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 1, 2), (1, 2, 0, 3), (1, 3, 0, 2), (2, 3, 0, 1)])


def _oriented_area(a, b, c, towards):
    """Area vectors of triangles (a, b, c), (m, 3), flipped to point along ``towards``."""
    s = 0.5 * np.cross(b - a, c - a)
    sign = np.where(np.einsum("ij,ij->i", s, towards) < 0.0, -1.0, 1.0)
    return s * sign[:, None]


def median_dual(X: np.ndarray, tets: np.ndarray):
    """Median-dual geometry of a tet mesh (Zhang Fig. 4.1, 4.2).

    Returns ``omega`` (n,) control volumes [m^3] and, per tet and local edge (TET_EDGES), the dual face
    area vectors ``S`` (m, 6, 3) [m^2] oriented from the edge's first to its second node.
    """
    P = X[tets]  # (m, 4, 3)
    C = P.mean(axis=1)
    V = np.abs(np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), P[:, 3] - P[:, 0])) / 6.0
    omega = np.zeros(X.shape[0])
    np.add.at(omega, tets.ravel(), np.repeat(V / 4.0, 4))
    S = np.empty((tets.shape[0], 6, 3))
    for e, (i, j, k, l) in enumerate(TET_EDGES):
        M = 0.5 * (P[:, i] + P[:, j])
        Fk = (P[:, i] + P[:, j] + P[:, k]) / 3.0
        Fl = (P[:, i] + P[:, j] + P[:, l]) / 3.0
        d = P[:, j] - P[:, i]
        S[:, e] = _oriented_area(M, Fk, C, d) + _oriented_area(M, Fl, C, d)
    return omega, S, V


def shape_gradients(X: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Gradients of the four linear shape functions per tet, (m, 4, 3) [1/m]."""
    P = X[tets]
    D = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]], axis=2)  # columns
    Dinv = np.linalg.inv(D)  # rows are grad N1..N3
    G = np.empty((tets.shape[0], 4, 3))
    G[:, 1:] = Dinv
    G[:, 0] = -Dinv.sum(axis=1)
    return G


def flux_matrix(X: np.ndarray, tets: np.ndarray, rho: float | np.ndarray = 1.0):
    """Assembled median-dual flux matrix L (n, n) with ``(L phi)_i`` = net flux of ``rho grad phi`` out of
    Omega_i (Zhang 4.7–4.8), and the control volumes ``omega``. ``rho`` is per tet or a scalar [m^2/s]."""
    omega, S, V = median_dual(X, tets)
    G = shape_gradients(X, tets)
    rho = np.broadcast_to(np.asarray(rho, dtype=np.float64), (tets.shape[0],))
    m = tets.shape[0]
    # per tet: flux out of node a's part through the dual faces: sum over edges touching a of
    # +/- S_e . grad phi, with grad phi = sum_b phi_b G_b
    out = np.zeros((m, 4, 3))  # sum of outward dual face vectors per local node
    for e, (i, j, _, _) in enumerate(TET_EDGES):
        out[:, i] += S[:, e]
        out[:, j] -= S[:, e]
    local = rho[:, None, None] * np.einsum("mad,mbd->mab", out, G)  # (m, 4, 4)
    rows = np.repeat(tets, 4, axis=1).ravel()
    cols = np.tile(tets, (1, 4)).ravel()
    L = sp.coo_matrix((local.ravel(), (rows, cols)), shape=(X.shape[0],) * 2).tocsr()
    return L, omega


def edge_table(tets: np.ndarray, volume: np.ndarray, S: np.ndarray):
    """Unique edges (e, 2) with a < b, their volume shares ``sum_T V_T / 6`` [m^3] and their assembled
    median-dual face vectors ``S_ab`` (e, 3) [m^2], oriented from a to b."""
    local = tets[:, TET_EDGES[:, :2]]  # (m, 6, 2)
    pairs = np.sort(local.reshape(-1, 2), axis=1)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    w = np.zeros(edges.shape[0])
    np.add.at(w, inverse, np.repeat(volume / 6.0, 6))
    sign = np.where(local[:, :, 0] < local[:, :, 1], 1.0, -1.0).ravel()
    S_edge = np.zeros((edges.shape[0], 3))
    np.add.at(S_edge, inverse, sign[:, None] * S.reshape(-1, 3))
    return edges, w, S_edge


MODAL_MAX_CELLS = 3000  # dense eigenbasis up to this many free cells (72 MB); sub-steps above


class ModalPropagation:
    """Closed form of n forward-Euler sub-steps ``phi <- phi + h (A phi - Q)`` on the free cells.

    With ``Omega_f^1/2 A_ff Omega_f^-1/2 = U diag(s) U^T`` (symmetric: the median-dual flux matrix of linear
    tets is the P1 Laplacian, ``L_ab = -rho V grad N_a . grad N_b``), the modal coordinates
    ``z = U^T Omega_f^1/2 phi_f`` obey ``z <- tau z + h b`` with ``tau = 1 + h s`` and
    ``b = U^T Omega_f^1/2 (Omega_f^-1 L_fc phi_c - Q_f)`` (fixed cells hold phi_c), so after n sub-steps
    ``z_n = tau^n z_0 + h b (tau^n - 1) / (tau - 1)``; the geometric sum is evaluated with expm1/log1p so that
    slow modes (h s -> 0) keep their precision, and is n for s = 0 (a cell group without a Dirichlet cell).
    The modal coordinates of the last result are kept: when the next call starts from that potential (the
    CNN stepping on), the projection is skipped and one dense product remains per call.
    """

    def __init__(self, L: sp.csr_matrix, omega: np.ndarray, fixed: np.ndarray, Q: np.ndarray):
        self.free = np.flatnonzero(~fixed)
        self.fixed = np.flatnonzero(fixed)
        Lf = L[self.free]
        L_ff = Lf[:, self.free].toarray()
        self.L_fc = Lf[:, self.fixed].tocsr()
        self.sqrt_omega = np.sqrt(omega[self.free])
        r = 1.0 / self.sqrt_omega
        sym = r[:, None] * L_ff * r[None, :]
        self.s, self.U = np.linalg.eigh(0.5 * (sym + sym.T))
        self.s = np.minimum(self.s, 0.0)  # negative semi-definite up to rounding
        self.b0 = self.U.T @ (-self.sqrt_omega[:, None] * Q[self.free])
        self._last = (None, None)  # (phi_f, z) of the last result

    def propagate(self, phi: np.ndarray, h: float, n: int) -> np.ndarray:
        out = phi.copy()
        phi_c = phi[self.fixed]
        b = self.b0
        if np.any(phi_c != 0.0):
            b = b + self.U.T @ ((self.L_fc @ phi_c) / self.sqrt_omega[:, None])
        phi_f = phi[self.free]
        last_phi_f, last_z = self._last
        if last_phi_f is not None and np.array_equal(phi_f, last_phi_f):
            z = last_z
        else:
            z = self.U.T @ (self.sqrt_omega[:, None] * phi_f)
        hs = h * self.s
        with np.errstate(divide="ignore", invalid="ignore"):
            log_tau = np.log1p(np.maximum(hs, -1.0))
            smooth = hs > -0.5  # tau > 1/2: tau^n and (tau^n - 1) / (h s) from log1p/expm1
            tau_n = np.where(smooth, np.exp(n * log_tau), (1.0 + hs) ** n)
            geometric = np.where(hs == 0.0, float(n),
                                 np.where(smooth, np.expm1(n * log_tau), tau_n - 1.0) / np.where(hs == 0.0, 1.0, hs))
        z = tau_n[:, None] * z + (h * geometric)[:, None] * b
        out[self.free] = (self.U @ z) / self.sqrt_omega[:, None]
        self._last = (out[self.free], z)
        return out


class EnergyPropagation:
    """The energy-propagation force model of one Model (see module docstring)."""

    def __init__(self, model, settings: CNNSettings | dict | None = None):
        settings = CNNSettings.of(settings)
        self.model = model
        self.rho = settings.energy_rho
        self.gradient = settings.energy_gradient
        self.kernel = settings.kernel
        X = model.X
        self.L, self.omega = flux_matrix(X, model.tets, self.rho)
        self.fixed = model.kinematic_mask()
        if not self.fixed.any():
            raise ValueError("cnn: force_model = \"energy\" needs fixed or prescribed nodes: they are the Dirichlet "
                             "cells (phi = 0, Zhang 4.26) without which the Poisson potential has no steady state")
        self.A = sp.diags(1.0 / self.omega) @ self.L  # CNN feedback template, Zhang 4.24
        self.A = self.A.tocsr()
        self.free = ~self.fixed
        f = np.zeros_like(X) if model.external_force is None else np.asarray(model.external_force, dtype=np.float64)
        self.contact = np.flatnonzero(np.linalg.norm(f, axis=1) > 0.0)
        self.contact_force = f[self.contact].copy()
        total = self.contact_force.sum(axis=0)
        self.total_load = float(np.linalg.norm(total))
        self.direction = total / self.total_load if self.total_load > 0.0 else np.zeros(3)
        self.Q = self.source(f)
        self.edges, self.edge_w, self.edge_S = edge_table(model.tets, model.volume, median_dual(X, model.tets)[1])
        # explicit diffusion limit: Gershgorin bound on the spectral radius of A
        lam = float(np.abs(self.A).sum(axis=1).max())
        self.h_max = 1.8 / lam
        self._edges = np.ascontiguousarray(self.edges, dtype=np.int64)
        self._fixed = np.ascontiguousarray(self.fixed)
        self.modal = None
        if self.kernel == "numba":
            self.propagation = "modal" if int(self.free.sum()) <= MODAL_MAX_CELLS else "substeps"
            if self.propagation == "modal":
                self.modal = ModalPropagation(self.L, self.omega, self.fixed, self.Q)
            self._A_csr = (self.A.indptr.astype(np.int64), self.A.indices.astype(np.int64), self.A.data.copy())
        else:
            self.propagation = "numpy"
        self.gain = 1.0
        if self.total_load > 0.0:
            raw = self.forces(self.steady_potential(), X)
            along = float((raw[self.free] @ self.direction).sum())
            if not along > 0.0:
                raise ValueError("cnn: the energy-propagation load has no resultant along the contact force "
                                 "(is the contact node fixed?)")
            self.gain = self.total_load / along

    def source(self, f: np.ndarray) -> np.ndarray:
        """Zhang 4.4: ``Q = sigma^2 / (2 E) F / |F|`` at contact nodes, (n, 3) [J/m^3]."""
        Q = np.zeros_like(f)
        if self.contact.size == 0:
            return Q
        E_node = np.zeros(f.shape[0])
        np.add.at(E_node, self.model.tets.ravel(), np.repeat(self.model.E * self.model.volume / 4.0, 4))
        E_node /= self.omega
        c = self.contact
        mag = np.linalg.norm(f[c], axis=1)
        sigma = mag / self.omega[c] ** (2.0 / 3.0)
        Q[c] = (sigma**2 / (2.0 * E_node[c]))[:, None] * f[c] / mag[:, None]
        return Q

    def rate(self, phi: np.ndarray) -> np.ndarray:
        """Cell state derivative, Zhang 4.22 with 4.24: ``A phi + I``, I = -Q; zero on fixed-state cells."""
        d = self.A @ phi - self.Q
        d[self.fixed] = 0.0
        return d

    def evolve(self, phi: np.ndarray, dt: float) -> np.ndarray:
        """Advance the three-layer potential by dt with forward Euler (4.12) in stable sub-steps."""
        n = self.substeps(dt)
        h = dt / n
        if self.propagation == "modal":
            phi = self.modal.propagate(phi, h, n)
        elif self.propagation == "substeps":
            phi = np.array(phi, dtype=np.float64, order="C")
            kernels.euler_substeps(phi, np.empty_like(phi), *self._A_csr, self.Q, self._fixed, h, n)
        else:
            for _ in range(n):
                phi = phi + h * self.rate(phi)
        phi[self.fixed] = 0.0
        return phi

    def substeps(self, dt: float) -> int:
        """Forward-Euler sub-steps of the potential per ``evolve(phi, dt)`` (below the diffusion limit)."""
        return max(1, int(np.ceil(dt / self.h_max)))

    def steady_potential(self) -> np.ndarray:
        """The CNN's equilibrium (d phi/dt = 0): ``L phi = Omega Q`` on free cells, phi = 0 on fixed ones."""
        free = np.flatnonzero(self.free)
        phi = np.zeros_like(self.Q)
        Lff = self.L[free][:, free].tocsc()
        solve = spla.factorized(Lff)
        rhs = self.omega[free, None] * self.Q[free]
        for k in range(3):
            phi[free, k] = solve(np.ascontiguousarray(rhs[:, k]))
        return phi

    def residual(self, phi: np.ndarray) -> np.ndarray:
        """Discrete Poisson residual per control volume, ``(L phi)_i / Omega_i - Q_i`` [J/m^3] (4.7 at steady state)."""
        r = (self.L @ phi) / self.omega[:, None] - self.Q
        r[self.fixed] = 0.0
        return r

    def forces(self, phi: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Nodal forces from the potential [N], zero on fixed cells (Zhang 4.28–4.30, signed difference).

        ``energy_gradient = "edge"``: ``g sum_j w_ij (psi_j - psi_i) / l_ij e_ij`` (4.29 as written, signed);
        ``"median_dual"`` (default): ``g sum_j (psi_j - psi_i) / 2 S_ij``, the same signed edge differences
        weighted by the dual face vector instead of ``e_ij / l_ij`` (the Green–Gauss form of 4.11), exact for
        a linear psi on any tet mesh; the edge form is biased along the Kuhn diagonals of box meshes.
        """
        if self.kernel == "numba":
            f = np.empty((x.shape[0], 3))
            kernels.potential_forces(np.ascontiguousarray(phi, dtype=np.float64), self.direction,
                                           np.ascontiguousarray(x, dtype=np.float64), self._edges, self.edge_S,
                                           self.edge_w, self.gain, self.gradient == "edge", self._fixed, f)
            return f
        psi = phi @ self.direction
        i, j = self.edges[:, 0], self.edges[:, 1]
        if self.gradient == "edge":
            d = x[j] - x[i]
            fe = (self.gain * self.edge_w * (psi[j] - psi[i]) / np.einsum("ij,ij->i", d, d))[:, None] * d
        else:
            fe = (0.5 * self.gain * (psi[j] - psi[i]))[:, None] * self.edge_S
        f = np.zeros_like(x)
        np.add.at(f, i, fe)  # 4.30 for i with neighbour j ...
        np.add.at(f, j, fe)  # ... and for j with neighbour i: (psi_i - psi_j) e_ji is the same vector
        f[self.fixed] = 0.0
        return f
