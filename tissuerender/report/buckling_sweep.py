"""A hard case swept like Zhang's (issue 17 item 1): the compressed cylinder with a sliding face, which buckles.

``sim.cases.buckling``: Zhang's cylinder (2 m, r 0.5 m, E 3000 Pa, nu 0.49, Neo-Hookean 5.35), the left face fixed,
the right face a roller pressed 0.4 m along the axis over 1 s (free to slide sideways, not to turn), a 0.01 N
lateral load at mid-span as the imperfection. Euler's fixed-guided column buckles at about 0.31 m of compression,
so the end of the load is past the critical point and the column has gone sideways.

Two references, both the quasi-static Newton path of ``sim.cases.buckling.buckling_path`` (relative gradient 1e-8,
``load_steps`` increments, so the path follows the imperfection's branch):

- **on the integrators' own elements** (linear tets without average nodal pressure): what every integrator below
  should reach, so its error is its own; the integrators' errors are against this one;
- **with average nodal pressure** (ANP): the physically meaningful column (plain linear tets at nu = 0.49 lock in
  bending), reported for its critical compression (the smallest eigenvalue of the reduced tangent stiffness
  crossing zero) and deflection: how far the integrators' elements are from the column itself.

Swept as the Zhang cases (``cases.run_mesh``'s settings): ``xpbd`` substeps x iterations, ``ebm`` iterations over 8
load steps, ``explicit`` and ``cnn`` over dt with Rayleigh damping, ``cnn_chainmail`` over alpha; the dynamic ones
run ``settle_s`` s. Measures per setting: relative L2 of the displacement, the line errors of u_x along the
cylinder's surface line, the loaded face's **sideways deflection** against the reference's, both again against the
ANP path's end (``rel_l2_anp``, ``sideways_rel_error_anp``: the column itself, locking included), and **stability**:
failures an integrator detects (an inverted element, non-finite positions) recorded as such, and at the end of a
finished run whether its positions are finite and how many tets are inverted (signed volume <= 0; ``stable``: finite
and none), so an integrator that does not check is checked here.
"""
from __future__ import annotations

import time

import numpy as np

from sim.cases.buckling import EULER_COMPRESSION, buckling_cylinder, buckling_path
from sim.cases.zhang import relative_l2
from sim.mesh.procedural import signed_volumes
from tissuerender.report.measure import mesh_point, pareto_front, refusal
from tissuerender.report.pictures import error_fields

CASE = "cylinder_buckling"
COMPONENT = 0  # u_x, the imperfection's direction
MESH_SETTINGS = {"damping": 2.0, "material": "model"}
DAMPED = {"rayleigh_alpha": 1.0, "rayleigh_beta": 0.01}  # as the Zhang cases (cases.run_mesh)

SWEEPS = {
    "full": {"cylinder_h": 0.25, "load_steps": 20, "settle_s": 8.0, "xpbd_dt": 0.05,
             "xpbd": [[1, 5], [1, 20], [5, 20], [5, 100]], "ebm": [20, 100], "ebm_load_steps": 8,
             "explicit_dts": [0.0025], "cnn_dts": [0.005, 0.0025], "cnn_K": 4.0, "chainmail_alpha": [0.2]},
    "quick": {"cylinder_h": 0.25, "load_steps": 10, "settle_s": 4.0, "xpbd_dt": 0.05,
              "xpbd": [[1, 5], [5, 20]], "ebm": [20], "ebm_load_steps": 8, "explicit_dts": [], "cnn_dts": [],
              "cnn_K": 4.0, "chainmail_alpha": []},
    "tiny": {"cylinder_h": 0.25, "load_steps": 10, "settle_s": 4.0, "xpbd_dt": 0.05,
             "xpbd": [[1, 5], [5, 20]], "ebm": [20], "ebm_load_steps": 8, "explicit_dts": [], "cnn_dts": [],
             "cnn_K": 4.0, "chainmail_alpha": []},
}


def work_units(sweep: dict) -> int:
    return 2 + sum(len(sweep[k]) for k in ("xpbd", "ebm", "explicit_dts", "cnn_dts", "chainmail_alpha"))


def sideways(model, u: np.ndarray) -> float:
    """The loaded face's sideways deflection [m]: the hypotenuse of its mean u_x and u_y."""
    end = model.partial().nodes
    return float(np.hypot(u[end, 0].mean(), u[end, 1].mean()))


