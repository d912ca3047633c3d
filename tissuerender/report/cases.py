"""The simulation cases of the accuracy report, each a function of its sweep settings returning one
JSON-ready dict: the points (one per swept setting), the reference it was measured against, a
convergence check of that reference, and the named ``measures`` the claims (``claims.py``) read.

- ``msd``: the mass–spring–damper of Zhang §4.3.2.1 (``sim.cases.msd``) against its closed-form
  solution: ``explicit`` and ``cnn`` (K = 5, 4, 2, state saturation) over the time step. Only these two
  apply (XPBD, EBM and ChainMail need a tetrahedral mesh).
- ``cylinder_extension``, ``cylinder_compression``, ``cube_shear``: Zhang §5.3.2 (``sim.cases.zhang``), and
  ``cube_stretch`` (Zhang §5.3.3: the same cube pulled 0.3 m along its normal),
  Neo-Hookean 5.35, against the quasi-static Newton reference (``sim.integrators.reference``, relative
  gradient 1e-8) on the same mesh: ``xpbd`` (``material = "model"``: the same Neo-Hookean energy) over
  substeps x iterations, ``ebm`` over iterations (8 load steps over the 1 s ramp), ``explicit`` and ``cnn``
  over dt (Rayleigh damping so they settle), ``cnn_chainmail`` over its strain limit alpha. The dynamic
  integrators run ``settle_s`` simulated seconds (ramp, then settling) and are measured at the end.
- ``rates``: steps per second of EBM and the CNN with energy propagation at the thesis's sizes (Zhang
  Figs. 5.13 and 4.17; the cases of ``sim.cases.rates``, which ``benchmarks/zhang_rates.py`` times too).
"""
from __future__ import annotations

import time

import numpy as np

from sim.cases.msd import MassSpringDamper, simulate
from sim.cases.rates import cnn_cube, ebm_block, step_rate
from sim.cases.zhang import zhang_cube_shear, zhang_cube_stretch, zhang_cylinder
from sim.integrators.reference import ReferenceIntegrator
from sim.model import State
from tissuerender.report import cnn_cube as zhang_cnn_cube  # not sim.cases.rates.cnn_cube, the rate's block
from tissuerender.report import buckling_sweep, cantilever_sweep, discretisation, indentation, mitsuba, variational
from tissuerender.report import viscoelastic, zhang_mesh
from tissuerender.report.measure import mesh_point, observed_order, pareto_front
from tissuerender.report.pictures import error_fields

# the displacement component the thesis plots along the measurement line: u_x on the cylinder (Zhang
# Figs. 5.5(c), 5.6(c)), u_z on the cube (Fig. 5.7(c))
LINE_COMPONENT = {"cylinder_extension": 0, "cylinder_compression": 0, "cube_shear": 2,
                  "cube_stretch": 0}  # the stretched cube's sideways contraction (sim.cases.zhang)
MESH_CASES = tuple(LINE_COMPONENT)
# cases of their own modules, each with SWEEPS per level, a run function and work_units
EXTRA = {"liver_variational": (variational.SWEEPS, variational.run_variational, variational.work_units),
         "indentation": (indentation.SWEEPS, indentation.run_indentation, indentation.work_units),
         "cnn_cube": (zhang_cnn_cube.SWEEPS, zhang_cnn_cube.run_cnn_cube, zhang_cnn_cube.work_units),
         "mitsuba": (mitsuba.SWEEPS, mitsuba.run_mitsuba, mitsuba.work_units),
         discretisation.CASE: (discretisation.SWEEPS, discretisation.run_discretisation, discretisation.work_units),
         zhang_mesh.CASE: (zhang_mesh.SWEEPS, zhang_mesh.run_zhang_mesh, zhang_mesh.work_units),
         viscoelastic.CASE: (viscoelastic.SWEEPS, viscoelastic.run_viscoelastic, viscoelastic.work_units),
         cantilever_sweep.CASE: (cantilever_sweep.SWEEPS, cantilever_sweep.run_cantilever_integrators, cantilever_sweep.work_units),
         buckling_sweep.CASE: (buckling_sweep.SWEEPS, buckling_sweep.run_buckling_sweep, buckling_sweep.work_units)}
