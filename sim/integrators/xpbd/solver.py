"""XPBD (Macklin et al. 2016; Qian §4.4, eqs. 4.36–4.44) with stable Neo-Hookean tet constraints
(Macklin & Müller 2021).

Per tet, with ``F = Ds Dm^-1``, two constraints with compliances from the Lamé parameters:

- deviatoric ``C_D = ||F||_F`` (``dC/dF = F / ||F||``), compliance ``1 / (mu V)``;
- hydrostatic ``C_H = det F - gamma``, ``gamma = 1 + mu / lam`` (the rest-stability shift),
  ``dC/dF = cof F``, compliance ``1 / (lam V)``.

Each substep: predict ``x* = x + dt v + dt^2 M^-1 f_ext``; reset the multipliers; for every
iteration, for every colour (tets sharing no node; the colours of separate domains' interiors are
swept concurrently, ``sim.integrators.xpbd.colouring.split_into_domains``, and a colour's tets are projected in
vectorised blocks, ``sim.integrators.xpbd.blocked``), project
``dlambda = (-C - alpha~ lambda) / (sum_i w_i |grad_i C|^2 + alpha~)``, ``alpha~ = alpha / dt^2``,
``x_i += w_i grad_i C dlambda`` (Qian 4.42–4.44; its eq. 4.22 gradient typo: docs/design.md, "Qian 4.22: strain-constraint gradient");
then tool contact, grasp attachments and static contact planes (``sim.contact``; Coulomb friction once after the
sweeps), then the nodes held in some components only are projected back onto their constraint
(``sim.model.PartialTargets``), then ``v = (x - x_prev) / dt``. Tools, grasps, planes and surface contacts without
the per-sweep extras run a substep's sweeps in one compiled call (``sim.integrators.xpbd.sweeps``, same result).
``tool_loads``: the force and torque the tissue exerted on each probe over the last step (minus the contact impulses
over the step, ``sim.probe``). The ``jacobi`` solver averages the corrections of all tets per iteration (with
relaxation) instead.

Cuts (``sim.cutting``): at the start of a substep the tets an active blade sweeps through are removed: their
constraints stop acting at once, and the per-tet data is filtered at the end of the step
(``sim.integrators.xpbd.removal``); a cutting tool's blade pushes no tissue.

Strain limits on Green-strain entries in a material frame (Qian 4.21–4.22, stretch and shear,
unilateral or held) are projected after every sweep (``sim.integrators.xpbd.strain``). Prony viscoelasticity
(Zhang 5.29–5.32) adds one constraint set per Prony term whose rest shape drifts towards the current
stretch after every step (generalised Maxwell branches, ``sim.integrators.xpbd.prony``).
"""
from __future__ import annotations

import numba
import numpy as np

from sim.constitutive import models
from sim.errors import SimulationDiverged
from sim.integrators.xpbd import blocked, kernels
from sim.integrators.xpbd.colouring import colour_tets, split_into_domains
from sim.integrators.xpbd.sweeps import FusedSweeps
from sim.integrators.xpbd.energy import EnergyConstraints
from sim.integrators.xpbd.prony import MaxwellBranches
from sim.integrators.xpbd.removal import TetRemoval
from sim.integrators.xpbd.settings import XPBDSettings, limit_boxes
from sim.integrators.xpbd.strain import GreenStrainLimits
from sim.contact import GraspState, PlaneState
from sim.cutting import Cutter
from sim.contact_bodies import SurfaceContactState
from sim.contact_set import ContactSet
from sim.model import Model, State
from sim.probe import resolve_contact_load


