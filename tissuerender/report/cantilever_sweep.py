"""The integrators on the large-deflection cantilever (issue 17 item 1): the solver's error apart from the mesh's.

The beam of ``sim.cases.cantilever`` (2 x 0.2 x 0.2 m, E 1 MPa, nu 0.3, rho 1000 kg/m^3, the face x = 0 fixed,
gravity -z; Neo-Hookean 5.35) at one mesh level, on linear tets. Its reference is the quasi-static Newton
equilibrium **on the same mesh** (relative gradient 1e-8, gravity ramped in ``load_steps`` increments), so every
error below is the integrator's own; the mesh's error against the mesh-converged beam is the ``cantilever`` case
(``discretisation.py``). Full gravity bends the beam far: its tip comes down 1.54 m at level 1.

Every integrator is run as a scene runs it: gravity switched on at t = 0 on the body at rest, stepped for
``settle_s`` simulated seconds with damping so it comes to rest (the swing overshoots the static shape first), and
measured at the end:

- ``xpbd`` over substeps x iterations (``material = "model"``, the same energy; velocity decay ``damping`` 1/s);
- ``explicit`` (forward Euler, Zhang 5.12) and ``cnn`` over dt, with Rayleigh damping
  ``D = alpha M + beta K``. Forward Euler grows every undamped mode; stiffness damping holds the stiff ones only if
  ``dt < beta`` for the modes it leaves underdamped and ``dt < 2 / (beta omega^2)`` for those it overdamps, so
  ``beta`` is small (1e-3 s) and the steps below 1e-3 s;
- ``ebm`` over iterations, at 8 steps a second: external forces act through its prediction only (docs/ebm.md,
  "Loads"), so it is expected to fail this force-loaded case, and a failure is reported, not hidden;
- ``cnn_chainmail`` is geometric and refuses gravity: the case records its refusal as "not applicable".

Measures per setting (``measure.mesh_point``): relative L2 displacement error, Zhang's line errors of u_z along the
beam's top edge (y = 0, z = 0.2 m, present at every level), the **tip deflection** (``-mean u_z`` of the end face,
as ``sim.cases.cantilever``) and its relative error, against wall time per simulated second.

Reference check: the equilibrium solved again along another load path (twice the increments) at a hundred times
tighter tolerance. (The order check of the Zhang cases, backward Euler released from the equilibrium plus a bump,
is not used here: on this stiff beam, E 1 MPa, the bump excites axial and shear modes whose differences stay
pre-asymptotic at steps a run can afford, observed orders -0.8 to 0.7 at steps of 0.005-0.05 s.)
"""
from __future__ import annotations

import time

import numpy as np

from sim.cases.cantilever import LENGTH, SIDE, cantilever_model
from sim.cases.zhang import Case, relative_l2
from sim.integrators.reference import ReferenceIntegrator
from sim.mesh import select
from tissuerender.report.measure import mesh_point, pareto_front, refusal
from tissuerender.report.pictures import error_fields

CASE = "cantilever_integrators"
COMPONENT = 2  # u_z, the deflection
DAMPED = {"rayleigh_alpha": 3.0, "rayleigh_beta": 1.0e-3}  # [1/s], [s]: see the module docstring

SWEEPS = {
    "full": {"level": 1, "load_steps": 8, "settle_s": 8.0, "xpbd_dt": 0.05, "xpbd_damping": 2.0,
             "xpbd": [[2, 10], [5, 5], [5, 20], [10, 20], [20, 20], [20, 50]],
             "explicit_dts": [0.00025, 0.0005], "cnn_dts": [0.00025, 0.0005], "cnn_Ks": [4.0, 100.0],
             "ebm": [20, 100]},
    "quick": {"level": 0, "load_steps": 8, "settle_s": 8.0, "xpbd_dt": 0.05, "xpbd_damping": 2.0,
              "xpbd": [[5, 5], [10, 20], [20, 20]], "explicit_dts": [0.0005], "cnn_dts": [0.0005], "cnn_Ks": [4.0],
              "ebm": [20]},
    # the test suite's: the 60-tet beam for 4 s
    "tiny": {"level": 0, "load_steps": 8, "settle_s": 4.0, "xpbd_dt": 0.05, "xpbd_damping": 2.0,
             "xpbd": [[5, 5], [20, 20]], "explicit_dts": [0.0005], "cnn_dts": [], "cnn_Ks": [4.0],
             "ebm": [20]},
}


def work_units(sweep: dict) -> int:
    return 3 + len(sweep["xpbd"]) + len(sweep["explicit_dts"]) + len(sweep["cnn_dts"]) * len(sweep["cnn_Ks"]) \
        + len(sweep["ebm"])


def cantilever_case(level: int) -> Case:
    """The beam at ``level`` as a report mesh case: its top edge (y = 0, z = SIDE) is the measurement line."""
    model = cantilever_model(level, False)
    on_edge = np.flatnonzero((np.abs(model.X[:, 1]) <= 1e-9) & (np.abs(model.X[:, 2] - SIDE) <= 1e-9))
    line = on_edge[np.argsort(model.X[on_edge, 0])]
    return Case(CASE, model, line, model.X[line, 0], 0.0, component=COMPONENT)