def run_buckling_sweep(sweep: dict, tick=lambda: None) -> dict:
    case = buckling_cylinder(h=sweep["cylinder_h"])
    model = case.model
    start = time.perf_counter()
    own = buckling_path(case, sweep["load_steps"], eigen_every=sweep["load_steps"], anp=False)
    reference_s = time.perf_counter() - start
    anp = buckling_path(buckling_cylinder(h=sweep["cylinder_h"]), sweep["load_steps"], anp=True)
    tick()
    u_ref = own.x - model.X
    deflection_ref = sideways(model, u_ref)
    u_anp = anp.x - model.X
    deflection_anp = sideways(model, u_anp)
    settle = sweep["settle_s"]
    runs = [("xpbd", f"{s}x{i}", {"substeps": s, "iterations": i, **MESH_SETTINGS}, sweep["xpbd_dt"], settle)
            for s, i in sweep["xpbd"]]
    n = sweep["ebm_load_steps"]
    runs += [("ebm", f"{it} it", {"iterations": it}, case.ramp_time / n, case.ramp_time)
             for it in sweep["ebm"]]
    runs += [("explicit", f"dt {dt:g}", dict(DAMPED), dt, settle) for dt in sweep["explicit_dts"]]
    runs += [("cnn", f"dt {dt:g}, K {sweep['cnn_K']:g}", {**DAMPED, "K": sweep["cnn_K"]}, dt, settle)
             for dt in sweep["cnn_dts"]]
    runs += [("cnn_chainmail", f"alpha {a:g}", {"alpha": a}, case.ramp_time / 10, case.ramp_time)
             for a in sweep["chainmail_alpha"]]
    refused = {name: refusal(name, model) for name in dict.fromkeys(r[0] for r in runs)}
    points = []
    for name, label, settings, dt, simulated in runs:
        tick()
        if refused[name] is not None:
            continue
        point = mesh_point(name, label, settings, case, u_ref, COMPONENT, dt, int(round(simulated / dt)))
        if "_u" in point:
            point["sideways_m"] = sideways(model, point["_u"])
            point["sideways_rel_error"] = abs(point["sideways_m"] - deflection_ref) / deflection_ref
            point["rel_l2_anp"] = relative_l2(point["_u"], u_anp)
            point["sideways_rel_error_anp"] = abs(point["sideways_m"] - deflection_anp) / deflection_anp
            x = model.X + point["_u"]
            point["finite"] = bool(np.isfinite(x).all())
            point["inverted_tets"] = int(np.count_nonzero(signed_volumes(x, model.tets) <= 0.0))
        point["stable"] = point["diverged"] is None and point.get("finite", False) and point.get("inverted_tets") == 0
        points.append(point)
    fields = error_fields(model, points, u_ref)
    tick()
    path = {"compression_m": own.compression.tolist(), "deflection_m": own.deflection.tolist(),
            "anp_deflection_m": anp.deflection.tolist(), "anp_smallest_eigenvalue": anp.smallest_eigenvalue.tolist()}
    measures = {"reference_sideways_m": deflection_ref, "anp_sideways_m": deflection_anp,
                "anp_critical_compression_m": anp.critical_compression()}
    for name in ("xpbd", "ebm", "explicit", "cnn", "cnn_chainmail"):
        mine = [p for p in points if p["integrator"] == name]
        ok = [p for p in mine if p["diverged"] is None]
        measures[f"{name}_best_rel_l2"] = min((p["rel_l2"] for p in ok), default=float("nan"))
        measures[f"{name}_failed"] = len(mine) - len(ok)
        measures[f"{name}_unstable"] = sum(1 for p in mine if not p["stable"])
    d = np.abs(u_ref[case.line, COMPONENT])
    return {"case": CASE, "title": "A hard case: the compressed cylinder with a sliding face, which buckles",
            "error_key": "rel_l2", "error_label": "relative L2 displacement error [-] against the reference on "
                                                  "the same elements",
            "mesh": {"nodes": int(model.n_nodes), "tets": int(model.n_tets)},
            "reference": {"kind": f"quasi-static Newton path, relative gradient 1e-8, {sweep['load_steps']} load "
                                  f"steps, linear tets without ANP (the integrators' own); ANP path for the critical "
                                  f"compression {measures['anp_critical_compression_m']:.3f} m (Euler {EULER_COMPRESSION:g} m)",
                          "wall_s": reference_s, "sideways_m": deflection_ref,
                          "line_component": "x", "line_peak_m": float(d.max()),
                          "line_coord_m": case.line_coord.tolist(), "line_u_m": u_ref[case.line, COMPONENT].tolist()},
            "convergence": {"what": "the ANP path's smallest eigenvalue of the reduced tangent stiffness crosses zero "
                                    f"at {measures['anp_critical_compression_m']:.3f} m of compression, against Euler's "
                                    f"{EULER_COMPRESSION:g} m", "relative_difference":
                                        abs(measures["anp_critical_compression_m"] / EULER_COMPRESSION - 1.0)},
            "not_applicable": {k: v for k, v in refused.items() if v is not None},
            "path": path, "points": points, "pareto": pareto_front(points, "rel_l2"), "measures": measures,
            "error_fields": fields}
