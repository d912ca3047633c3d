"""The changing topology of a cut body: which of its original tets remain, the model filtered to them, and the
boundary of what remains split into the original surface and the faces the cut exposed.

Element removal (Qian §5.3; Cotin et al. 2000): a tet is either kept whole or removed whole, no node is created,
and every node keeps its index, so node sets (fixed, prescribed, held, grasped, painted) stay valid. A node left
in no tet keeps its position and gets mass 0 (inverse mass 0: no integrator moves it, and it belongs to no
surface). One rule keeps the boundary a closed 2-manifold (every edge on exactly two boundary faces): around
every edge the remaining tets must form one fan (an *arc* of tets joined through faces containing the edge);
where a removal leaves several arcs, the tets held by that edge alone are hinges of zero stiffness across it, and
the arcs other than the largest are removed as well (ties: the arc holding the lowest tet id is kept). Only the
edges of removed tets can change, so the closure looks at those.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from sim.mesh.surface import TET_FACES
from sim.model import Model

_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


@njit(cache=True)
def split_fans(edges, tets, alive, node_start, node_tets, drop):
    """For each edge (u, v) of ``edges`` (k, 2): group the ``alive`` tets around it into arcs (joined when two share a
    face containing the edge, i.e. a third node) and mark in ``drop`` the tets of every arc but the largest (ties:
    the arc holding the lowest tet id stays). ``node_tets[node_start[i]:node_start[i + 1]]``: the tets of node i."""
    for e in range(edges.shape[0]):
        u, v = edges[e, 0], edges[e, 1]
        degree = node_start[u + 1] - node_start[u]
        fan = np.empty(degree, np.int64)
        parent = np.empty(degree, np.int64)
        size = np.empty(degree, np.int64)
        lowest = np.empty(degree, np.int64)
        n = 0
        for p in range(node_start[u], node_start[u + 1]):
            t = node_tets[p]
            if alive[t] and (tets[t, 0] == v or tets[t, 1] == v or tets[t, 2] == v or tets[t, 3] == v):
                fan[n] = t
                n += 1
        if n < 2:
            continue
        for i in range(n):
            parent[i] = i
        for i in range(n):
            for j in range(i + 1, n):
                joined = False
                for a in range(4):
                    x = tets[fan[i], a]
                    if x == u or x == v:
                        continue
                    for b in range(4):
                        if tets[fan[j], b] == x:
                            joined = True
                if joined:
                    ri, rj = i, j
                    while parent[ri] != ri:
                        ri = parent[ri]
                    while parent[rj] != rj:
                        rj = parent[rj]
                    parent[ri] = rj
        for i in range(n):
            size[i] = 0
            lowest[i] = np.iinfo(np.int64).max
        for i in range(n):
            r = i
            while parent[r] != r:
                r = parent[r]
            parent[i] = r
            size[r] += 1
            lowest[r] = min(lowest[r], fan[i])
        best = -1
        for i in range(n):
            if parent[i] == i and (best < 0 or size[i] > size[best] or (size[i] == size[best] and lowest[i] < lowest[best])):
                best = i
        for i in range(n):
            if parent[i] != best:
                drop[fan[i]] = True


@dataclass
class Cut:
    """Tool ``probe`` (index into ``Model.probes``) cuts from ``t_start`` to ``t_end`` [s] with its capsules from
    ``blade_from`` on (0: all of them; 1: an instrument's without its shaft)."""

    probe: int
    t_start: float
    t_end: float
    blade_from: int = 0


def face_keys(faces: np.ndarray, n_nodes: int) -> np.ndarray:
    """One int64 per triangle (k, 3) of node ids, equal for equal node sets: ``(a n + b) n + c``, a < b < c
    (exact for n < 2**21 nodes)."""
    s = np.sort(faces, axis=1).astype(np.int64)
    return (s[:, 0] * n_nodes + s[:, 1]) * n_nodes + s[:, 2]


def boundary_of(tets: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """The faces (k, 3) used by exactly one of ``tets``, outward oriented (``TET_FACES``), and their keys."""
    faces = tets[:, TET_FACES].reshape(-1, 3)
    keys = face_keys(faces, n_nodes)
    _, first, counts = np.unique(keys, return_index=True, return_counts=True)
    once = first[counts == 1]
    once.sort()  # in tet order: deterministic
    return faces[once], keys[once]


def filter_model(model: Model, keep: np.ndarray) -> None:
    """Keep only the tets ``keep`` (m,) bool of ``model`` (in place): rest shape, volumes, per-tet material fields
    and fibres filtered, lumped masses ``rho V / 4`` summed again over the remaining tets (0 on orphan nodes)."""
    keep = np.flatnonzero(keep)
    take = lambda a: np.take(a, keep, axis=0)  # noqa: E731 (many times faster than a[keep] for 2-d and 3-d arrays)
    model.tets, model.Dm_inv, model.volume = take(model.tets), take(model.Dm_inv), take(model.volume)
    model.E, model.nu, model.mu, model.lam = take(model.E), take(model.nu), take(model.mu), take(model.lam)
    if model.fibre is not None:
        model.fibre = take(model.fibre)
    # summed in tet order as np.add.at would (bincount adds its weights in order): a node none of whose tets went
    # keeps its mass to the bit
    model.mass = np.bincount(model.tets.ravel(), np.repeat(model.density * model.volume / 4.0, 4),
                             minlength=model.n_nodes)


@njit(cache=True)
def sum_node_masses(nodes, node_start, node_tets, alive, node_mass, mass):
    """``mass[i]`` for each of ``nodes``: the sum of ``node_mass[t]`` over its ``alive`` tets in increasing id (the
    order in which ``filter_model``'s bincount adds them, starting from 0: the same value to the bit)."""
    for i in nodes:
        total = 0.0
        for p in range(node_start[i], node_start[i + 1]):
            t = node_tets[p]
            if alive[t]:
                total += node_mass[t]
        mass[i] = total


@njit(cache=True)
def alive_tets_of(nodes, node_start, node_tets, alive, mark):
    """Set ``mark[t]`` for every ``alive`` tet t of one of ``nodes`` (the tets whose nodes' masses a removal
    changed)."""
    for i in nodes:
        for p in range(node_start[i], node_start[i + 1]):
            t = node_tets[p]
            if alive[t]:
                mark[t] = True


class CutTopology:
    """A body's original tets and which remain (``alive``, by original id; the model's tets are
    ``tets[alive]`` in order), with the node-to-tet incidence and the keys of the original boundary faces."""

    def __init__(self, model: Model):
        self.tets = np.ascontiguousarray(model.tets, dtype=np.int64)
        self.n_nodes = model.n_nodes
        if self.n_nodes >= 2 ** 21:  # face_keys packs three node ids into one int64
            raise ValueError(f"cutting supports bodies of fewer than 2**21 nodes, found {self.n_nodes}")
        self.alive = np.ones(self.tets.shape[0], dtype=bool)
        node_of = self.tets.ravel()
        order = np.argsort(node_of, kind="stable")
        self.node_tets = order // 4  # tets of node i: node_tets[node_start[i]:node_start[i + 1]]
        self.node_start = np.concatenate([[0], np.cumsum(np.bincount(node_of, minlength=self.n_nodes))])
        self.original_boundary = np.sort(boundary_of(self.tets, self.n_nodes)[1])
        self.removed_volume = 0.0
        self.removed = 0

    def ids(self) -> np.ndarray:
        """Original ids of the remaining tets (the model's tet k is original tet ``ids()[k]``)."""
        return np.flatnonzero(self.alive)

    def remove(self, ids: np.ndarray) -> np.ndarray:
        """Remove the original tets ``ids`` and those the manifold rule adds (module docstring); returns every
        original id removed now, sorted."""
        ids = np.unique(np.asarray(ids, dtype=np.int64))
        ids = ids[self.alive[ids]]
        removed = [ids]
        self.alive[ids] = False
        work = ids
        while work.size:
            edges = np.sort(self.tets[work][:, _EDGES].reshape(-1, 2), axis=1)
            key = np.unique(edges[:, 0] * self.n_nodes + edges[:, 1])  # one int64 per edge (n < 2**21 nodes)
            edges = np.stack([key // self.n_nodes, key % self.n_nodes], axis=1)
            drop = np.zeros(self.alive.size, dtype=np.bool_)
            split_fans(edges, self.tets, self.alive, self.node_start, self.node_tets, drop)
            work = np.flatnonzero(drop & self.alive)
            self.alive[work] = False
            removed.append(work)
        removed = np.unique(np.concatenate(removed))
        self.removed += int(removed.size)
        return removed

    def surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The boundary of the remaining tets as node-id triangles, outward: ``(original, cut)``, the faces on the
        original boundary and the faces the cut exposed. Together closed and edge-manifold (module docstring)."""
        faces, keys = boundary_of(self.tets[self.alive], self.n_nodes)
        on_original = np.isin(keys, self.original_boundary, assume_unique=False)
        return faces[on_original], faces[~on_original]
