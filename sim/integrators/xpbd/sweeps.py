"""One compiled call per XPBD substep for all its Gauss-Seidel sweeps when tools, grasps, contact planes or surface
contacts are projected after every sweep (issue 21, "Performance"): per sweep, the blocked elastic sweep
(``sim.integrators.xpbd.blocked``), the tools' capsules pushing nodes out (``sim.probe``), the grasps' attachments
(``sim.contact.GraspState``), the static planes (``sim.contact.project_onto_plane``) and the surface contacts
(``sim.contact_set``), in the order and with the arithmetic of the per-sweep Python loop in
``sim.integrators.xpbd.solver`` (the same positions and loads bit for bit: tests/sim/test_contact_set.py, and with a
cut, tests/sim/test_cut.py); that loop stays for what this does not cover (strain limits, nodes held in some
components, several constraint sets, other kernels, mesh tools). A cut's blade pushes as its shaft
(``sim.cutting.Shaft``); a removal leaves inert lanes in, or repacks, the blocks read at every call.

A tool's capsules test only the free nodes within its largest radius of them at the substep's start (a node must move
that far within one substep's sweeps to get inside); if any node has moved that far since, that sweep tests them all.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit

from sim.contact import project_onto_plane
from sim.contact_set import project_entries
from sim.integrators.xpbd import blocked
from sim.probe import Probe, push_nodes_out_of_capsule, push_out_of_capsule_load


@njit(cache=True)
def nodes_near_capsules(x, w, capsules, margin):
    """The free nodes (``w > 0``) within ``radius + margin`` of one of ``capsules`` ((k, 7): a, b, radius),
    ascending."""
    near = np.zeros(x.shape[0], np.bool_)
    for k in range(capsules.shape[0]):
        a, b, reach = capsules[k, 0:3], capsules[k, 3:6], capsules[k, 6] + margin
        ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        len2 = ab0 * ab0 + ab1 * ab1 + ab2 * ab2
        for i in range(x.shape[0]):
            if w[i] == 0.0 or near[i]:
                continue
            ap0, ap1, ap2 = x[i, 0] - a[0], x[i, 1] - a[1], x[i, 2] - a[2]
            s = min(max((ap0 * ab0 + ap1 * ab1 + ap2 * ab2) / len2, 0.0), 1.0) if len2 > 0.0 else 0.0
            d0, d1, d2 = ap0 - s * ab0, ap1 - s * ab1, ap2 - s * ab2
            near[i] = d0 * d0 + d1 * d1 + d2 * d2 < reach * reach
    return np.flatnonzero(near)


@njit(cache=True)
def _grasp_sweep(x, w, nodes, offsets, lam, centre, alpha, load):
    """``sim.contact.GraspState.project``: ``dlambda = (-C - alpha~ lambda) / (w + alpha~)`` per attached node, its
    impulse summed over the nodes, then added to ``load`` with its moment about the tool's centre."""
    j_sum, m_sum = np.zeros(3), np.zeros(3)
    for k in range(nodes.size):
        i = nodes[k]
        dlam = np.empty(3)
        for d in range(3):
            C = x[i, d] - (centre[d] + offsets[k, d])
            dlam[d] = (-C - alpha * lam[k, d]) / (w[i] + alpha)
            lam[k, d] += dlam[d]
            x[i, d] += w[i] * dlam[d]
        r0, r1, r2 = x[i, 0] - centre[0], x[i, 1] - centre[1], x[i, 2] - centre[2]
        for d in range(3):
            j_sum[d] += dlam[d]
        m_sum[0] += r1 * dlam[2] - r2 * dlam[1]
        m_sum[1] += r2 * dlam[0] - r0 * dlam[2]
        m_sum[2] += r0 * dlam[1] - r1 * dlam[0]
    for d in range(3):
        load[d] += j_sum[d]
        load[3 + d] += m_sum[d]


