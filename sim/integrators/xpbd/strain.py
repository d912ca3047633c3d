"""Strain limiting on the entries of the Green strain in a material frame (Qian §4.3.4, eqs. 4.21–4.22),
projected inside the XPBD iteration loop.

Per tet, with ``F = Ds Dm^-1`` and a material frame ``R = (r_1, r_2, r_3)`` (orthonormal columns:
the rest axes x, y, z, or for fibred materials the fibre and two axes orthogonal to it), the strain
in that frame is ``E' = R^T E R = ((F R)^T (F R) - I) / 2``. With ``u_i = F r_i = sum_k e_k a_i[k]``
(edges ``e_k = x_k - x_0``, ``a_i = Dm^-1 r_i``) each entry is

    E'_ij = (u_i . u_j - delta_ij) / 2,      dE'_ij/dx_k = (a_i[k] u_j + a_j[k] u_i) / 2   (k = 1..3)

and ``dE'_ij/dx_0 = -(sum of the other three)``. This is Qian's eq. 4.22 with the corrections of
docs/design.md, "Qian 4.22: strain-constraint gradient": the thesis's ``c_i`` are the columns ``m_i`` of ``Dm^-1`` (here ``a_i = Dm^-1 r_i``, which
is ``m_i`` in the rest frame), the factor 1/2 is missing there, and the fourth vertex's gradient is
omitted.

Each limited entry is the constraint ``C = E'_ij - s_ij`` of eq. 4.21 with a box ``lo <= E'_ij <= hi``:
a stretch bound on a diagonal entry (unilateral), ``|E'_ij| <= shear_max`` off the diagonal
(unilateral on both sides), or ``lo = hi = s_ij`` held (bilateral). With the compliance
``alpha = limit_compliance / V`` (0: hard) each entry has one multiplier per substep, and a
projection solves the compliant box exactly along the constraint gradient (projected Gauss–Seidel):

    lambda_hi = lambda + (hi - E - alpha~ lambda) / (w.|grad|^2 + alpha~)   taken if < 0 (upper bound pushes)
    lambda_lo = lambda + (lo - E - alpha~ lambda) / (w.|grad|^2 + alpha~)   else, taken if > 0 (lower bound pushes)
    lambda'   = 0 otherwise (inactive: any earlier push within this substep is withdrawn)

and moves node k by ``w_k grad_k C (lambda' - lambda)``. With ``alpha = 0`` and ``lambda = 0`` this is
the plain projection onto the violated bound; ``lo = hi`` gives the bilateral XPBD update.

Settings (``sim.integrators.xpbd`` / the scene's ``[simulation.xpbd]``): ``limit_frame`` ("rest" | "fibre"),
``limit_axes`` (the frame axes 1..3 whose stretch is bounded; default all three),
``green_stretch_min`` (in (-1/2, 0]) / ``green_stretch_max`` (>= 0): bounds on ``E'_ii``;
``shear_max`` (>= 0): bound on ``|E'_ij|``, i != j (all three pairs); ``strain_hold``: entries held
at a value, ``{"11": 0.0, "23": 0.05}``; ``limit_compliance`` [1/Pa] (>= 0, default 0: hard).
A stretch ratio ``s`` along an axis is ``E'_ii = (s^2 - 1) / 2``.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from sim.integrators.xpbd.kernels import PARALLEL_MIN_TETS
from sim.integrators.xpbd.settings import FRAMES, XPBDSettings, limit_boxes

CONDITION = 1e-10  # entries whose free-node gradient is below this share of the whole are not projected


def material_frames(model, frame: str) -> np.ndarray:
    """``R (m, 3, 3)`` per tet, orthonormal columns ``r_1, r_2, r_3``: the rest axes (identity) or
    ``(fibre, t_1, t_2)`` with ``t_1`` normal to the fibre and to the rest axis least aligned with it and
    ``t_2 = fibre x t_1`` (right-handed)."""
    if frame not in FRAMES:
        raise ValueError(f"xpbd limit_frame must be 'rest' or 'fibre', found {frame!r}")
    m = model.n_tets
    if frame == "rest":
        return np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
    if model.fibre is None:
        raise ValueError("xpbd limit_frame = 'fibre' needs a fibred material (the model has no fibre direction)")
    f = model.fibre / np.linalg.norm(model.fibre, axis=1, keepdims=True)
    least = np.eye(3)[np.argmin(np.abs(f), axis=1)]
    t1 = np.cross(f, least)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(f, t1)
    return np.stack([f, t1, t2], axis=2)


def green_strain_in_frame(x, tets, Dm_inv, R) -> np.ndarray:
    """``E' = R^T (F^T F - I) R / 2`` per tet (m, 3, 3), NumPy (for checks and reports)."""
    p = x[tets]
    Ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    U = Ds @ Dm_inv @ R  # columns u_i = F r_i
    return 0.5 * (np.swapaxes(U, 1, 2) @ U - np.eye(3))


