"""Node selection for boundary conditions (fixed regions, prescribed displacements, tractions)."""
from __future__ import annotations

import numpy as np


def nodes_on_side(points: np.ndarray, axis: int, side: str, tol: float | None = None) -> np.ndarray:
    """Nodes on the ``"min"`` or ``"max"`` face of the bounding box along ``axis`` (0, 1, 2).

    ``tol`` defaults to 1e-6 of the largest extent.
    """
    if side not in ("min", "max"):
        raise ValueError(f"side must be 'min' or 'max', found {side!r}")
    coord = points[:, axis]
    extent = float(np.ptp(points, axis=0).max()) if points.size else 0.0
    tol = 1e-6 * max(extent, 1e-300) if tol is None else tol
    target = coord.min() if side == "min" else coord.max()
    return np.flatnonzero(np.abs(coord - target) <= tol).astype(np.int32)


def nodes_in_box(points: np.ndarray, lo, hi) -> np.ndarray:
    """Nodes with ``lo <= p <= hi`` componentwise."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1)).astype(np.int32)
