"""Directional albedos of the GGX lobes the layered tissue stacks (:mod:`.mucosa`) needs to stay energy
preserving: tabulated once by deterministic quadrature, looked up by linear interpolation.

- ``E_s(alpha, mu) = F0 A(alpha, mu) + B(alpha, mu)``: the tissue's Cook–Torrance lobe (GGX D, height-
  correlated Smith G2, Schlick F) reflects this much of the light arriving at cosine ``mu``; Schlick's F is
  linear in F0, ``F = F0 (1 - (1 - v.h)^5) + (1 - v.h)^5``, so two tables over (alpha, mu) serve every F0
  (the split-sum tables of Karis 2013). ``A + B`` is the albedo of the F = 1 granular lobe.
- ``E_c(mu)``: the wet coat's lobe (GGX, G2, exact dielectric Fresnel of ``coat_ior``) per material.
- the normalisations of the diffuse lobes under the coat and the tissue lobe (:func:`coat_norms`):
  ``N(alpha) = 2 int_0^1 (1 - E_c(mu)) (1 - E(alpha, mu)) mu dmu``, by Gauss–Legendre on ``AVERAGE_NODES``
  cosines. It is not ``(1 - E_c_avg) (1 - E_avg)``: both albedos rise towards grazing, so the product of the
  averages read the integral ~0.8 % low (the furnace that much bright) for a smooth coat over a smooth
  tissue.

Quadrature: ``E(mu) = E_{m ~ D_wi}[F(wi.m) G2 / G1(wi)]`` over the distribution of visible normals (Heitz
2018), on an N x N stratified grid (``microfacet.visible_normals``); the estimand is bounded by 1 and
smooth, so 48 x 48 points give about 1e-4 (checked against a 192 x 192 grid in the tests).
"""
from __future__ import annotations

import functools

import numpy as np
from numba import njit

MU_SIZE = 64  # cosines 0 ... 1, evenly spaced (as bsdf.plastic's tables)
ALPHA_SIZE = 33  # alpha 0 ... 1, evenly spaced (alpha clamped to 1e-3 at the first entry)
QUADRATURE = 48  # N of the N x N visible-normal grid per table entry
AVERAGE_NODES = 24  # Gauss-Legendre cosines of the hemispherical averages


@njit(cache=True)
def _albedo(mu, alpha, n_grid, mode, eta):
    """E(mu) of a GGX lobe: ``mode`` 0 -> Schlick's (1 - (1 - v.h)^5) part (A), 1 -> the (1 - v.h)^5 part (B),
    2 -> exact dielectric Fresnel of relative index ``eta``."""
    mu = max(mu, 1e-4)
    wi = (np.sqrt(max(1.0 - mu * mu, 0.0)), 0.0, mu)
    vx, vy, vz = alpha * wi[0], alpha * wi[1], wi[2]
    norm = np.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / norm, vy / norm, vz / norm
    lensq = vx * vx + vy * vy
    if lensq > 0.0:
        inv = 1.0 / np.sqrt(lensq)
        t1x, t1y, t1z = -vy * inv, vx * inv, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    t2x, t2y, t2z = vy * t1z - vz * t1y, vz * t1x - vx * t1z, vx * t1y - vy * t1x
    a2 = alpha * alpha
    lam_i = 0.5 * (np.sqrt(1.0 + a2 * (1.0 - mu * mu) / (mu * mu)) - 1.0)
    total = 0.0
    for a in range(n_grid):
        u1 = (a + 0.5) / n_grid
        for b in range(n_grid):
            u2 = (b + 0.5) / n_grid
            r, phi = np.sqrt(u1), 2.0 * np.pi * u2
            p1, p2 = r * np.cos(phi), r * np.sin(phi)
            s = 0.5 * (1.0 + vz)
            p2 = (1.0 - s) * np.sqrt(max(1.0 - p1 * p1, 0.0)) + s * p2
            p3 = np.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
            nx = p1 * t1x + p2 * t2x + p3 * vx
            ny = p1 * t1y + p2 * t2y + p3 * vy
            nz = p1 * t1z + p2 * t2z + p3 * vz
            mx, my, mz = alpha * nx, alpha * ny, max(nz, 0.0)
            mn = np.sqrt(mx * mx + my * my + mz * mz)
            mx, my, mz = mx / mn, my / mn, mz / mn
            c = wi[0] * mx + wi[1] * my + wi[2] * mz
            ox, oy, oz = 2.0 * c * mx - wi[0], 2.0 * c * my - wi[1], 2.0 * c * mz - wi[2]
            if oz <= 0.0 or c <= 0.0:
                continue
            lam_o = 0.5 * (np.sqrt(1.0 + a2 * (1.0 - oz * oz) / (oz * oz)) - 1.0)
            g2_over_g1 = (1.0 + lam_i) / (1.0 + lam_i + lam_o)
            if mode == 0:
                F = 1.0 - (1.0 - c) ** 5
            elif mode == 1:
                F = (1.0 - c) ** 5
            else:
                g = np.sqrt(max(eta * eta - 1.0 + c * c, 0.0))
                x = (g - c) / max(g + c, 1e-12)
                y = (c * (g + c) - 1.0) / max(c * (g - c) + 1.0, 1e-12)
                F = 0.5 * x * x * (1.0 + y * y)
            total += F * g2_over_g1
    return total / (n_grid * n_grid)


