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

from sim.mesh.surface import TET_FACES
from sim.model import Model

_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


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
    unique, first, counts = np.unique(keys, return_index=True, return_counts=True)
    once = first[counts == 1]
    once.sort()  # in tet order: deterministic
    return faces[once], keys[once]


def filter_model(model: Model, keep: np.ndarray) -> None:
    """Keep only the tets ``keep`` (m,) bool of ``model`` (in place): rest shape, volumes, per-tet material fields
    and fibres filtered, lumped masses ``rho V / 4`` summed again over the remaining tets (0 on orphan nodes)."""
    model.tets = np.ascontiguousarray(model.tets[keep])
    model.Dm_inv = np.ascontiguousarray(model.Dm_inv[keep])
    model.volume = model.volume[keep]
    model.E, model.nu, model.mu, model.lam = model.E[keep], model.nu[keep], model.mu[keep], model.lam[keep]
    if model.fibre is not None:
        model.fibre = np.ascontiguousarray(model.fibre[keep])
    mass = np.zeros(model.n_nodes)
    np.add.at(mass, model.tets.ravel(), np.repeat(model.density * model.volume / 4.0, 4))
    model.mass = mass


class CutTopology:
    """A body's original tets and which remain (``alive``, by original id; the model's tets are
    ``tets[alive]`` in order), with the node-to-tet incidence and the keys of the original boundary faces."""

    def __init__(self, model: Model):
        self.tets = np.ascontiguousarray(model.tets, dtype=np.int64)
        self.n_nodes = model.n_nodes
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

    def _fan(self, u: int, v: int) -> list[int]:
        a = self.node_tets[self.node_start[u]:self.node_start[u + 1]]
        b = self.node_tets[self.node_start[v]:self.node_start[v + 1]]
        return [int(t) for t in np.intersect1d(a, b) if self.alive[t]]

    def _arcs(self, u: int, v: int, fan: list[int]) -> list[list[int]]:
        """The fan's tets grouped into arcs: joined when they share a face containing the edge u-v."""
        parent = list(range(len(fan)))

        def root(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        others = [set(self.tets[t].tolist()) - {u, v} for t in fan]
        for i in range(len(fan)):
            for j in range(i + 1, len(fan)):
                if others[i] & others[j]:
                    parent[root(i)] = root(j)
        groups: dict[int, list[int]] = {}
        for i, t in enumerate(fan):
            groups.setdefault(root(i), []).append(t)
        return list(groups.values())

    def remove(self, ids: np.ndarray) -> np.ndarray:
        """Remove the original tets ``ids`` and those the manifold rule adds (module docstring); returns every
        original id removed now, sorted."""
        ids = np.unique(np.asarray(ids, dtype=np.int64))
        ids = ids[self.alive[ids]]
        removed = [ids]
        self.alive[ids] = False
        work = ids
        while work.size:
            edges = np.unique(np.sort(self.tets[work][:, _EDGES].reshape(-1, 2), axis=1), axis=0)
            more = []
            for u, v in edges.tolist():
                fan = self._fan(u, v)
                if len(fan) < 2:
                    continue
                arcs = self._arcs(u, v, fan)
                if len(arcs) > 1:
                    arcs.sort(key=lambda arc: (-len(arc), min(arc)))
                    for arc in arcs[1:]:
                        more += arc
            work = np.unique(np.array(more, dtype=np.int64))
            work = work[self.alive[work]]
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
