"""Heterogeneous stiffness painting with the poly6 kernel (Qian eqs. 4.26–4.28).

A brush stroke at centre c with support radius h adds a kernel weight to every node within h
(4.26–4.27). With the poly6 kernel in its published form (docs/design.md, "Qian 4.28: poly6 kernel": the thesis prints
``(v^2 - h^2)^3``, negative inside the support)::

    w(v) = 315 / (64 pi h^9) (h^2 - v^2)^3   for v < h,   0 otherwise          (4.28)

We normalise the stroke so that ``amount`` is the weight added at the brush centre,
``amount * w(v) / w(0) = amount (1 - v^2/h^2)^3``, which makes strokes of different radii comparable.
A tet's stiffness is then scaled by ``1 + (mean weight of its four nodes)``: Young's modulus and
both Lamé parameters together, so the Poisson ratio is unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.model import Model, lame_from_young_poisson


def poly6(v: np.ndarray, h: float) -> np.ndarray:
    """The poly6 kernel w(v) [1/m^3] (Qian 4.28 with the sign fixed)."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v < h, 315.0 / (64.0 * np.pi * h**9) * (h * h - v * v) ** 3, 0.0)


@dataclass(frozen=True)
class Stroke:
    centre: tuple[float, float, float]
    radius: float  # kernel support h [m]
    amount: float  # weight added at the centre (stiffness multiplier - 1)


def paint_weights(points: np.ndarray, strokes, weights: np.ndarray | None = None) -> np.ndarray:
    """Node weights W (n,) after the strokes (4.26): W <- W + amount w(|x - c|) / w(0)."""
    W = np.zeros(points.shape[0]) if weights is None else weights.astype(np.float64).copy()
    for s in strokes:
        if not s.radius > 0.0:
            raise ValueError(f"paint stroke radius must be positive, found {s.radius}")
        v = np.linalg.norm(points - np.asarray(s.centre, dtype=np.float64), axis=1)
        W += s.amount * poly6(v, s.radius) / poly6(np.zeros(1), s.radius)[0]
    return W


def apply_painting(model: Model, strokes) -> np.ndarray:
    """Scale each tet's E, mu, lam by 1 + mean node weight; returns the per-tet factors."""
    W = paint_weights(model.X, strokes)
    factor = 1.0 + W[model.tets].mean(axis=1)
    if np.any(factor <= 0.0):
        bad = int(np.argmin(factor))
        raise ValueError(f"painting makes tet {bad} non-positive (stiffness factor {factor[bad]:.3g}); "
                         "negative amounts must stay above -1 at every node")
    model.E = model.E * factor
    model.mu, model.lam = lame_from_young_poisson(model.E, model.nu)
    return factor
