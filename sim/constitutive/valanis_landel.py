"""Valanis–Landel materials defined by editable curves (Qian §4.3.2–4.3.3, eqs. 4.15–4.20).

    Psi(l1, l2, l3) = sum_i f(l_i) + g(l1 l2) + g(l2 l3) + g(l3 l1) + h(l1 l2 l3)        (4.15)

with the principal stretches l_i of ``F = U diag(l) V^T`` (a rotation-preserving SVD: when det F < 0
the smallest stretch is negative, so inverted elements are handled) and
``P = U diag(dPsi/dl_i) V^T`` (4.16–4.17).

The user edits the *derivative* curves f', g', h' (stress-like, as measured in a tension test) by
control points ``[[x, y], ...]``; they are interpolated by a cubic B-spline (scipy
``make_interp_spline``; lower degree with fewer points) that also extrapolates. f, g, h are their
antiderivatives shifted so that f(1) = g(1) = h(1) = 0: the rest-energy correction of 4.18, which
keeps Psi(I) = 0 after any edit. The rest state must also stay stress free,
``f'(1) + 2 g'(1) + h'(1) = 0``; curves that break it are rejected with the value found.

Neo-Hookean in this form (4.19–4.20): ``f'(x) = mu x``, ``g' = 0``, ``h'(x) = (-mu + lam log x) / x``
(:func:`neo_hookean_curves` samples it).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _spline(points):
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2:
        raise ValueError(f"a curve needs at least 2 control points [x, y], found {np.asarray(points).tolist()}")
    if np.any(np.diff(pts[:, 0]) <= 0) or np.any(pts[:, 0] <= 0):
        raise ValueError(f"curve x values (stretches) must be positive and strictly increasing, found {pts[:, 0].tolist()}")
    k = min(3, pts.shape[0] - 1)
    from scipy.interpolate import make_interp_spline  # here: scipy.interpolate costs ~1 s of start-up

    return make_interp_spline(pts[:, 0], pts[:, 1], k=k)


@dataclass
class Curve:
    """A derivative curve c'(x) and its rest-corrected antiderivative c(x) = int_1^x c'."""

    points: list | None

    def __post_init__(self):
        if self.points is None:
            self.d = self.v = None
            return
        self.d = _spline(self.points)
        anti = self.d.antiderivative()
        offset = float(anti(1.0))
        self.v = lambda x: anti(x) - offset

    def value(self, x):
        return np.zeros_like(x) if self.v is None else self.v(x)

    def slope(self, x):
        return np.zeros_like(x) if self.d is None else self.d(x)


class ValanisLandel:
    def __init__(self, f_prime=None, g_prime=None, h_prime=None):
        self.f, self.g, self.h = Curve(f_prime), Curve(g_prime), Curve(h_prime)
        rest = float(self.f.slope(np.array(1.0)) + 2.0 * self.g.slope(np.array(1.0)) + self.h.slope(np.array(1.0)))
        scale = max(abs(float(c.slope(np.array(1.0)))) for c in (self.f, self.g, self.h)) + 1e-300
        if abs(rest) > 1e-6 * scale and abs(rest) > 1e-12:
            raise ValueError(f"the rest state must be stress free: f'(1) + 2 g'(1) + h'(1) = 0 expected, "
                             f"found {rest:.6g}")

    @classmethod
    def from_params(cls, params: dict) -> "ValanisLandel":
        curves = params.get("valanis_landel")
        if not curves:
            raise ValueError("a valanis_landel material needs material_params['valanis_landel'] with "
                             "f_prime/g_prime/h_prime control points")
        unknown = set(curves) - {"f_prime", "g_prime", "h_prime"}
        if unknown:
            raise ValueError(f"unknown Valanis-Landel curves {sorted(unknown)}; expected f_prime, g_prime, h_prime")
        return cls(curves.get("f_prime"), curves.get("g_prime"), curves.get("h_prime"))

    @staticmethod
    def stretches(F):
        """U, l, V with F = U diag(l) V^T, U and V rotations (l3 < 0 for inverted F)."""
        U, s, Vt = np.linalg.svd(F)
        V = np.swapaxes(Vt, 1, 2)
        flip_u = np.linalg.det(U) < 0
        flip_v = np.linalg.det(V) < 0
        U[flip_u, :, 2] *= -1.0
        s[flip_u, 2] *= -1.0
        V[flip_v, :, 2] *= -1.0
        s[flip_v, 2] *= -1.0
        return U, s, V

    def energy_of_stretches(self, l):
        l1, l2, l3 = l[:, 0], l[:, 1], l[:, 2]
        return (self.f.value(l1) + self.f.value(l2) + self.f.value(l3)
                + self.g.value(l1 * l2) + self.g.value(l2 * l3) + self.g.value(l3 * l1) + self.h.value(l1 * l2 * l3))

    def energy(self, F):
        return self.energy_of_stretches(self.stretches(F)[1])

    def piola(self, F):
        U, l, V = self.stretches(F)
        l1, l2, l3 = l[:, 0], l[:, 1], l[:, 2]
        J = l1 * l2 * l3
        hJ = self.h.slope(J)
        d = np.stack([
            self.f.slope(l1) + self.g.slope(l1 * l2) * l2 + self.g.slope(l3 * l1) * l3 + hJ * l2 * l3,
            self.f.slope(l2) + self.g.slope(l1 * l2) * l1 + self.g.slope(l2 * l3) * l3 + hJ * l1 * l3,
            self.f.slope(l3) + self.g.slope(l2 * l3) * l2 + self.g.slope(l3 * l1) * l1 + hJ * l1 * l2,
        ], axis=1)
        return np.einsum("mij,mj,mkj->mik", U, d, V)

    def tangent(self, F, h: float = 1e-6):
        """dP/dF (m, 9, 9) by central differences (the SVD is not complex-step differentiable)."""
        m = F.shape[0]
        out = np.empty((m, 9, 9))
        for col in range(9):
            step = np.zeros((3, 3))
            step.flat[col] = h
            out[:, :, col] = (self.piola(F + step) - self.piola(F - step)).reshape(m, 9) / (2 * h)
        return out


def neo_hookean_curves(mu: float, lam: float, stretches=None) -> dict:
    """Control points of Qian 4.19–4.20's Neo-Hookean curves, for editing from a known material."""
    x = np.linspace(0.3, 3.0, 28) if stretches is None else np.asarray(stretches, dtype=np.float64)
    return {"f_prime": np.column_stack([x, mu * x]).tolist(),
            "h_prime": np.column_stack([x, (-mu + lam * np.log(x)) / x]).tolist()}