# cases whose work the report schedules and caches unit by unit: (units(sweep) -> JSON-ready units, unit_id(unit),
# run_unit(unit) -> JSON-ready result, combine(sweep, {unit_id: result}) -> the case's result, as run_case's)
SPLIT = {zhang_mesh.CASE: (zhang_mesh.units, zhang_mesh.unit_id, zhang_mesh.run_unit, zhang_mesh.combine)}
CASES = ("msd", *MESH_CASES, "rates", *EXTRA)
SCENE_CASES = ("liver_variational", "mitsuba")  # they build a shipped scene (and render): keyed on all the code

# sweep settings per level; "tiny" is the test suite's (not a CLI option)
SWEEPS = {
    "full": {
        "msd": {"dts": [0.0004, 0.0008, 0.002, 0.005, 0.01], "Ks": [5.0, 4.0, 2.0], "order_dt": 0.0004},
        "mesh": {"cylinder_h": 0.125, "cube_cells": 8, "settle_s": 8.0,
                 "xpbd": [[1, 1], [1, 5], [1, 20], [5, 5], [5, 20], [5, 100]], "xpbd_dt": 0.05,
                 "ebm": [20, 100, 500], "ebm_load_steps": 8, "explicit_dts": [0.0025, 0.00125],
                 "cnn_dts": [0.005, 0.0025], "cnn_K": 4.0, "chainmail_alpha": [0.1, 0.2, 0.4],
                 "order_dts": [0.1, 0.05, 0.025], "order_t": 0.2},
        "rates": {"steps": 100, "repeats": 5, "cnn_energy": True},
    },
    "quick": {
        "msd": {"dts": [0.0008, 0.002, 0.005, 0.01], "Ks": [5.0, 4.0, 2.0], "order_dt": 0.0008},
        "mesh": {"cylinder_h": 0.25, "cube_cells": 4, "settle_s": 8.0,
                 "xpbd": [[1, 1], [1, 5], [1, 20], [5, 20]], "xpbd_dt": 0.05,
                 "ebm": [20, 100], "ebm_load_steps": 8, "explicit_dts": [0.005], "cnn_dts": [0.01, 0.005],
                 "cnn_K": 4.0, "chainmail_alpha": [0.1, 0.2], "order_dts": [0.1, 0.05, 0.025], "order_t": 0.2},
        "rates": {"steps": 20, "repeats": 3, "cnn_energy": False},
    },
    "tiny": {
        "msd": {"dts": [0.0008, 0.005, 0.01], "Ks": [5.0, 4.0, 2.0], "order_dt": 0.0008},
        "mesh": {"cylinder_h": 0.25, "cube_cells": 4, "settle_s": 4.0,
                 "xpbd": [[1, 1], [1, 5], [1, 20]], "xpbd_dt": 0.05,
                 "ebm": [20], "ebm_load_steps": 8, "explicit_dts": [0.005], "cnn_dts": [0.01, 0.005],
                 "cnn_K": 4.0, "chainmail_alpha": [0.2], "order_dts": [0.1, 0.05, 0.025], "order_t": 0.2},
        "rates": {"steps": 5, "repeats": 1, "cnn_energy": False},
    },
}
# --quick leaves out the compressed cylinder and the buckling cylinder (a hard case: full report only)
QUICK_CASES = ("msd", "cylinder_extension", "cube_shear", "cube_stretch", "rates",
               *(name for name in EXTRA if name != buckling_sweep.CASE))


def sweep_for(case: str, level: str) -> dict:
    if case in EXTRA:
        return EXTRA[case][0][level]
    return SWEEPS[level]["msd" if case == "msd" else "rates" if case == "rates" else "mesh"]


