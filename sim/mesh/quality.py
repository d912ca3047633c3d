"""Mesh quality: tet dihedral angles, volume ratio and inverted elements; angles between neighbouring faces."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim.mesh.types import TetMesh

_EDGE_PAIRS = [(0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 1, 2), (1, 2, 0, 3), (1, 3, 0, 2), (2, 3, 0, 1)]


@dataclass(frozen=True)
class QualityReport:
    """``volume_ratio`` is the tet volume over that of the regular tet with the same RMS edge length
    (1 for a regular tet, -> 0 for slivers and needles)."""

    n_points: int
    n_tets: int
    min_dihedral_deg: float
    max_dihedral_deg: float
    min_volume_ratio: float
    mean_volume_ratio: float
    inverted: int
    total_volume: float

    def as_dict(self) -> dict:
        return asdict(self)


def dihedral_angles(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """The six interior dihedral angles [deg] of each tet, (m, 6)."""
    p = points[tets]
    out = np.empty((tets.shape[0], 6))
    for j, (a, b, c, d) in enumerate(_EDGE_PAIRS):
        e = p[:, b] - p[:, a]
        n1 = np.cross(e, p[:, c] - p[:, a])
        n2 = np.cross(e, p[:, d] - p[:, a])
        cos = np.einsum("ij,ij->i", n1, n2) / np.maximum(np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1), 1e-300)
        out[:, j] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def quality_report(mesh: TetMesh) -> QualityReport:
    p = mesh.points[mesh.tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0
    edges = np.stack([p[:, b] - p[:, a] for a, b, _, _ in _EDGE_PAIRS], axis=1)
    rms = np.sqrt((edges**2).sum(axis=2).mean(axis=1))
    ratio = vol / (rms**3 / (6.0 * np.sqrt(2.0)))
    dih = dihedral_angles(mesh.points, mesh.tets)
    return QualityReport(mesh.n_points, mesh.n_tets, float(dih.min()), float(dih.max()), float(ratio.min()),
                         float(ratio.mean()), int((vol <= 0.0).sum()), float(vol.sum()))


def neighbour_normal_angles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Angle [degrees] between the normals of the two faces at each edge shared by exactly two triangles
    (a facet shows where it is large; a voxel staircase has 90-degree steps)."""
    p = points[triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    face = np.tile(np.arange(triangles.shape[0]), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, face = edges[order], face[order]
    same = (edges[1:] == edges[:-1]).all(axis=1)
    # an edge shared by exactly two faces: equal to its successor, and neither a third copy before nor after
    first = np.flatnonzero(same & ~np.r_[same[1:], False] & ~np.r_[False, same[:-1]])
    cos = np.einsum("ij,ij->i", n[face[first]], n[face[first + 1]])
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