class TetConstraints:
    """One set of per-tet elastic constraints in colour order: the body's tets, or one Prony branch
    (rest matrix ``Dm^-1 Fv^-1``, energy weighted by ``weight``). Holds its compliances, multipliers
    and, for the blocked kernel, its block layout."""

    def __init__(self, xpbd: "XPBD", Dm_inv: np.ndarray, weight: float):
        self.xpbd = xpbd
        self.weight = weight
        m = xpbd.model
        order = xpbd.tet_order
        mu, lam, volume = m.mu[order], m.lam[order], m.volume[order]
        self.alpha_dev = 1.0 / (weight * mu * volume)
        # lam = 0 (nu = 0, only with material = "model": the constraints below need nu > 1/8, XPBD.__init__): the
        # hydrostatic set is unused, kept finite
        has_lam = lam > 0.0
        self.alpha_hyd = np.where(has_lam, 1.0 / (weight * np.where(has_lam, lam, 1.0) * volume), 1e30)
        self.gamma = np.where(has_lam, 1.0 + mu / np.where(has_lam, lam, 1.0), 1.0)
        self.lam_dev = np.zeros(m.n_tets)  # multipliers (lam_dev alone for the model's energy)
        self.lam_hyd = np.zeros(m.n_tets)
        self.energy = None
        self.blocks = None
        self.set_rest(Dm_inv)

    def set_rest(self, Dm_inv: np.ndarray) -> None:
        """New rest matrices (a Prony branch after its drift)."""
        x = self.xpbd
        self.Dm_inv = np.ascontiguousarray(Dm_inv)
        if x.material == "model":
            self.energy = EnergyConstraints(x.model, x.tet_order, x.colour_start, self.Dm_inv, self.weight,
                                            x.energy_kernel)
        elif x.solver == "gauss_seidel" and x.kernel == "blocked":
            self.blocks = blocked.pack_blocks(x.tets, self.Dm_inv, x.w, self.alpha_dev, self.alpha_hyd, self.gamma,
                                              x.colour_start)

    def reset(self) -> None:
        self.lam_dev[:] = 0.0
        self.lam_hyd[:] = 0.0
        if self.blocks is not None:
            blocked.reset_multipliers(self.blocks[1])

    def sweeps(self, x: np.ndarray, inv_dt2: float, iterations: int) -> None:
        xp = self.xpbd
        if self.energy is not None:  # the model's own energy, C = sqrt(2 V Psi)
            self.energy.sweeps(x, self.lam_dev, xp.w, inv_dt2, iterations)
            return
        if self.blocks is not None:
            node_index, params, lanes_used, colour_block = self.blocks
            blocked.gauss_seidel_blocked(x, node_index, params, lanes_used, colour_block, xp.domain_colour,
                                         inv_dt2, xp.mode, iterations, numba.get_num_threads())
            return
        args = (x, xp.tets, self.Dm_inv, xp.w, self.alpha_dev, self.alpha_hyd, self.gamma, self.lam_dev,
                self.lam_hyd, inv_dt2, xp.mode)
        if xp.solver == "gauss_seidel":
            kernels.gauss_seidel(*args, xp.colour_start, iterations)
        else:
            kernels.jacobi(*args, xp.tet_scale, iterations)