def work_units(case: str, sweep: dict) -> int:
    """How many times ``run_case`` calls its ``tick``: the progress bar's share of the case."""
    if case in EXTRA:
        return EXTRA[case][2](sweep)
    if case == "msd":
        return 1
    if case == "rates":
        return 3 if sweep["cnn_energy"] else 2
    return 2 + sum(len(sweep[k]) for k in ("xpbd", "ebm", "explicit_dts", "cnn_dts", "chainmail_alpha"))


def run_case(case: str, sweep: dict, tick=lambda: None) -> dict:
    """Run one case; ``tick()`` is called after each unit of work (``work_units`` in all)."""
    if case in EXTRA:
        return EXTRA[case][1](sweep, tick)
    if case == "msd":
        result = run_msd(sweep)
        tick()
        return result
    if case == "rates":
        return run_rates(sweep, tick)
    return run_mesh(case, sweep, tick)


# --- mass–spring–damper -------------------------------------------------------------------------

def _msd_point(system, scheme: str, dt: float, K: float, y_ref_of) -> dict:
    t_end = 1.0
    start = time.perf_counter()
    t, y = simulate(system, dt, t_end, scheme=scheme, K=K)
    seconds = time.perf_counter() - start
    y_ref = y_ref_of(t)
    err = np.abs(y - y_ref)
    late = t >= t_end - 0.1
    return {"integrator": scheme, "setting": f"dt {dt:g}" + ("" if scheme == "explicit" else f", K {K:g}"),
            "settings": {"dt": dt, **({} if scheme == "explicit" else {"K": K, "saturation": "state"})},
            "dt_s": dt, "steps": len(t) - 1, "simulated_s": t_end, "wall_s": seconds,
            "wall_s_per_sim_s": seconds / t_end, "diverged": None,
            "max_abs_m": float(err.max()),
            "rel_l2": float(np.linalg.norm(y - y_ref) / np.linalg.norm(y_ref - system.y_rest)),
            "late_amplitude_m": float(np.abs(y[late] - system.y_rest).max())}


def run_msd(sweep: dict) -> dict:
    system = MassSpringDamper()
    simulate(system, 0.01, 0.02, scheme="cnn", K=5.0)  # warm-up (pure Python: nothing to compile)
    fine_t = np.linspace(0.0, 1.0, 100001)
    peak = float(np.abs(system.analytic(fine_t) - system.y_rest).max())
    points = [_msd_point(system, "explicit", dt, np.inf, system.analytic) for dt in sweep["dts"]]
    points += [_msd_point(system, "cnn", dt, K, system.analytic) for K in sweep["Ks"] for dt in sweep["dts"]]
    # forward Euler converges at first order: halve the step twice
    h = sweep["order_dt"]
    errors = [_msd_point(system, "explicit", h / 2**k, np.inf, system.analytic)["max_abs_m"] for k in range(3)]
    convergence = {"what": "explicit (forward Euler) against the closed form, max |y - y_exact| over 1 s",
                   "dts": [h / 2**k for k in range(3)], "errors_m": errors,
                   "orders": [observed_order(errors[0], errors[1]), observed_order(errors[1], errors[2])],
                   "expected_order": 1}

    def err(scheme, dt, K=None):
        for p in points:
            if p["integrator"] == scheme and p["dt_s"] == dt and (K is None or p["settings"].get("K") == K):
                return p
        return None

    small, large = min(sweep["dts"]), max(sweep["dts"])
    measures = {"analytic_peak_m": peak}
    for K in sweep["Ks"]:
        measures[f"cnn_K{K:g}_small_max_m"] = err("cnn", small, K)["max_abs_m"]
        measures[f"cnn_K{K:g}_large_max_m"] = err("cnn", large, K)["max_abs_m"]
        measures[f"cnn_K{K:g}_large_late_amplitude_m"] = err("cnn", large, K)["late_amplitude_m"]
    measures["small_dt_s"], measures["large_dt_s"] = small, large
    measures["explicit_small_max_m"] = err("explicit", small)["max_abs_m"]
    measures["explicit_large_late_amplitude_m"] = err("explicit", large)["late_amplitude_m"]
    return {"case": "msd", "title": "mass–spring–damper (Zhang §4.3.2.1)", "error_key": "max_abs_m",
            "error_label": "max |y - y_exact| over 1 s [m]",
            "reference": {"kind": "closed form (underdamped)", "params": system.__dict__},
            "convergence": convergence, "points": points, "pareto": pareto_front(points, "max_abs_m"),
            "measures": measures}


