"""Mesh containers shared by every part of the product.

Arrays are structure-of-arrays, C-contiguous: ``points (n, 3) float64``, ``tets (m, 4) int32``
(positively oriented: ``det([x1-x0, x2-x0, x3-x0]) > 0``), ``triangles (k, 3) int32``
(counter-clockwise seen from outside, so the geometric normal points out).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class TetMesh:
    """A tetrahedral volume mesh.

    Parameters
    ----------
    points : (n, 3) float64 rest positions in metres.
    tets : (m, 4) int32 vertex indices, positively oriented.
    source : where the mesh came from (a file path or ``"procedural:<shape>"``), used in messages.
    repairs : what reading the file repaired, ``{"flipped": int, "unreferenced_removed": int}`` (empty when the
        mesh was not read from a file).
    """

    points: np.ndarray
    tets: np.ndarray
    source: str = "<memory>"
    repairs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(self.points, dtype=np.float64)
        self.tets = np.ascontiguousarray(self.tets, dtype=np.int32)

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_tets(self) -> int:
        return int(self.tets.shape[0])


@dataclass
class SurfaceMesh:
    """A triangle surface, optionally with per-vertex normals and UVs.

    ``normals`` is ``None`` when the source had none (they are then computed by area weighting);
    ``uv`` is ``None`` when no parameterisation exists.
    """

    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None = None
    uv: np.ndarray | None = None
    source: str = "<memory>"
    vertex_map: np.ndarray | None = None  # surface vertex -> tet-mesh node, for boundary surfaces

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(self.points, dtype=np.float64)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int32)
        if self.normals is not None:
            self.normals = np.ascontiguousarray(self.normals, dtype=np.float64)
        if self.uv is not None:
            self.uv = np.ascontiguousarray(self.uv, dtype=np.float64)


@dataclass
class Embedding:
    """Points embedded in a tet mesh by barycentric coordinates.

    ``tet_index (p,) int32`` is the containing (or nearest) tet of each embedded point and
    ``bary (p, 4) float64`` its barycentric weights (summing to one). Deformed positions are
    ``sum_k bary[:, k, None] * x[tets[tet_index, k]]``.
    """

    tet_index: np.ndarray
    bary: np.ndarray
    extra: dict = field(default_factory=dict)