class XPBD:
    """XPBD integrator. Parameters: :class:`sim.integrators.xpbd.settings.XPBDSettings` (its module docstring is
    the parameter table: name, default, unit, range, equation). ``kernel = "blocked"`` projects the tets of a colour
    16 at a time by a vectorised loop, ``"scalar"`` is the per-tet reference ``project_tet`` (same positions up to
    rounding); ``domains`` slabs have their interiors swept concurrently, one per thread, before the separator
    layer between them (the result does not depend on the threads used). A model with Prony terms
    (``material_params["prony"]``) gets one more constraint set per term (``sim.integrators.xpbd.prony``)."""

    name = "xpbd"
    tool_loads: np.ndarray | None = None  # (probes, 6): force [N] and torque [N m] on each tool, last step
    plane_loads: np.ndarray | None = None  # (planes, 6): force [N], torque about its point [N m] on each plane, last step
    contact_loads: np.ndarray | None = None  # (pairs, 6): force [N] and torque [N m] on each contact pair's second member

    def __init__(self, model: Model, settings: XPBDSettings | dict | None = None):
        settings = XPBDSettings.of(settings)
        self.settings = settings
        self.model = model
        self.substeps = settings.substeps
        self.iterations = settings.iterations
        self.solver = settings.solver
        self.relaxation = settings.relaxation
        self.damping = settings.damping
        coupling = settings.coupling or ("coupled" if settings.coupled else "sequential")
        smin, smax = settings.strain_min, settings.strain_max
        self.strain_limits = None if smin is None and smax is None else (
            0.0 if smin is None else float(smin), np.inf if smax is None else float(smax))
        self.mode = 1 if coupling == "coupled" else 0
        self.material = settings.material
        if self.material != "model":
            models.require_stable_rest(model, 'xpbd\'s stable Neo-Hookean constraints (material = "stable_neo_hookean")')
        self.kernel = settings.kernel
        # material = "model": "numba" (default where the material has one) or "numpy" (sim.integrators.xpbd.energy)
        self.energy_kernel = settings.energy_kernel
        m = model
        # Per-tet data is stored in colour order, so each colour is a contiguous range read sequentially:
        # the colours of each domain's interior, then the separator's (see split_into_domains).
        self.domains = settings.domains
        tets = np.ascontiguousarray(m.tets, dtype=np.int64)
        colours, domain_colour = [], [0]
        for part in split_into_domains(m.X, tets, self.domains):
            if part.size:
                colours += [part[c] for c in colour_tets(tets[part], m.n_nodes)]
            domain_colour.append(len(colours))
        self.domain_colour = np.array(domain_colour, dtype=np.int64)
        order = np.concatenate(colours).astype(np.int64)
        colour_start = np.concatenate([[0], np.cumsum([c.size for c in colours])]).astype(np.int64)
        prony = m.material_params.get("prony")
        self.branches = MaxwellBranches(prony, np.ascontiguousarray(m.tets[order], dtype=np.int64),
                                        np.ascontiguousarray(m.Dm_inv[order])) if prony else None
        self.kinematic = m.kinematic()
        self.partial = m.partial()  # nodes held in some components: projected onto their constraint after each sweep
        self._build_tets(order, colour_start)
        # grasps and static contact planes (sim.contact), optional attributes of the model
        self.grasps = [GraspState(g, m.probes[g.probe]) for g in getattr(m, "grasps", ())]
        self.planes = [PlaneState(p, m.n_nodes) for p in getattr(m, "contact_planes", ())]
        # contact with triangle surfaces: other bodies of a merged model, static meshes (sim.contact_bodies)
        self.contacts = [SurfaceContactState(c, m.X) for c in getattr(m, "contacts", ())]
        self.contact_set = ContactSet(self.contacts, m.n_nodes)  # their broad and narrow phases (sim.contact_set)
        self.contact_pairs = max((c.pair + 1 for c in getattr(m, "contacts", ())), default=0)
        # cuts (sim.cutting), an optional attribute of the model: tets removed at the start of a substep
        self.cutter = Cutter(m) if getattr(m, "cuts", ()) else None
        self.removal = TetRemoval(self) if self.cutter is not None else None
        self.fused = None  # sim.integrators.xpbd.sweeps.FusedSweeps, made at the first step that can use it

    def _build_tets(self, order: np.ndarray, colour_start: np.ndarray) -> None:
        """Everything per tet or per mass, from the model's tets in colour order ``order`` (ranges ``colour_start``)."""
        m, settings = self.model, self.settings
        self.tet_order = order
        self.colour_start = colour_start
        self.tets = np.ascontiguousarray(m.tets[order], dtype=np.int64)
        self._per_node()
        # constraint sets: the body's tets (long-term weight 1 - sum a_i with Prony terms), then one
        # set per Prony branch (sim.integrators.xpbd.prony)
        self.sets = [TetConstraints(self, weight_B[1], weight_B[0]) for weight_B in (
            self.branches.sets() if self.branches is not None else [(1.0, m.Dm_inv[order])])]
        base = self.sets[0]
        self.Dm_inv, self.alpha_dev, self.alpha_hyd, self.gamma = base.Dm_inv, base.alpha_dev, base.alpha_hyd, base.gamma
        self.blocks, self.energy = base.blocks, base.energy
        if self.strain_limits is not None:
            # limited axes: the rest frame's x, y, z and, for fibred materials, the fibre (Qian 4.3.4)
            axes = [np.broadcast_to(np.eye(3)[k], (m.n_tets, 3)) for k in range(3)]
            if m.fibre is not None:
                axes.append(m.fibre)
            self.limit_axes = np.ascontiguousarray(
                np.stack([np.einsum("mij,mj->mi", m.Dm_inv, a) for a in axes], axis=1)[order])
        self.green_limits = (GreenStrainLimits(m, order, self.colour_start, settings)
                             if limit_boxes(settings) is not None else None)

    def _per_node(self) -> None:
        """Inverse masses, the external-force accelerations and (``solver = "jacobi"``) the per-tet relaxation, from
        the model's masses and the tets in colour order (again after a cut, ``sim.integrators.xpbd.removal``)."""
        m = self.model
        self.w = m.inverse_mass()
        self.tet_scale = np.zeros(0)
        if self.solver == "jacobi" and self.tets.size:
            counts = np.bincount(self.tets.ravel(), minlength=m.n_nodes).astype(np.float64)
            self.tet_scale = self.relaxation / counts[self.tets].max(axis=1)
        self.f_ext_acc = m.nodal_external_force() * np.where(self.w > 0, self.w, 0.0)[:, None]

    def step(self, state: State, dt: float) -> State:
        m = self.model
        h = dt / self.substeps
        inv_dt2 = 1.0 / (h * h)
        x = state.x.copy()
        v = state.v.copy()
        t = state.t
        # with probes, limits or several constraint sets, those are visited after every sweep; else
        # one kernel call does all the iterations
        per_sweep = (bool(m.probes) or self.strain_limits is not None or self.green_limits is not None
                     or not self.partial.empty or bool(self.planes) or bool(self.contacts))
        per_call = 1 if per_sweep or len(self.sets) > 1 else self.iterations
        fused = None
        if per_sweep and FusedSweeps.covers(self, m.probes):
            if self.fused is None:
                self.fused = FusedSweeps(self)
            fused = self.fused
        loads = np.zeros((len(m.probes), 6))  # per probe: sum of m dx and its moment, over this step
        substep_load = np.zeros(6)
        plane_loads = np.zeros((len(self.planes), 6))
        contact_loads = np.zeros((self.contact_pairs, 6))
        if fused is not None:  # the tools' capsules at every substep's end at once
            fused.begin_step(m.probes, t, h, self.substeps)
        for s in range(self.substeps):
            t_next = t + h
            if self.cutter is not None:  # the blades remove the tets they sweep through over this substep
                removed = self.cutter.sweep(x, t, t_next)
                if removed is not None:
                    self.removal.remove(removed)
                    v[self.model.mass == 0.0] = 0.0  # orphan nodes (in no tet) stay where they are
            x_prev = x.copy()
            x += h * v + h * h * self.f_ext_acc
            x[self.kinematic.nodes] = self.kinematic.at(t_next)
            self.partial.place(x, t_next)
            for constraints in self.sets:
                constraints.reset()
            if self.green_limits is not None:
                self.green_limits.reset()
            w_tools = self.w
            for grasp in self.grasps:
                grasp.update(x_prev, self.w, t, t_next)
                grasp.reset()
            if any(g.nodes.size for g in self.grasps):  # grasped nodes follow the jaws, not pushed out of them
                w_tools = self.w.copy()
                for grasp in self.grasps:
                    w_tools[grasp.nodes] = 0.0
            for plane in self.planes:
                plane.reset()
            probes = m.probes if self.cutter is None else self.cutter.contact_probes(m.probes, t, t_next)
            if self.contacts:
                self.contact_set.begin(x)
            if fused is not None:  # every sweep in one compiled call (sim.integrators.xpbd.sweeps)
                fused.run(x, w_tools, probes, s, t_next, inv_dt2, loads, plane_loads, contact_loads)
            for _ in range(0 if fused is not None else self.iterations // per_call):
                for constraints in self.sets:
                    constraints.sweeps(x, inv_dt2, per_call)
                if self.strain_limits is not None:
                    kernels.strain_limit(x, self.tets, self.limit_axes, self.w, *self.strain_limits,
                                         self.colour_start)
                if self.green_limits is not None:
                    self.green_limits.project(x, self.w, inv_dt2)
                for k, probe in enumerate(probes):
                    substep_load[:] = 0.0
                    resolve_contact_load(x, probe, t_next, w_tools, substep_load)
                    loads[k] += substep_load
                for grasp in self.grasps:
                    grasp.project(x, self.w, t_next, inv_dt2, loads[grasp.grasp.probe])
                for k, plane in enumerate(self.planes):
                    plane.project(x, self.w, plane_loads[k])
                self.contact_set.project(x, self.w, contact_loads)
                # a zero-compliance constraint on the held components, projected last in each sweep (Gauss-Seidel):
                # the converged state is XPBD's with the generalised inverse mass P / m on these nodes
                self.partial.place(x, t_next)
            for k, plane in enumerate(self.planes):
                plane.friction(x, x_prev, self.w, plane_loads[k])
            self.contact_set.friction(x, x_prev, self.w, contact_loads)
            if self.planes or self.contacts:
                self.partial.place(x, t_next)
            for grasp in self.grasps:
                grasp.tear(inv_dt2)
            v = (x - x_prev) / h
            if self.damping > 0.0:
                v *= np.exp(-self.damping * h)
            t = t_next
        if self.removal is not None:  # the step's removals filtered out of the per-tet data
            self.removal.compact()
        if not np.isfinite(x).all():
            raise SimulationDiverged(f"xpbd: non-finite positions at t = {t:.6g} s")
        # the force and torque the tissue exerts on each tool, averaged over the step: minus the contact impulses
        # m dx / h of every substep, divided by the step (sum over substeps of (m dx / h^2) h / dt)
        self.tool_loads = -loads / (h * dt)
        self.plane_loads = -plane_loads / (h * dt)
        self.contact_loads = contact_loads / (h * dt)  # the SurfaceContact signs give the force on the second member
        if self.branches is not None:
            self.branches.relax(x, dt)
            for constraints, (_, rest) in zip(self.sets[1:], self.branches.sets()[1:]):
                constraints.set_rest(rest)
        return State(x=x, v=v, t=t, private=state.private)