# --- Zhang §5.3.2 mesh cases --------------------------------------------------------------------

def _zhang_case(case: str, sweep: dict):
    if case == "cylinder_extension":
        return zhang_cylinder(h=sweep["cylinder_h"], displacement=0.4)
    if case == "cylinder_compression":
        return zhang_cylinder(h=sweep["cylinder_h"], displacement=-0.4)
    if case == "cube_stretch":
        return zhang_cube_stretch(n_cells=sweep["cube_cells"])
    return zhang_cube_shear(n_cells=sweep["cube_cells"])


# the axis along which each case's kinematic faces lie at 0 and 2 m
END_AXIS = {"cylinder_extension": 2, "cylinder_compression": 2, "cube_shear": 1, "cube_stretch": 1}


def _reference_convergence(case, case_name: str, x_ref, sweep: dict) -> dict:
    """Backward Euler (the reference's dynamic mode) at three steps h, h/2, h/4 over ``order_t`` s after the
    ramp, released at rest from the equilibrium plus a smooth transverse bump (0.05 m sin(pi s / 2), s the
    coordinate between the kinematic faces, zero on them). It is first order, so successive differences
    should halve. A smooth start matters: released from rest mid-ramp, the boundary's velocity jump sends a
    front through the mesh and the observed order falls to about 0.6 at these steps (measured)."""
    s = case.model.X[:, END_AXIS[case_name]]
    x0 = x_ref.copy()
    x0[:, 0] += 0.05 * np.sin(np.pi * s / 2.0)
    kin, target = case.model.kinematic_targets(case.ramp_time)
    x0[kin] = target
    xs = []
    for dt in sweep["order_dts"]:
        ref = ReferenceIntegrator(case.model, {"mode": "dynamic"})
        state = State(x=x0.copy(), v=np.zeros_like(x0), t=case.ramp_time)
        for _ in range(int(round(sweep["order_t"] / dt))):
            state = ref.step(state, dt)
        xs.append(state.x)
    # the bump's amplitude (the projection of the transverse displacement on the bump shape): the slow
    # mode the step resolves; the stiff volumetric modes (nu = 0.49) that BE damps in one step at these h
    # are in the pre-asymptotic regime and would hide the order
    weight = np.sin(np.pi * s / 2.0)
    q = [float(weight @ (x[:, 0] - x_ref[:, 0]) / (weight @ weight)) for x in xs]
    d = [abs(q[0] - q[1]), abs(q[1] - q[2])]
    return {"what": f"backward Euler released from the equilibrium plus a smooth bump, the bump's amplitude "
                    f"{sweep['order_t']:g} s later: |q_h - q_h/2| and |q_h/2 - q_h/4|", "amplitudes_m": q,
            "dts": sweep["order_dts"], "differences_m": d, "orders": [observed_order(d[0], d[1])],
            "expected_order": 1}


def _add(points: list, tick, point: dict) -> None:
    points.append(point)
    tick()