def equilibrium(model, load_steps: int, tol: float = 1e-8) -> np.ndarray:
    """The quasi-static Newton equilibrium under the model's gravity, ramped in ``load_steps`` equal increments
    (``tol``: the relative gradient norm each solve reaches)."""
    solver = ReferenceIntegrator(model, {"mode": "quasistatic", "tol": tol})
    gravity = model.gravity.copy()
    x = model.X.copy()
    try:
        for k in range(1, load_steps + 1):
            model.gravity = gravity * (k / load_steps)
            x = solver.solve(x, None, 1.0, 0.0)
    finally:
        model.gravity = gravity
    return x


def tip_deflection(model, u: np.ndarray) -> float:
    """``-mean u_z`` over the end face x = L [m]."""
    return -float(u[select.nodes_on_side(model.X, 0, "max"), 2].mean())


def reference_convergence(model, x_ref: np.ndarray, sweep: dict) -> dict:
    """The reference's equilibrium solved again with twice the load increments and a hundred times tighter Newton
    tolerance: a hyperelastic equilibrium does not depend on the load path, so the difference is what the
    reference's own tolerance leaves (module docstring)."""
    x_tight = equilibrium(model, 2 * sweep["load_steps"], tol=1e-10)
    difference = relative_l2(x_ref - model.X, x_tight - model.X)
    return {"what": f"the equilibrium again with {2 * sweep['load_steps']} load increments at relative gradient "
                    f"1e-10: relative L2 difference of the displacement", "relative_difference": difference,
            "tip_difference_m": abs(tip_deflection(model, x_ref - model.X) - tip_deflection(model, x_tight - model.X))}


def run_cantilever_integrators(sweep: dict, tick=lambda: None) -> dict:
    case = cantilever_case(sweep["level"])
    model = case.model
    start = time.perf_counter()
    x_ref = equilibrium(model, sweep["load_steps"])
    reference_s = time.perf_counter() - start
    u_ref = x_ref - model.X
    tip_ref = tip_deflection(model, u_ref)
    tick()
    settle = sweep["settle_s"]
    runs = [("xpbd", f"{s}x{i}", {"substeps": s, "iterations": i, "damping": sweep["xpbd_damping"],
                                   "material": "model"}, sweep["xpbd_dt"]) for s, i in sweep["xpbd"]]
    runs += [("explicit", f"dt {dt:g}", dict(DAMPED), dt) for dt in sweep["explicit_dts"]]
    runs += [("cnn", f"dt {dt:g}, K {K:g}", {**DAMPED, "K": K}, dt) for K in sweep["cnn_Ks"] for dt in sweep["cnn_dts"]]
    runs += [("ebm", f"{it} it", {"iterations": it}, 1.0 / 8.0) for it in sweep["ebm"]]
    points = []
    for name, label, settings, dt in runs:
        point = mesh_point(name, label, settings, case, u_ref, COMPONENT, dt, int(round(settle / dt)))
        if "_u" in point:
            point["tip_m"] = tip_deflection(model, point["_u"])
            point["tip_rel_error"] = abs(point["tip_m"] - tip_ref) / tip_ref
        points.append(point)
        tick()
    fields = error_fields(model, points, u_ref)
    convergence = reference_convergence(model, x_ref, sweep)
    tick()
    refused = {"cnn_chainmail": refusal("cnn_chainmail", model)}
    tick()
    measures = {"reference_tip_m": tip_ref}
    for name in ("xpbd", "explicit", "cnn", "ebm"):
        ok = [p for p in points if p["integrator"] == name and p["diverged"] is None]
        measures[f"{name}_best_rel_l2"] = min((p["rel_l2"] for p in ok), default=float("nan"))
        measures[f"{name}_failed"] = sum(1 for p in points if p["integrator"] == name and p["diverged"] is not None)
    return {"case": CASE, "title": f"The integrators on the large-deflection cantilever (level {sweep['level']}, "
                                   f"{model.n_tets} tets, against the reference on the same mesh)",
            "error_key": "rel_l2", "error_label": "relative L2 displacement error [-] after "
                                                  f"{settle:g} s under gravity switched on at rest",
            "mesh": {"nodes": int(model.n_nodes), "tets": int(model.n_tets), "level": sweep["level"]},
            "reference": {"kind": f"quasi-static Newton on the same mesh, relative gradient 1e-8, gravity in "
                                  f"{sweep['load_steps']} increments", "wall_s": reference_s, "tip_m": tip_ref,
                          "line_component": "z", "line_peak_m": float(np.abs(u_ref[case.line, COMPONENT]).max()),
                          "line_coord_m": case.line_coord.tolist(), "line_u_m": u_ref[case.line, COMPONENT].tolist()},
            "not_applicable": {k: v for k, v in refused.items() if v is not None},
            "convergence": convergence, "points": points, "pareto": pareto_front(points, "rel_l2"),
            "measures": measures, "error_fields": fields}
