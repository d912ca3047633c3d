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


def _domains(coordinate, tets, cuts):
    """Domain of every tet (-1: separator) for slab cuts ``cuts`` of the node coordinates."""
    node_domain = np.searchsorted(cuts, coordinate, side="right")
    tet_domain = node_domain[tets]
    return np.where((tet_domain == tet_domain[:, :1]).all(axis=1), tet_domain[:, 0], -1)


def split_into_domains(points: np.ndarray, tets: np.ndarray, n_domains: int) -> list[np.ndarray]:
    """Tet index arrays ``[interior_0, ..., interior_{D-1}, separator]`` for parallel Gauss–Seidel with
    one thread per domain: the mesh is cut into ``n_domains`` slabs along its longest axis; each node
    belongs to the slab of its coordinate, a tet to a domain's interior when all four of its nodes do,
    otherwise to the separator. Interiors of different domains share no node, so they can be swept
    concurrently, each in its own colour order, and the separator (a layer about one tet thick) after
    them; the order, and so the result, does not depend on how many threads run it. Each cut is
    placed near a quantile of the tet centroids where it best balances the two interiors it bounds."""
    tets = np.asarray(tets)
    everything = np.arange(tets.shape[0], dtype=np.int64)
    if n_domains <= 1 or tets.shape[0] == 0:
        return [everything, np.zeros(0, np.int64)]
    axis = int(np.argmax(np.ptp(points, axis=0)))
    coordinate = points[:, axis]
    centroid = coordinate[tets].mean(axis=1)
    cuts = np.quantile(centroid, np.arange(1, n_domains) / n_domains)
    for j in range(n_domains - 1):
        best = None
        for q in (j + 1 + np.linspace(-0.25, 0.25, 51)) / n_domains:
            trial = cuts.copy()
            trial[j] = np.quantile(centroid, q)
            if not np.all(np.diff(trial) > 0):
                continue
            counts = np.bincount(_domains(coordinate, tets, trial) + 1, minlength=n_domains + 1)[1:]
            imbalance = abs(int(counts[j]) - int(counts[j + 1]))
            if best is None or imbalance < best[0]:
                best = (imbalance, trial[j])
        if best is not None:
            cuts[j] = best[1]
    domain = _domains(coordinate, tets, cuts)
    return [everything[domain == d] for d in range(n_domains)] + [everything[domain < 0]]