def run_mesh(case_name: str, sweep: dict, tick=lambda: None) -> dict:
    case = _zhang_case(case_name, sweep)
    model = case.model
    component = LINE_COMPONENT[case_name]
    start = time.perf_counter()
    ref = ReferenceIntegrator(model, {"mode": "quasistatic", "load_steps": 4})
    x_ref = ref.step(State.at_rest(model), case.ramp_time).x
    reference_s = time.perf_counter() - start
    tick()
    u_ref = x_ref - model.X
    settle = sweep["settle_s"]
    points = []
    for substeps, iterations in sweep["xpbd"]:
        settings = {"substeps": substeps, "iterations": iterations, "damping": 2.0, "material": "model"}
        dt = sweep["xpbd_dt"]
        _add(points, tick, mesh_point("xpbd", f"{substeps}x{iterations}", settings, case, u_ref, component, dt,
                                 int(round(settle / dt))))
    for iterations in sweep["ebm"]:
        n = sweep["ebm_load_steps"]
        _add(points, tick, mesh_point("ebm", f"{iterations} it", {"iterations": iterations}, case, u_ref, component,
                                 case.ramp_time / n, n))
    for dt in sweep["explicit_dts"]:
        settings = {"rayleigh_alpha": 1.0, "rayleigh_beta": 0.01}
        _add(points, tick, mesh_point("explicit", f"dt {dt:g}", settings, case, u_ref, component, dt,
                                 int(round(settle / dt))))
    for dt in sweep["cnn_dts"]:
        settings = {"rayleigh_alpha": 1.0, "rayleigh_beta": 0.01, "K": sweep["cnn_K"]}
        _add(points, tick, mesh_point("cnn", f"dt {dt:g}, K {sweep['cnn_K']:g}", settings, case, u_ref, component, dt,
                                 int(round(settle / dt))))
    for alpha in sweep["chainmail_alpha"]:
        n = 10
        _add(points, tick, mesh_point("cnn_chainmail", f"alpha {alpha:g}", {"alpha": alpha}, case, u_ref, component,
                                 case.ramp_time / n, n))
    fields = error_fields(model, points, u_ref)
    convergence = _reference_convergence(case, case_name, x_ref, sweep)
    tick()
    measures = {}
    for p in points:
        if p["integrator"] == "ebm" and p["settings"]["iterations"] == 20:
            for key in ("line_max_m", "line_mean_m", "line_rmse_m", "red"):
                measures[f"ebm20_{key}"] = p.get(key, float("nan"))
            measures["ebm20_diverged"] = p["diverged"]
    d = np.abs(u_ref[case.line, component])
    return {"case": case_name, "title": f"Zhang §5.3.2 {case_name.replace('_', ' ')}", "error_key": "rel_l2",
            "error_label": "relative L2 displacement error [-]",
            "mesh": {"nodes": int(model.n_nodes), "tets": int(model.n_tets)},
            "reference": {"kind": "quasi-static Newton, relative gradient 1e-8, 4 load steps", "wall_s": reference_s,
                          "newton_iterations_last": int(ref.last_iterations),
                          "line_component": "xyz"[component], "line_peak_m": float(d.max()),
                          "line_coord_m": case.line_coord.tolist(),
                          "line_u_m": u_ref[case.line, component].tolist()},
            "convergence": convergence, "points": points,
            "pareto": pareto_front(points, "rel_l2"), "measures": measures, "error_fields": fields}


# --- step rates at the thesis's sizes -----------------------------------------------------------

def run_rates(sweep: dict, tick=lambda: None) -> dict:
    runs = [("ebm_isotropic_504tets", "ebm", ebm_block("neo_hookean", cells=(7, 4, 3)), {"iterations": 20}, 1e-3),
            ("ebm_anisotropic_216tets", "ebm", ebm_block("anisotropic_neo_hookean", [0.0, 0.0, 1.0], cells=(4, 3, 3)),
             {"iterations": 20}, 1e-3)]
    if sweep["cnn_energy"]:
        runs.append(("cnn_energy_1452nodes", "cnn", cnn_cube(cells=(10, 10, 11)), {"force_model": "energy", "K": 4.0},
                     1.0 / 60.0))
    measures, rows = {}, []
    for key, name, model, settings, dt in runs:
        hz, _ = step_rate(name, model, settings, dt, sweep["steps"], sweep["repeats"])
        tick()
        measures[f"{key}_hz"] = hz
        rows.append({"run": key, "integrator": name, "settings": settings, "dt_s": dt, "nodes": int(model.n_nodes),
                     "tets": int(model.n_tets), "steps_per_s": hz})
    return {"case": "rates", "title": "step rates at the thesis's sizes (Zhang Figs. 5.13, 4.17)", "rows": rows,
            "measures": measures, "statistic": f"median of {sweep['repeats']} x {sweep['steps']} steps"}