@njit(cache=True)
def substep_sweeps(x, w, w_tools, x_start, inv_dt2, iterations, node_index, params, lanes_used, colour_block,
                   domain_colour, mode, n_threads, capsules, capsule_start, probe_centre, probe_margin, probe_loads,
                   grasp_nodes, grasp_offsets, grasp_lam, grasp_start, grasp_centre, grasp_alpha, grasp_probe,
                   plane_point, plane_normal, plane_acts, plane_dn, plane_loads, static_x, n_nodes, entry_node,
                   entry_contact, entry_hint, entry_start, candidates, entry_second, surface_nodes, all_triangles,
                   c_tri_start, tri_v, tri_adj, tri_lv, lv_start, lv_face, normals_at, substep, face_n, edge_n,
                   corner_n, lv_n, lv_at, lo, hi, c_reach, c_motion, entry_closed, clear_x, clear_d, clear_m, c_sign,
                   c_pair, lam_n, contact_tri, contact_bary, contact_n, contact_loads):
    """``iterations`` sweeps of one substep (module docstring). Tool p: capsules ``capsule_start[p]:capsule_start[p +
    1]`` (rows a, b, radius), centre ``probe_centre[p]``, candidate nodes those within ``probe_margin[p]`` of its
    capsules at the substep's start (:func:`nodes_near_capsules`), loads ``probe_loads[p]``; grasp g: nodes, offsets and
    multipliers ``grasp_start[g]:grasp_start[g + 1]``, tool centre, ``alpha~``, its tool; plane k: point, normal, the
    nodes it acts on (a row of ``plane_acts``), its summed corrections ``plane_dn[k]``; then ``sim.contact_set``'s
    visited nodes (``project_entries``' arguments)."""
    x_start[:] = x
    sub = np.zeros(6)
    n_probes = probe_centre.shape[0]
    push_nodes, push_start = np.empty(n_probes * x.shape[0], np.int64), np.zeros(n_probes + 1, np.int64)
    for p in range(n_probes):
        near = nodes_near_capsules(x, w_tools, capsules[capsule_start[p]:capsule_start[p + 1]], probe_margin[p])
        push_nodes[push_start[p]:push_start[p] + near.size] = near
        push_start[p + 1] = push_start[p] + near.size
    for _ in range(iterations):
        blocked.gauss_seidel_blocked(x, node_index, params, lanes_used, colour_block, domain_colour, inv_dt2, mode, 1,
                                     n_threads)
        motion2 = 0.0
        if probe_centre.shape[0]:
            for i in range(x.shape[0]):
                motion2 = max(motion2, (x[i, 0] - x_start[i, 0]) ** 2 + (x[i, 1] - x_start[i, 1]) ** 2
                              + (x[i, 2] - x_start[i, 2]) ** 2)
        for p in range(probe_centre.shape[0]):
            sub[:] = 0.0
            nodes = push_nodes[push_start[p]:push_start[p + 1]]
            for k in range(capsule_start[p], capsule_start[p + 1]):
                if motion2 < probe_margin[p] * probe_margin[p]:
                    push_nodes_out_of_capsule(x, w_tools, nodes, capsules[k, 0:3], capsules[k, 3:6], capsules[k, 6],
                                              probe_centre[p], sub)
                else:
                    push_out_of_capsule_load(x, w_tools, capsules[k, 0:3], capsules[k, 3:6], capsules[k, 6],
                                             probe_centre[p], sub)
            for d in range(6):
                probe_loads[p, d] += sub[d]
        for g in range(grasp_alpha.size):
            a, b = grasp_start[g], grasp_start[g + 1]
            if a < b:
                _grasp_sweep(x, w, grasp_nodes[a:b], grasp_offsets[a:b], grasp_lam[a:b], grasp_centre[g],
                             grasp_alpha[g], probe_loads[grasp_probe[g]])
        for k in range(plane_point.shape[0]):
            project_onto_plane(x, w, plane_point[k], plane_normal[k], plane_acts[k], plane_dn[k], plane_loads[k])
        if entry_node.size:
            project_entries(x, w, x_start, static_x, n_nodes, entry_node, entry_contact, entry_hint, entry_start,
                            candidates, entry_second, surface_nodes, all_triangles, c_tri_start, tri_v, tri_adj, tri_lv,
                            lv_start, lv_face, normals_at, substep, face_n, edge_n, corner_n, lv_n, lv_at, lo, hi,
                            c_reach, c_motion, entry_closed, clear_x, clear_d, clear_m, c_sign, c_pair, lam_n,
                            contact_tri, contact_bary, contact_n, contact_loads)


