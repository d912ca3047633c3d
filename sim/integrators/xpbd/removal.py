"""XPBD's side of a cut (``sim.cutting``; docs/interaction.md, "Cutting"): the tets a blade removes stop acting at
once, and the per-tet data is filtered once per step.

A removal in a substep (:meth:`TetRemoval.remove`) touches only what is near it:

- the removed tets' lanes in the blocked kernel's blocks (``sim.integrators.xpbd.blocked``) become inert: every
  parameter zero, so the lane's deformation gradient is 0, its projection takes the degenerate branch and its node
  corrections are exactly 0.0 (``blocked.make_inert``); the lane keeps its place, so nothing is packed again;
- the cutter has summed the lumped masses of the removed tets' nodes again (``sim.cutting.Cutter.sweep``); the
  inverse masses follow, and the rows w_k and M of the kept tets around those nodes are rewritten
  (``blocked.set_inverse_masses``, the packing's own arithmetic).

At the end of the step (:meth:`TetRemoval.compact`) the model's per-tet arrays are filtered
(``sim.cutting.Cutter.commit``) and so are XPBD's, in colour order: removing tets from a graph colouring leaves a
colouring and the domains' interiors still share no node, so each colour is filtered, not recomputed. The blocks
are packed anew only when their inert lanes number more than ``repack_fraction`` of the tets kept (inert lanes
still cost their share of a sweep). The kept tets keep their order within every colour and their parameters, so
the positions are those of blocks packed anew after every removal, to the bit (tests/sim/test_cut.py).

The constraint sets other than the blocked kernel's (the scalar and Jacobi kernels, the model's own energy) and the
strain limits read the per-tet arrays directly: for them the arrays are filtered at every removal.
"""
from __future__ import annotations

import numpy as np

from sim.integrators.xpbd import blocked
from sim.integrators.xpbd.strain import GreenStrainLimits


