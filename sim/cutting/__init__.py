"""Cutting (issue 21 item 3; Qian §5.3): a tool's blade removes the tets it sweeps through while its cut is active.

Qian's dissection is topology-unchanged: no node or element is created, elements are taken out and the renderer
is fed only the faces still in use. Here, likewise, a tet the blade meets is removed whole
(``sim.cutting.sweep``: exact capsule–tet tests over the blade's positions in each substep), every node keeps its
index, and the topology is brought up to date at once (``sim.cutting.topology``): the model's per-tet arrays are
filtered, lumped masses summed again (orphan nodes get mass 0 and drop out of the solve), tets hanging on by an
edge are removed with them (the boundary stays a closed 2-manifold), and the integrator updates its constraints
(``sim.integrators.xpbd.removal``: the removed tets stop acting at once, the per-tet data is filtered once per step;
removing tets from a graph colouring leaves it a colouring, so each colour is filtered, not recomputed). The masses
change at the removal, the model's per-tet arrays when the integrator commits it (:meth:`Cutter.commit`). The render surface is then the boundary of the remaining tets, the
faces the cut exposed drawn with the body's ``cut_material`` (``tissuerender.world``; docs/interaction.md,
"Cutting"). Not modelled: Qian's heat transfer and shrinkage of the dissected area (§5.3.2–5.3.3), splitting tets
along the blade (virtual nodes).
"""
from __future__ import annotations

import math

import numpy as np

from sim.cutting.sweep import blade_hits
from sim.cutting.topology import Cut, CutTopology, alive_tets_of, filter_model, sum_node_masses
from sim.model import Model
from sim.probe import Probe

__all__ = ["Cut", "CutState", "Cutter", "CutTopology", "filter_model"]


class CutState:
    """One cut's blade: the probe's capsules from ``blade_from`` on, sampled over a substep."""

    def __init__(self, cut: Cut, probe):
        self.cut = cut
        self.probe = probe

    def window(self, t: float, t_next: float) -> tuple[float, float] | None:
        """The part of the substep ``[t, t_next]`` in which the cut is active, or None."""
        lo, hi = max(t, self.cut.t_start), min(t_next, self.cut.t_end)
        return (lo, hi) if lo <= hi else None

    def blade(self, t: float) -> list[tuple]:
        return self.probe.capsules(t)[self.cut.blade_from:]

    def samples(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Capsule ends ``(a, b)`` (k, 3) and radii (k,) at times from ``t0`` to ``t1``, spaced so that each end of
        every blade capsule moves at most its radius between consecutive samples (``sim.cutting.sweep``)."""
        first, last = self.blade(t0), self.blade(t1)
        n = 1
        for (a0, b0, r), (a1, b1, _) in zip(first, last):
            travel = max(np.linalg.norm(np.asarray(a1) - a0), np.linalg.norm(np.asarray(b1) - b0))
            n = max(n, math.ceil(travel / r))
        times = [t0] if t1 <= t0 else [t0 + (t1 - t0) * i / n for i in range(n)] + [t1]
        caps = [c for i, time in enumerate(times)
                for c in (first if i == 0 else last if i == len(times) - 1 else self.blade(time))]
        a = np.array([c[0] for c in caps], dtype=np.float64).reshape(-1, 3)
        b = np.array([c[1] for c in caps], dtype=np.float64).reshape(-1, 3)
        r = np.array([c[2] for c in caps], dtype=np.float64)
        return a, b, r


class Shaft:
    """A probe seen without its blade (its capsules before ``blade_from``): what still pushes tissue while it cuts."""

    def __init__(self, probe, blade_from: int):
        self.probe = probe
        self.blade_from = blade_from

    def position(self, t: float) -> np.ndarray:
        return self.probe.position(t)

    def capsules(self, t: float) -> list[tuple]:
        return self.probe.capsules(t)[:self.blade_from]

    push_out = Probe.push_out  # its capsules pushed out like any probe's (sim.probe.resolve_contact_load)


class Cutter:
    """The cuts acting on one body (``model.cuts``, tools from ``model.probes``) and its :class:`CutTopology`.
    ``revision`` counts the removals, so a renderer knows when to rebuild the surface."""

    def __init__(self, model: Model):
        self.model = model
        self.cuts = [CutState(c, model.probes[c.probe]) for c in getattr(model, "cuts", ())]
        self.topology = CutTopology(model)
        self.revision = 0
        self.model_ids = np.arange(model.n_tets)  # the original ids of the model's tets (filtered by commit)
        self.volume = model.volume.copy()  # per original tet
        self.node_mass = model.density * self.volume / 4.0  # its share of each of its nodes' lumped mass
        model.mass = model.mass.copy()  # summed again in place at each removal
        self.pending = False  # tets removed since the last commit
        self.touched = np.zeros(0, dtype=np.int64)  # the nodes whose masses the last sweep changed

    def contact_probes(self, probes: list, t: float, t_next: float) -> list:
        """The probes as they push tissue over the substep ``[t, t_next]``: a tool whose cut is active there pushes
        with its shaft only; its blade passes through the tissue, removing what it meets, instead of pushing the
        tissue ahead of it (which would let the tissue slip around the blade uncut)."""
        probes = list(probes)
        for cut in self.cuts:
            if cut.window(t, t_next) is not None:
                probes[cut.cut.probe] = Shaft(probes[cut.cut.probe], cut.cut.blade_from)
        return probes

    def sweep(self, x: np.ndarray, t: float, t_next: float) -> np.ndarray | None:
        """Remove the tets the active blades sweep through over the substep ``[t, t_next]`` at positions ``x``:
        returns the original ids removed (sorted; with those of the manifold rule), None when nothing was cut. The
        lumped masses of their nodes are summed again over the remaining tets at once (in tet order, as
        ``filter_model`` sums them: the same values); the model keeps the tets until :meth:`commit`."""
        m = self.model
        hit = np.zeros(m.n_tets, dtype=bool)
        for cut in self.cuts:
            window = cut.window(t, t_next)
            if window is not None:
                blade_hits(x, m.tets, *cut.samples(*window), hit)
        if not hit.any():
            return None
        removed = self.topology.remove(self.model_ids[hit])  # the tets removed before and not yet committed: dropped
        if not removed.size:
            return None
        self.topology.removed_volume += float(self.volume[removed].sum())
        top = self.topology
        self.touched = np.unique(top.tets[removed])  # the nodes whose masses change
        sum_node_masses(self.touched, top.node_start, top.node_tets, top.alive, self.node_mass, m.mass)
        self.revision += 1
        self.pending = True
        return removed

    def touched_tets(self) -> np.ndarray:
        """The original ids of the remaining tets around the nodes the last :meth:`sweep` changed the masses of."""
        top = self.topology
        mark = np.zeros(top.alive.size, dtype=bool)
        alive_tets_of(self.touched, top.node_start, top.node_tets, top.alive, mark)
        return np.flatnonzero(mark)

    def commit(self) -> np.ndarray | None:
        """Filter the model's per-tet arrays to the remaining tets (``filter_model``): returns the mask (m,) of its
        previous tets kept, None when none was removed since the last commit."""
        if not self.pending:
            return None
        keep = self.topology.alive[self.model_ids]
        self.model_ids = self.model_ids[keep]
        filter_model(self.model, keep)
        self.pending = False
        return keep