def table_cosines() -> np.ndarray:
    return np.arange(MU_SIZE) / (MU_SIZE - 1.0)


def table_alphas() -> np.ndarray:
    return np.maximum(np.arange(ALPHA_SIZE) / (ALPHA_SIZE - 1.0), 1e-3)


def average_nodes():
    """Gauss–Legendre cosines and weights on [0, 1] for ``2 int_0^1 E(mu) mu dmu``."""
    x, w = np.polynomial.legendre.leggauss(AVERAGE_NODES)
    mu = 0.5 * (x + 1.0)
    return mu, w * mu  # 2 * (w / 2) * mu


@functools.lru_cache(maxsize=1)
def schlick_tables(n_grid: int = QUADRATURE):
    """``(E, at_nodes)``: E (2, ALPHA_SIZE, MU_SIZE) the A and B tables of Schlick's split, and the same at the
    Gauss–Legendre cosines (2, ALPHA_SIZE, AVERAGE_NODES)."""
    E = np.empty((2, ALPHA_SIZE, MU_SIZE))
    at_nodes = np.zeros((2, ALPHA_SIZE, AVERAGE_NODES))
    nodes, _ = average_nodes()
    for k, alpha in enumerate(table_alphas()):
        for mode in (0, 1):
            for j, mu in enumerate(table_cosines()):
                E[mode, k, j] = _albedo(mu, alpha, n_grid, mode, 1.0)
            for j, mu in enumerate(nodes):
                at_nodes[mode, k, j] = _albedo(mu, alpha, n_grid, mode, 1.0)
    E.setflags(write=False)
    at_nodes.setflags(write=False)
    return E, at_nodes


@functools.lru_cache(maxsize=64)
def coat_table(alpha: float, ior: float, n_grid: int = QUADRATURE):
    """``(E_c, E_c at the Gauss–Legendre cosines)``: the coat lobe's albedo on the table's cosines (MU_SIZE,)."""
    a = max(float(alpha), 1e-3)
    E = np.array([_albedo(mu, a, n_grid, 2, float(ior)) for mu in table_cosines()])
    E.setflags(write=False)
    nodes, _ = average_nodes()
    return E, np.array([_albedo(mu, a, n_grid, 2, float(ior)) for mu in nodes])


@functools.lru_cache(maxsize=64)
def coat_norms(alpha: float, ior: float):
    """(3, ALPHA_SIZE): ``P = 2 int (1 - E_c)(1 - B) mu dmu``, ``Q = 2 int (1 - E_c) A mu dmu`` and
    ``R = 2 int (1 - E_c)(1 - A - B) mu dmu`` per table alpha, so that under this coat the tissue's diffuse
    lobe (F0) is normalised by ``P - F0 Q`` and the granular multiple-scattering lobe (F = 1) by ``R``."""
    _, c_nodes = coat_table(alpha, ior)
    _, s_nodes = schlick_tables()
    _, weights = average_nodes()
    c = (1.0 - c_nodes) * weights
    out = np.stack([(1.0 - s_nodes[1]) @ c, s_nodes[0] @ c, (1.0 - s_nodes[0] - s_nodes[1]) @ c])
    out.setflags(write=False)
    return out


def lookup_mu(table: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Linear interpolation of a (..., MU_SIZE) table at cosines ``mu`` (the numba kernel's ``_table``)."""
    x = np.clip(mu, 0.0, 1.0) * (MU_SIZE - 1)
    k = np.minimum(x.astype(np.int64), MU_SIZE - 2)
    f = x - k
    return table[..., k] * (1.0 - f) + table[..., k + 1] * f


def lookup_alpha_mu(E: np.ndarray, alpha: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a (ALPHA_SIZE, MU_SIZE) table at per-point ``alpha`` and ``mu``."""
    xa = np.clip(alpha, 0.0, 1.0) * (ALPHA_SIZE - 1)
    ka = np.minimum(xa.astype(np.int64), ALPHA_SIZE - 2)
    fa = xa - ka
    xm = np.clip(mu, 0.0, 1.0) * (MU_SIZE - 1)
    km = np.minimum(xm.astype(np.int64), MU_SIZE - 2)
    fm = xm - km
    lo = E[ka, km] * (1.0 - fm) + E[ka, km + 1] * fm
    hi = E[ka + 1, km] * (1.0 - fm) + E[ka + 1, km + 1] * fm
    return lo * (1.0 - fa) + hi * fa


def lookup_alpha(avg: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Linear interpolation of an (ALPHA_SIZE,) table at per-point ``alpha``."""
    xa = np.clip(alpha, 0.0, 1.0) * (ALPHA_SIZE - 1)
    ka = np.minimum(xa.astype(np.int64), ALPHA_SIZE - 2)
    fa = xa - ka
    return avg[ka] * (1.0 - fa) + avg[ka + 1] * fa