class TetRemoval:
    """The removal state of one :class:`sim.integrators.xpbd.solver.XPBD` with a cutter: each original tet's
    position in the colour order (``position_of``, -1 once filtered out), the positions removed since the last
    :meth:`compact` (``dead``) and, per constraint set, each position's lane in its blocks (``slots[k]``) and the
    inert lanes left in them (``inert[k]``). A set packed anew elsewhere (a Prony branch after its drift, always
    from the filtered arrays) is noticed by its blocks' identity and gets a fresh layout."""

    # blocks are packed anew once their inert lanes number more than this fraction of the tets kept
    repack_fraction = 1.0 / 16.0

    def __init__(self, xpbd):
        self.xpbd = xpbd
        n = xpbd.tet_order.size
        self.position_of = np.empty(n, dtype=np.int64)  # the model's tets are the original ones before any cut
        self.position_of[xpbd.tet_order] = np.arange(n)
        self.dead = np.zeros(n, dtype=bool)
        self.packed = [None] * len(xpbd.sets)  # the blocks each layout below belongs to
        self.slots = [np.zeros(0, dtype=np.int64)] * len(xpbd.sets)
        self.inert = [0] * len(xpbd.sets)
        # filtered once per step only where every constraint set is the blocked kernel's and nothing else reads
        # the per-tet arrays during the sweeps
        self.deferred = (all(s.blocks is not None for s in xpbd.sets) and xpbd.strain_limits is None
                         and xpbd.green_limits is None)

    def _layout(self, k: int) -> np.ndarray:
        """Set k's lane per colour-order position; a fresh packing's when its blocks are not those last seen."""
        blocks = self.xpbd.sets[k].blocks
        if blocks is not self.packed[k]:
            self.packed[k] = blocks
            self.slots[k] = blocked.colour_slots(self.xpbd.colour_start)[1]
            self.inert[k] = 0
        return self.slots[k]

    def remove(self, removed: np.ndarray) -> None:
        """The cutter has removed the original tets ``removed`` and summed the masses of their nodes again."""
        xp = self.xpbd
        positions = self.position_of[removed]
        self.dead[positions] = True
        for k, constraints in enumerate(xp.sets):
            if constraints.blocks is not None:
                blocked.make_inert(constraints.blocks[1], self._layout(k)[positions])
                self.inert[k] += positions.size
        self._masses_changed(self.position_of[xp.cutter.touched_tets()])
        for grasp in xp.grasps:  # a grasped node left in no tet has no mass to hold: it lets go
            if grasp.nodes.size:
                grasp.detach(xp.w[grasp.nodes] == 0.0)
        if not self.deferred:
            self.compact()

    def _masses_changed(self, around: np.ndarray | None = None) -> None:
        """Inverse masses from the model's masses; the mass rows of the live tets of a node whose mass changed: the
        tets at positions ``around`` (the cutter's :meth:`~sim.cutting.Cutter.touched_tets`: no others can have
        changed), or, without them, every tet of a node whose inverse mass is not what it was."""
        xp = self.xpbd
        w_before = xp.w
        xp._per_node()
        if around is None:
            moved = xp.w != w_before
            if not moved.any():
                return
            tets = xp.tets
            around = np.flatnonzero((moved[tets[:, 0]] | moved[tets[:, 1]] | moved[tets[:, 2]] | moved[tets[:, 3]])
                                    & ~self.dead)
        if around.size:
            for k, constraints in enumerate(xp.sets):
                if constraints.blocks is not None:
                    blocked.set_inverse_masses(constraints.blocks[1], self._layout(k)[around], xp.tets[around],
                                               constraints.Dm_inv[around], xp.w)

    def compact(self) -> None:
        """Filter the model's per-tet arrays and XPBD's to the tets kept (nothing when none was removed since the last
        call); the blocks keep their inert lanes unless these pass ``repack_fraction``."""
        xp = self.xpbd
        keep = xp.cutter.commit()  # mask over the model's previous tets
        if keep is None:
            return
        layouts = [self._layout(k) if c.blocks is not None else None for k, c in enumerate(xp.sets)]  # current order
        new_id = np.cumsum(keep) - 1
        kept_mask = keep[xp.tet_order]  # per colour-order position: ~self.dead
        kept = np.flatnonzero(kept_mask)
        take = lambda a: np.take(a, kept, axis=0)  # noqa: E731 (many times faster than a[kept] for 2-d, 3-d arrays)
        kept_before = np.concatenate([[0], np.cumsum(kept_mask)])  # kept tets before each colour-order position
        xp.colour_start = kept_before[xp.colour_start].astype(np.int64)
        xp.tet_order = new_id[take(xp.tet_order)].astype(np.int64)
        xp.tets = take(xp.tets)
        alive = xp.cutter.topology.alive
        self.position_of = np.where(alive, kept_before[self.position_of], -1)
        self.dead = np.zeros(kept.size, dtype=bool)
        if xp.branches is not None:
            xp.branches.tets = xp.tets
            xp.branches.Dm_inv = take(xp.branches.Dm_inv)
            xp.branches.Fv = np.take(xp.branches.Fv, kept, axis=1)
        for k, s in enumerate(xp.sets):
            s.Dm_inv = take(s.Dm_inv)
            s.alpha_dev, s.alpha_hyd, s.gamma = take(s.alpha_dev), take(s.alpha_hyd), take(s.gamma)
            s.lam_dev, s.lam_hyd = take(s.lam_dev), take(s.lam_hyd)
            if s.blocks is not None:
                self.slots[k] = np.take(layouts[k], kept)
            if s.energy is not None or (s.blocks is not None and self.inert[k] > self.repack_fraction * kept.size):
                s.set_rest(s.Dm_inv)  # the model's energy (per-tet data of its own), or blocks packed anew
                if s.blocks is not None:
                    self._layout(k)  # the new packing's, without inert lanes
        base = xp.sets[0]
        xp.Dm_inv, xp.alpha_dev, xp.alpha_hyd, xp.gamma = base.Dm_inv, base.alpha_dev, base.alpha_hyd, base.gamma
        xp.blocks, xp.energy = base.blocks, base.energy
        if xp.strain_limits is not None:
            xp.limit_axes = take(xp.limit_axes)
        if xp.green_limits is not None:
            xp.green_limits = GreenStrainLimits(xp.model, xp.tet_order, xp.colour_start, xp.settings)
        self._masses_changed()  # summed again over the kept tets: the same sums, so normally no row changes