class FusedSweeps:
    """Runs a substep's sweeps of an :class:`~sim.integrators.xpbd.solver.XPBD` in one call (:func:`substep_sweeps`);
    :meth:`covers` says whether it can. The planes' summed corrections become rows of one array (each
    ``PlaneState.dn`` a view of its row). :meth:`begin_step` finds the tools' capsules and centres at every
    substep of ``LOOKAHEAD`` steps at once (``Probe.capsule_rows``, the values one time at a time gives: each row is
    computed alone), used while the steps follow on at the same substep; the grasps' packed
    nodes, offsets and multipliers are kept while no grasp's nodes change (each ``GraspState.lam`` a view of its
    rows, zeroed at every substep)."""

    # steps whose tools' poses one begin_step computes: numpy's per-call overhead, not the rows, is what costs
    # (measured: docs/interaction.md, "Scalar closest points, the poses ahead, lists kept beyond the cap")
    LOOKAHEAD = 16

    @staticmethod
    def covers(xpbd, probes) -> bool:
        return (len(xpbd.sets) == 1 and xpbd.sets[0].blocks is not None and xpbd.strain_limits is None
                and xpbd.green_limits is None and xpbd.partial.empty
                and all(type(p).push_out is Probe.push_out for p in probes))  # capsules: not a mesh tool

    def __init__(self, xpbd):
        self.xpbd = xpbd
        n = xpbd.model.n_nodes
        planes = xpbd.planes
        self.plane_point = np.array([p.plane.point for p in planes], dtype=np.float64).reshape(-1, 3)
        self.plane_normal = np.array([p.plane.normal for p in planes], dtype=np.float64).reshape(-1, 3)
        self.plane_acts = np.ones((len(planes), n), dtype=np.bool_)
        self.plane_dn = np.zeros((len(planes), n))
        for k, p in enumerate(planes):
            if p.acts is not None:
                self.plane_acts[k] = p.acts
            p.dn = self.plane_dn[k]
        self.x_start = np.zeros((n, 3))
        self.grasps_packed = None  # (grasps and their nodes arrays, inv_dt2) the packed grasp arrays are of
        self.ahead = None  # (probes, h, substeps, step start times, capsules, centres, margins) of begin_step

    def begin_step(self, probes: list, t: float, h: float, substeps: int) -> None:
        """The capsules (substeps, capsules, 7), their ranges per tool, the tools' centres (substeps, tools, 3) and
        largest radii (substeps, tools) of ``probes`` at the substeps' ends of the step from ``t``: ``t + h``,
        ``t + h + h``, ... (the step's own sums). Computed for ``LOOKAHEAD`` steps on (the next starting where this
        one ends, as ``XPBD.step`` returns it) and kept while the steps come as foreseen."""
        self.probes = list(probes)
        ahead = self.ahead
        if (ahead is None or len(ahead[0]) != len(probes) or any(p is not q for p, q in zip(ahead[0], probes))
                or ahead[1] != h or ahead[2] != substeps or t not in ahead[3]):
            ends, starts = [t], []
            for _ in range(self.LOOKAHEAD):
                starts.append(ends[-1])
                for _ in range(substeps):
                    ends.append(ends[-1] + h)
            times = ends[1:]
            rows = [p.capsule_rows(times) for p in probes]
            n = len(times)
            capsules = np.ascontiguousarray(np.concatenate(rows, axis=1) if rows else np.zeros((n, 0, 7)))
            self.capsule_start = np.concatenate([[0], np.cumsum([r.shape[1] for r in rows])]).astype(np.int64)
            centres = np.ascontiguousarray(np.stack([p.positions_at(times) for p in probes], axis=1) if probes
                                           else np.zeros((n, 0, 3)))
            margins = np.ascontiguousarray(np.stack([r[:, :, 6].max(axis=1) if r.shape[1] else np.zeros(n)
                                                     for r in rows], axis=1) if rows else np.zeros((n, 0)))
            ahead = self.ahead = (list(probes), h, substeps, starts, capsules, centres, margins)
        k = ahead[3].index(t) * substeps
        self.capsules, self.centres, self.margins = (ahead[4][k:k + substeps], ahead[5][k:k + substeps],
                                                     ahead[6][k:k + substeps])

    def _tools(self, probes, s: int, t: float) -> tuple:
        """Capsules, their ranges, centres and margins of ``probes`` at substep s (ending at ``t``): the step's
        (:meth:`begin_step`) unless a probe was replaced for the substep (a cutting tool's shaft), then asked."""
        if len(probes) == len(self.probes) and all(p is q for p, q in zip(probes, self.probes)):
            return self.capsules[s], self.capsule_start, self.centres[s], self.margins[s]
        rows = [np.array([[*a, *b, r] for a, b, r in p.capsules(t)], dtype=np.float64).reshape(-1, 7)
                for p in probes]
        capsules = np.ascontiguousarray(np.concatenate(rows) if rows else np.zeros((0, 7)))
        start = np.concatenate([[0], np.cumsum([r.shape[0] for r in rows])]).astype(np.int64)
        centres = np.array([p.position(t) for p in probes], dtype=np.float64).reshape(-1, 3)
        margins = np.array([float(r[:, 6].max()) if r.size else 0.0 for r in rows], dtype=np.float64)
        return capsules, start, centres, margins

    def _pack_grasps(self, inv_dt2: float) -> None:
        grasps = self.xpbd.grasps
        key = ([(g, g.nodes) for g in grasps], inv_dt2)
        kept = self.grasps_packed
        if (kept is not None and kept[1] == inv_dt2 and len(kept[0]) == len(grasps)
                and all(g is h and nodes is h.nodes for (g, nodes), h in zip(kept[0], grasps))):
            return
        self.grasps_packed = key
        cat = lambda parts, shape, dtype=np.float64: (  # noqa: E731
            np.ascontiguousarray(np.concatenate(parts), dtype=dtype) if parts else np.zeros(shape, dtype))
        self.grasp_nodes = cat([g.nodes for g in grasps], (0,), np.int64)
        self.grasp_offsets = cat([g.offsets for g in grasps], (0, 3))
        self.grasp_lam = np.zeros((self.grasp_nodes.size, 3))
        self.grasp_start = np.concatenate([[0], np.cumsum([g.nodes.size for g in grasps])]).astype(np.int64)
        for g, a, b in zip(grasps, self.grasp_start[:-1], self.grasp_start[1:]):
            g.lam = self.grasp_lam[a:b]  # tear() reads the multipliers after the sweeps
        self.grasp_alpha = np.array([g.grasp.compliance * inv_dt2 for g in grasps], dtype=np.float64)
        self.grasp_probe = np.array([g.grasp.probe for g in grasps], dtype=np.int64)

    def run(self, x, w_tools, probes, s, t, inv_dt2, loads, plane_loads, contact_loads) -> None:
        """The sweeps of substep ``s`` of the step, ending at ``t``, after the prediction, the grasps' update and
        the contacts' broad phase."""
        xp = self.xpbd
        capsules, capsule_start, centres, margins = self._tools(probes, s, t)
        self._pack_grasps(inv_dt2)
        self.grasp_lam[:] = 0.0
        tools = self.probes
        grasp_centre = np.array([self.centres[s, g.grasp.probe] if g.grasp.probe < len(tools)
                                 and g.probe is tools[g.grasp.probe] else g.probe.position(t) for g in xp.grasps],
                                dtype=np.float64).reshape(-1, 3)
        node_index, params, lanes_used, colour_block = xp.sets[0].blocks
        cs = xp.contact_set
        substep_sweeps(
            x, xp.w, w_tools, self.x_start, inv_dt2, xp.iterations, node_index, params,
            lanes_used, colour_block, xp.domain_colour, xp.mode, numba.get_num_threads(), capsules, capsule_start,
            centres, margins, loads, self.grasp_nodes, self.grasp_offsets, self.grasp_lam, self.grasp_start,
            grasp_centre, self.grasp_alpha, self.grasp_probe, self.plane_point, self.plane_normal, self.plane_acts,
            self.plane_dn, plane_loads, cs.static_x, cs.n_nodes, cs.entry_node, cs.entry_contact, cs.entry_hint,
            cs.entry_start, cs.candidates, cs.entry_second, cs.surface_nodes, cs.all_triangles, cs.c_tri_start,
            cs.tri_v, cs.tri_adj, cs.tri_lv, cs.lv_start, cs.lv_face, cs.normals_at, cs.substep, cs.face_n, cs.edge_n,
            cs.corner_n, cs.lv_n, cs.lv_at, cs.lo, cs.hi, cs.c_reach, cs.c_motion, cs.entry_closed, cs.clear_x,
            cs.clear_d, cs.clear_m, cs.c_sign, cs.c_pair, cs.lam_n, cs.tri, cs.bary, cs.normal, contact_loads)