@njit(cache=True, inline="always")
def _frame_columns(e1x, e1y, e1z, e2x, e2y, e2z, e3x, e3y, e3z, A, t, i, j):
    """``u_i = F r_i`` and ``u_j`` from the edges ``e_k = x_k - x_0`` (``A[t]`` holds ``a_i = Dm^-1 r_i``)."""
    a1i, a2i, a3i = A[t, 0, i], A[t, 1, i], A[t, 2, i]
    a1j, a2j, a3j = A[t, 0, j], A[t, 1, j], A[t, 2, j]
    return (e1x * a1i + e2x * a2i + e3x * a3i, e1y * a1i + e2y * a2i + e3y * a3i, e1z * a1i + e2z * a2i + e3z * a3i,
            e1x * a1j + e2x * a2j + e3x * a3j, e1y * a1j + e2y * a2j + e3y * a3j, e1z * a1j + e2z * a2j + e3z * a3j)


@njit(cache=True, inline="always")
def _entry_gradient(A, t, i, j, uix, uiy, uiz, ujx, ujy, ujz):
    """``dE'_ij/dx_k = (a_i[k] u_j + a_j[k] u_i) / 2`` for k = 1..3 (Qian 4.22 corrected), a 9-tuple."""
    a1i, a2i, a3i = A[t, 0, i], A[t, 1, i], A[t, 2, i]
    a1j, a2j, a3j = A[t, 0, j], A[t, 1, j], A[t, 2, j]
    return (0.5 * (a1i * ujx + a1j * uix), 0.5 * (a1i * ujy + a1j * uiy), 0.5 * (a1i * ujz + a1j * uiz),
            0.5 * (a2i * ujx + a2j * uix), 0.5 * (a2i * ujy + a2j * uiy), 0.5 * (a2i * ujz + a2j * uiz),
            0.5 * (a3i * ujx + a3j * uix), 0.5 * (a3i * ujy + a3j * uiy), 0.5 * (a3i * ujz + a3j * uiz))


@njit(cache=True)
def entry_and_gradient(x, tets, A, t, i, j):
    """``(E'_ij, grad (4, 3))`` of tet ``t``, from the kernel's own expressions (for tests)."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    u = _frame_columns(x[i1, 0] - x[i0, 0], x[i1, 1] - x[i0, 1], x[i1, 2] - x[i0, 2],
                       x[i2, 0] - x[i0, 0], x[i2, 1] - x[i0, 1], x[i2, 2] - x[i0, 2],
                       x[i3, 0] - x[i0, 0], x[i3, 1] - x[i0, 1], x[i3, 2] - x[i0, 2], A, t, i, j)
    E = 0.5 * (u[0] * u[3] + u[1] * u[4] + u[2] * u[5]) - (0.5 if i == j else 0.0)
    r = _entry_gradient(A, t, i, j, u[0], u[1], u[2], u[3], u[4], u[5])
    g = np.empty((4, 3))
    for c in range(3):
        g[1, c] = r[c]
        g[2, c] = r[3 + c]
        g[3, c] = r[6 + c]
        g[0, c] = -(g[1, c] + g[2, c] + g[3, c])
    return E, g


@njit(cache=True, inline="always")
def _project_tet_entries(t, x, tets, A, w, entry_i, entry_j, lo, hi, alpha, lam, inv_dt2):
    """Project every limited entry of tet ``t`` in turn. The node positions are held in locals between
    entries and written back once; an entry within its box with no multiplier is skipped before its
    gradient is formed (its projection would be zero)."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    x0x, x0y, x0z = x[i0, 0], x[i0, 1], x[i0, 2]
    x1x, x1y, x1z = x[i1, 0], x[i1, 1], x[i1, 2]
    x2x, x2y, x2z = x[i2, 0], x[i2, 1], x[i2, 2]
    x3x, x3y, x3z = x[i3, 0], x[i3, 1], x[i3, 2]
    w0, w1, w2, w3 = w[i0], w[i1], w[i2], w[i3]
    w_max = max(max(w0, w1), max(w2, w3))
    alpha_tilde = alpha[t] * inv_dt2
    moved = False
    for k in range(entry_i.shape[0]):
        i = entry_i[k]
        j = entry_j[k]
        uix, uiy, uiz, ujx, ujy, ujz = _frame_columns(x1x - x0x, x1y - x0y, x1z - x0z, x2x - x0x, x2y - x0y, x2z - x0z,
                                                      x3x - x0x, x3y - x0y, x3z - x0z, A, t, i, j)
        E = 0.5 * (uix * ujx + uiy * ujy + uiz * ujz)
        if i == j:
            E -= 0.5
        old = lam[t, k]
        if old == 0.0 and lo[k] <= E <= hi[k]:
            continue
        g1x, g1y, g1z, g2x, g2y, g2z, g3x, g3y, g3z = _entry_gradient(A, t, i, j, uix, uiy, uiz, ujx, ujy, ujz)
        g0x, g0y, g0z = -(g1x + g2x + g3x), -(g1y + g2y + g3y), -(g1z + g2z + g3z)
        n0 = g0x * g0x + g0y * g0y + g0z * g0z
        n1 = g1x * g1x + g1y * g1y + g1z * g1z
        n2 = g2x * g2x + g2y * g2y + g2z * g2z
        n3 = g3x * g3x + g3y * g3y + g3z * g3z
        movable = w0 * n0 + w1 * n1 + w2 * n2 + w3 * n3
        # An entry the free nodes cannot change (to rounding: e.g. a stretch along a fixed face, whose
        # free node has a gradient of 1e-17) is left alone; projecting its rounding-level C along that
        # gradient would move the node by C / |g|, arbitrarily far.
        if movable <= CONDITION * w_max * (n0 + n1 + n2 + n3):
            continue
        denom = movable + alpha_tilde
        new = old + (hi[k] - E - alpha_tilde * old) / denom
        if not new < 0.0:  # the upper bound does not push: the lower bound may
            new = old + (lo[k] - E - alpha_tilde * old) / denom
            if not new > 0.0:
                new = 0.0
        s = new - old
        if s == 0.0:
            continue
        lam[t, k] = new
        moved = True
        x0x += w0 * g0x * s
        x0y += w0 * g0y * s
        x0z += w0 * g0z * s
        x1x += w1 * g1x * s
        x1y += w1 * g1y * s
        x1z += w1 * g1z * s
        x2x += w2 * g2x * s
        x2y += w2 * g2y * s
        x2z += w2 * g2z * s
        x3x += w3 * g3x * s
        x3y += w3 * g3y * s
        x3z += w3 * g3z * s
    if moved:
        x[i0, 0], x[i0, 1], x[i0, 2] = x0x, x0y, x0z
        x[i1, 0], x[i1, 1], x[i1, 2] = x1x, x1y, x1z
        x[i2, 0], x[i2, 1], x[i2, 2] = x2x, x2y, x2z
        x[i3, 0], x[i3, 1], x[i3, 2] = x3x, x3y, x3z


