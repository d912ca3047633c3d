"""Force against indentation (issue 21 item 5): a rigid sphere indents a block quasi-statically; XPBD's tool force
(``sim.probe.resolve_contact_load`` through ``XPBD.tool_loads``) against the reference integrator's reaction, at
several depths.

Setup (``tests/test_tool_forces.py`` has its 5 mm case): a 10 cm cube (``cells`` per side, stable Neo-Hookean,
E = 10 kPa, nu = 0.3, rho = 1,000 kg/m^3, no gravity) clamped on its bottom face; a sphere of radius R = 0.2 m
over the centre of the top face moves down by ``depth`` over ``ramp_s`` and holds, XPBD (``substeps`` x
``iterations``, damping 10/s) running ``steps`` steps of ``dt`` in all, so the block settles (quasi-static). The
force is ``tool_loads`` of the last step (z component: the tissue pushes the tool up).

Reference: the nodes the sphere touches at the end (within 1e-6 m of its surface) prescribed at XPBD's positions
for them, every other free node solved by the quasi-static Newton reference (relative gradient 1e-8); the
reaction is the sum of the internal elastic forces at the touched nodes (``sim.constitutive.elastic``): the force
the tissue exerts on whatever holds those nodes where they are. So the comparison isolates the force's measure
(contact impulses of a not fully converged XPBD against the equilibrium's reaction) from the contact set (taken
from XPBD's run); frictionless contact puts no tangential constraint on the touched nodes in XPBD, while the
reference holds them in all three components, which the lateral force components (both ~0 by symmetry) show.
"""
from __future__ import annotations

import time

import numpy as np

from sim.constitutive import elastic
from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State
from sim.probe import Probe

SIZE_M = 0.1
RADIUS_M = 0.2
SWEEPS = {
    "full": {"depths_mm": [1.0, 2.5, 5.0, 10.0, 15.0, 20.0], "cells": 6, "substeps": 10, "iterations": 100,
             "dt": 0.01, "steps": 80, "ramp_s": 0.3},
    "quick": {"depths_mm": [1.0, 2.5, 5.0, 7.5, 10.0, 15.0], "cells": 4, "substeps": 10, "iterations": 50, "dt": 0.02,
              "steps": 40, "ramp_s": 0.3},
    "tiny": {"depths_mm": [2.5, 5.0, 10.0], "cells": 4, "substeps": 10, "iterations": 20, "dt": 0.02, "steps": 30,
             "ramp_s": 0.2},
}


def _block(cells: int) -> tuple:
    mesh = procedural.box((SIZE_M, SIZE_M, SIZE_M), (cells, cells, cells))
    model = Model.from_mesh(mesh, E=1e4, nu=0.3, density=1000.0, constitutive="stable_neo_hookean")
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    return mesh, model


def indent(depth_m: float, sweep: dict) -> dict:
    """One depth: XPBD's tool force, the reference reaction at the touched nodes, and the cost."""
    mesh, model = _block(sweep["cells"])
    top = [SIZE_M / 2, SIZE_M / 2, SIZE_M + RADIUS_M]
    bottom = [top[0], top[1], top[2] - depth_m]
    model.probes = [Probe("sphere", RADIUS_M, [0.0, sweep["ramp_s"], 2.0 * sweep["ramp_s"]], [top, bottom, bottom])]
    settings = {"substeps": sweep["substeps"], "iterations": sweep["iterations"], "damping": 10.0}
    integrator = make_integrator("xpbd", model, settings)
    state = State.at_rest(model)
    start = time.perf_counter()
    for _ in range(sweep["steps"]):
        state = integrator.step(state, sweep["dt"])
    xpbd_s = time.perf_counter() - start
    force = integrator.tool_loads[0, :3]
    distance = np.linalg.norm(state.x - model.probes[0].position(state.t), axis=1)
    contact = np.flatnonzero(distance < RADIUS_M + 1e-6)

    _, reference_model = _block(sweep["cells"])
    reference_model.prescribed = [PrescribedDisplacement(np.array([i]), state.x[i] - mesh.points[i]) for i in contact]
    reference = make_integrator("reference", reference_model, {"mode": "quasistatic"})
    start = time.perf_counter()
    x = reference.step(State(x=state.x.copy(), v=np.zeros_like(state.x)), 1.0).x
    reference_s = time.perf_counter() - start
    reaction = elastic.elastic_forces(reference_model, x)[contact].sum(axis=0)
    return {"depth_mm": 1e3 * depth_m, "contact_nodes": int(contact.size), "xpbd_force_N": force.tolist(),
            "reference_force_N": reaction.tolist(), "xpbd_fz_N": float(force[2]), "reference_fz_N": float(reaction[2]),
            "relative_difference": float(force[2] / reaction[2] - 1.0) if reaction[2] != 0.0 else float("nan"),
            "xpbd_wall_s": xpbd_s, "reference_wall_s": reference_s}


def run_indentation(sweep: dict, tick=lambda: None) -> dict:
    rows = []
    for depth in sweep["depths_mm"]:
        rows.append(indent(1e-3 * depth, sweep))
        tick()
    diffs = [abs(r["relative_difference"]) for r in rows]
    return {"case": "indentation", "title": "force against indentation: a sphere pressing a block (issue 21 item 5)",
            "setup": {"block_m": SIZE_M, "sphere_radius_m": RADIUS_M, "E_Pa": 1e4, "nu": 0.3,
                      "constitutive": "stable_neo_hookean", **sweep},
            "rows": rows,
            "measures": {"max_abs_relative_difference": max(diffs),
                         "smallest_depth_relative_difference": rows[0]["relative_difference"],
                         "force_rises_with_depth": all(b["xpbd_fz_N"] > a["xpbd_fz_N"] for a, b in zip(rows, rows[1:]))}}


def work_units(sweep: dict) -> int:
    return len(sweep["depths_mm"])

