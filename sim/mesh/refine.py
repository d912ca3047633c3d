"""Uniform refinement of a tetrahedral mesh and its quadratic (10-node) form, both from the mesh's edges.

- :func:`refine`: every tet split into 8 (Bey 1995, "Tetrahedral grid refinement"): the four corner tets cut off
  at the edge midpoints, and the octahedron left in the middle split along its shortest diagonal (the choice
  that keeps the children's shape quality from degrading). The children fill the parent exactly, so the volume
  is preserved; every face is cut into the same four triangles from either side, so the refined mesh conforms.
- :func:`to_quadratic`: the same edge midpoints as extra nodes of 10-node tets (straight edges: the map from the
  reference tet stays affine, so the corner tets' ``Dm_inv`` and volume serve the quadratic element too).

Both keep the coarse nodes first, with their indices, and append one node per unique edge in the order of
:func:`unique_edges`: the refined mesh and the quadratic mesh have the same nodes, and ``x[:n_coarse]`` of either is
the coarse mesh's nodes (how the report compares a coarse solution with a refined one).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.mesh.procedural import orient
from sim.mesh.types import TetMesh

# the local edges of a tet, in the order of the 10-node tet's edge nodes 4..9
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


def unique_edges(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(edges (e, 2), tet_edges (m, 6))``: the unique edges (sorted node pairs, in lexicographic order) and, per tet,
    the index of its local edges ``TET_EDGES`` in ``edges``."""
    tets = np.asarray(tets, dtype=np.int64)
    pairs = np.sort(tets[:, TET_EDGES], axis=2).reshape(-1, 2)  # (6m, 2)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    return edges, inverse.reshape(-1, 6)


@dataclass
class QuadraticTetMesh:
    """A mesh of 10-node tets: ``points (n + e, 3)`` (the corner mesh's ``n`` nodes first, then one per edge at its
    midpoint) and ``tets (m, 10) int32``: the 4 corners of the linear tet, then the nodes of its edges 01, 02, 03,
    12, 13, 23. ``linear`` is the corner mesh."""

    points: np.ndarray
    tets: np.ndarray
    linear: TetMesh

    @property
    def n_corner_nodes(self) -> int:
        return self.linear.n_points


def _with_midpoints(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray]:
    """The points with the edge midpoints appended, and each tet's 10 node ids."""
    edges, tet_edges = unique_edges(mesh.tets)
    points = np.concatenate([mesh.points, 0.5 * (mesh.points[edges[:, 0]] + mesh.points[edges[:, 1]])])
    nodes10 = np.concatenate([mesh.tets.astype(np.int64), mesh.n_points + tet_edges], axis=1)
    return points, nodes10


def to_quadratic(mesh: TetMesh) -> QuadraticTetMesh:
    """The 10-node form of a linear tet mesh (module docstring).

    >>> from sim.mesh.procedural import box
    >>> q = to_quadratic(box((1.0, 1.0, 1.0), (1, 1, 1)))
    >>> q.tets.shape, q.points.shape  # 6 tets; 8 corners + 19 edges
    ((6, 10), (27, 3))
    """
    points, nodes10 = _with_midpoints(mesh)
    return QuadraticTetMesh(points, np.ascontiguousarray(nodes10, dtype=np.int32), mesh)


# the 8 children of a tet in its local 10-node numbering (corners 0-3, edge nodes 4-9 of TET_EDGES): the corner tets,
# then the octahedron's four tets around each possible diagonal, the four others in cyclic order
_CORNER_CHILDREN = np.array([[0, 4, 5, 6], [4, 1, 7, 8], [5, 7, 2, 9], [6, 8, 9, 3]])
_OCTAHEDRON = {  # diagonal -> the ring of the other four midpoints (neighbours share a corner of the parent)
    (4, 9): (5, 6, 8, 7),  # 01-23 : 02, 03, 13, 12
    (5, 8): (4, 6, 9, 7),  # 02-13 : 01, 03, 23, 12
    (6, 7): (4, 5, 9, 8),  # 03-12 : 01, 02, 23, 13
}


def refine(mesh: TetMesh) -> TetMesh:
    """Every tet split into 8 (module docstring); the coarse nodes keep their indices, the edge midpoints follow.

    >>> from sim.mesh.procedural import box
    >>> refine(box((1.0, 1.0, 1.0), (1, 1, 1))).n_tets
    48
    """
    points, nodes10 = _with_midpoints(mesh)
    diagonals = list(_OCTAHEDRON)
    lengths = np.stack([np.linalg.norm(points[nodes10[:, a]] - points[nodes10[:, b]], axis=1) for a, b in diagonals],
                       axis=1)
    shortest = np.argmin(lengths, axis=1)  # ties: the first, so the split is deterministic
    children = np.empty((mesh.n_tets, 8, 4), dtype=np.int64)
    children[:, :4] = nodes10[:, _CORNER_CHILDREN]
    for k, (a, b) in enumerate(diagonals):
        rows = shortest == k
        ring = _OCTAHEDRON[(a, b)]
        local = np.array([[a, b, ring[i], ring[(i + 1) % 4]] for i in range(4)])
        children[rows, 4:] = nodes10[rows][:, local]
    tets = children.reshape(-1, 4)
    source = f"{mesh.source} refined 1:8"
    return TetMesh(points, orient(points, tets), source=source)