@njit(cache=True, parallel=True)
def green_strain_limit(x, tets, A, w, entry_i, entry_j, lo, hi, alpha, lam, inv_dt2, colour_start):
    """One coloured Gauss–Seidel sweep of the Green-strain limits; per-tet data (``tets``, ``A``,
    ``alpha``, ``lam (m, n_entries)``) in colour order, colour c the range ``colour_start[c:c+2]``."""
    for c in range(colour_start.shape[0] - 1):
        lo_t = colour_start[c]
        hi_t = colour_start[c + 1]
        if hi_t - lo_t < PARALLEL_MIN_TETS:
            for t in range(lo_t, hi_t):
                _project_tet_entries(t, x, tets, A, w, entry_i, entry_j, lo, hi, alpha, lam, inv_dt2)
        else:
            for t in prange(lo_t, hi_t):
                _project_tet_entries(t, x, tets, A, w, entry_i, entry_j, lo, hi, alpha, lam, inv_dt2)


class GreenStrainLimits:
    """The Green-strain limits of one body: per-tet frames, boxes, compliances and multipliers, stored
    in the integrator's colour order (``order``)."""

    def __init__(self, model, order: np.ndarray, colour_start: np.ndarray, settings: XPBDSettings):
        boxes = limit_boxes(settings)
        if boxes is None:
            raise ValueError("no Green-strain limit in the settings")
        self.entry_i, self.entry_j, self.lo, self.hi = boxes
        self.frame = settings.limit_frame
        self.R = material_frames(model, self.frame)[order]
        self.tets = np.ascontiguousarray(model.tets[order], dtype=np.int64)
        self.Dm_inv = np.ascontiguousarray(model.Dm_inv[order])
        self.A = np.ascontiguousarray(self.Dm_inv @ self.R)
        compliance = settings.limit_compliance
        self.alpha = compliance / model.volume[order]
        self.colour_start = colour_start
        self.lam = np.zeros((model.n_tets, self.entry_i.size))

    def reset(self) -> None:
        self.lam[:] = 0.0

    def project(self, x: np.ndarray, w: np.ndarray, inv_dt2: float) -> None:
        green_strain_limit(x, self.tets, self.A, w, self.entry_i, self.entry_j, self.lo, self.hi, self.alpha,
                           self.lam, inv_dt2, self.colour_start)

    def strain(self, x: np.ndarray) -> np.ndarray:
        """``E'`` per tet (m, 3, 3) in colour order."""
        return green_strain_in_frame(x, self.tets, self.Dm_inv, self.R)
