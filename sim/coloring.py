"""Greedy graph colouring of tets: tets of one colour share no node, so a colour's constraints can be
projected in parallel without races (Gauss–Seidel across colours, Jacobi-free within one)."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _greedy(tets, n_nodes):
    m = tets.shape[0]
    colour = np.empty(m, np.int64)
    # node_colours[i] is a bitmask of colours already used by tets touching node i (up to 63 colours).
    node_mask = np.zeros(n_nodes, np.int64)
    for t in range(m):
        used = node_mask[tets[t, 0]] | node_mask[tets[t, 1]] | node_mask[tets[t, 2]] | node_mask[tets[t, 3]]
        c = 0
        while (used >> c) & 1:
            c += 1
        colour[t] = c
        bit = np.int64(1) << c
        for k in range(4):
            node_mask[tets[t, k]] |= bit
    return colour


def colour_tets(tets: np.ndarray, n_nodes: int) -> list[np.ndarray]:
    """Tet index arrays, one per colour; no two tets of a colour share a node."""
    colour = _greedy(np.ascontiguousarray(tets, dtype=np.int64), int(n_nodes))
    if colour.max() >= 63:
        raise ValueError("more than 63 colours needed; the mesh has a node shared by too many tets")
    order = np.argsort(colour, kind="stable")
    counts = np.bincount(colour)
    return [g.astype(np.int64) for g in np.split(order, np.cumsum(counts)[:-1])]
