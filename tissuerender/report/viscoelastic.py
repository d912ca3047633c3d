"""The accuracy report's viscoelastic cube (Zhang §5.3.4, Fig. 5.9; ``sim.cases.viscoelastic``): the reaction force
at the held face over a stress-relaxation test, the reference's against Prony's prediction and every integrator
that evaluates Prony series (``sim.integrators.supported_by("prony")`` but the reference) against the reference.

- **Reference**: the quasi-static Newton reference (relative gradient 1e-8) stepped at ``reference_dt``, its Prony
  history committed every step (``sim.integrators.reference``): the test as the thesis poses it, inertia left out.
  Its own step error: the relative L2 difference of its history at ``2 reference_dt`` from it.
- **Prony's prediction**: the relaxation ratio ``F(end) / F_el`` (-> ``1 - alpha_1``), the time constant fitted over
  the hold against the history update's ``dt / ln(1 + dt / tau_1)`` and the continuous ``tau_1``
  (``sim.cases.viscoelastic``), on the thesis's 0.3 m and on a small-strain copy (``check_displacement_m``) at
  ``check_dt``, whose whole history must follow the discrete recursion to within its strain (linear viscoelasticity
  holds to first order in the strain).
- **Integrators**: each swept setting's F(t) at its own step times against the reference's at the same times
  (``reference_dt`` divides every step), relative L2 over the history, against wall time per simulated second;
  and over the last ``LATE_S`` of the hold alone (``late_rel_l2``: the relaxed force, once a dynamic integrator's
  ringing has died down).
  EBM is quasi-static in effect (its iterations lower the element energies from the predicted start); XPBD is
  dynamic (damping 2/s as in the other mesh cases): the 0.5 s ramp is not slow against the cube's lowest modes (its
  force rings about the reference's with a period of about 0.6 s on the 48-tet mesh), so XPBD's error includes
  that inertia, which the quasi-static test leaves out.

JSON-ready like the other cases (``cases.run_case`` calls :func:`run_viscoelastic`); :func:`section_html` draws it.
"""
from __future__ import annotations

import base64
import html
import math
import time

import numpy as np

from sim.cases import viscoelastic as cube_case
from sim.errors import SimulationDiverged
from sim.integrators import make_integrator
from sim.model import State
from tissuerender.report.discretisation import num, png_bytes, table
from tissuerender.report.measure import pareto_front

CASE = "viscoelastic_cube"
XPBD_DAMPING = 2.0  # [1/s], the other mesh cases' (docs/report.md)
# EBM at the thesis's step (``ebm_hold_over_peak``, the Fig. 5.9 claim): 100 iterations, 0.05 s
CLAIM_EBM = (100, 0.05)
LATE_S = 2.0  # the end of the hold [s]: from 3 s on, XPBD's damping (2/s) has taken e^-5 off the ramp's ringing

SWEEPS = {
    "full": {"cells": 6, "displacement_m": -0.3, "reference_dt": 0.0125, "check_displacement_m": -0.003,
             "check_dt": 0.05, "ebm": [[20, 0.05], [100, 0.05], [500, 0.05], [100, 0.025], [100, 0.0125]],
             "xpbd": [[1, 5, 0.05], [1, 20, 0.05], [5, 20, 0.05], [10, 20, 0.025]]},
    "quick": {"cells": 3, "displacement_m": -0.3, "reference_dt": 0.025, "check_displacement_m": -0.003,
              "check_dt": 0.05, "ebm": [[20, 0.05], [100, 0.05], [100, 0.025]],
              "xpbd": [[1, 5, 0.05], [5, 20, 0.05]]},
    "tiny": {"cells": 2, "displacement_m": -0.3, "reference_dt": 0.05, "check_displacement_m": -0.003,
             "check_dt": 0.05, "ebm": [[20, 0.05], [100, 0.05]], "xpbd": [[1, 5, 0.05], [5, 20, 0.05]]},
}


def work_units(sweep: dict) -> int:
    return 3 + len(sweep["ebm"]) + len(sweep["xpbd"])


def force_history(name: str, settings: dict, cube, dt: float) -> dict:
    """F(t) at every step of ``dt`` from rest to the end of the hold; the wall time of the steps alone (a warm-up
    step of another instance first, so numba's compilation is not counted; the reaction is measured outside the
    timing)."""
    model = cube.model
    if name != "reference":
        make_integrator(name, model, settings).step(State.at_rest(model), dt)
    integrator = make_integrator(name, model, settings)
    state = State.at_rest(model)
    times, forces, seconds, failure = [0.0], [0.0], 0.0, None
    for _ in range(int(round(cube.end_s / dt))):
        start = time.perf_counter()
        try:
            state = integrator.step(state, dt)
        except SimulationDiverged as e:  # also the reference's failed Newton solve
            failure = str(e).splitlines()[0]
            break
        finally:
            seconds += time.perf_counter() - start
        times.append(state.t)
        forces.append(cube_case.reaction_force(integrator, state.x, cube.held))
    return {"t": times, "force_N": forces, "wall_s": seconds, "x": state.x, "diverged": failure}


def _on(reference: dict, dt: float, reference_dt: float) -> np.ndarray:
    """The reference's F at the step times of ``dt`` (a whole multiple of ``reference_dt``)."""
    stride = int(round(dt / reference_dt))
    if abs(stride * reference_dt - dt) > 1e-9 * dt:
        raise ValueError(f"{CASE}: step {dt} s is not a multiple of the reference's {reference_dt} s")
    return np.asarray(reference["force_N"])[::stride]


def relative_l2(force, reference_force) -> float:
    force, reference_force = np.asarray(force, dtype=np.float64), np.asarray(reference_force, dtype=np.float64)
    return float(np.linalg.norm(force - reference_force) / np.linalg.norm(reference_force))


def prony_check(run: dict, cube, dt: float) -> dict:
    """The relaxation ``run`` shows against Prony's prediction (``sim.cases.viscoelastic``), with the bounds each
    measure must meet when the material is linear to within the strain ``eps`` (|displacement| / side):

    - ratio ``F(end) / F_el`` within ``eps`` of the discrete prediction's end value (``1 - alpha`` plus the
      excess left after the hold: ``(peak - (1 - alpha)) B^n``);
    - fitted tau within ``eps`` of the history update's ``dt / ln(1 + dt / tau)``, which is within
      ``dt / (2 tau)`` of tau (``1 / ln(1 + x) = 1 / x + 1 / 2 - x / 12 + ...``, so ``tau_eff / tau - 1`` lies
      between ``x / 2 - x^2 / 12`` and ``x / 2``, x = dt / tau);
    - the history ``F / F_el`` within ``eps`` of the discrete recursion at every step.

    Second-order terms of the Neo-Hookean stress make the departure from linearity a relative O(eps) (measured
    0.13-0.24 eps on 2-4 cells at eps = 1.5e-3): the bound is ``eps`` itself."""
    model = cube.model
    t, force = np.asarray(run["t"]), np.asarray(run["force_N"])
    elastic = cube_case.elastic_reaction(model, run["x"], cube.held)
    fit = cube_case.fit_relaxation(t, force, elastic, cube.ramp_s)
    eps = abs(float(model.prescribed[0].displacement[0])) / cube_case.SIDE_M
    predicted = cube_case.discrete_relaxation(t, dt, cube.ramp_s)
    tau_eff = cube_case.discrete_tau(dt)
    deviation = float(np.abs(force / elastic - predicted).max())
    return {**fit, "strain": eps, "dt_s": dt, "predicted_ratio": float(predicted[-1]),
            "predicted_peak_ratio": float(predicted[np.argmin(np.abs(t - cube.ramp_s))]),
            "continuous_peak_ratio": float(cube_case.continuous_relaxation(cube.ramp_s, cube.ramp_s)),
            "tau_discrete_s": tau_eff, "tau_s_thesis": cube_case.TAU, "alpha_thesis": cube_case.ALPHA,
            "max_deviation_from_recursion": deviation, "tolerance": eps,
            "ratio_within": abs(fit["ratio"] - predicted[-1]) <= eps,
            "tau_within": abs(fit["tau_s"] / tau_eff - 1.0) <= eps,
            "tau_within_continuous": abs(fit["tau_s"] / cube_case.TAU - 1.0) <= 0.5 * dt / cube_case.TAU + eps,
            "history_within": deviation <= eps,
            "rises_during_ramp": bool(np.all(np.diff(force[t <= cube.ramp_s + 1e-9]) > 0.0)),
            "falls_during_hold": bool(np.all(np.diff(force[t >= cube.ramp_s - 1e-9]) < 0.0))}


def _point(name: str, label: str, settings: dict, cube, dt: float, reference: dict, reference_dt: float) -> dict:
    run = force_history(name, settings, cube, dt)
    simulated = run["t"][-1] if run["t"][-1] > 0.0 else dt
    point = {"integrator": name, "setting": label, "settings": settings, "dt_s": dt, "steps": len(run["t"]) - 1,
             "simulated_s": simulated, "wall_s": run["wall_s"], "wall_s_per_sim_s": run["wall_s"] / simulated,
             "diverged": run["diverged"], "t": run["t"], "force_N": run["force_N"]}
    if run["diverged"] is None:
        force, t, reference_force = np.asarray(run["force_N"]), np.asarray(run["t"]), _on(reference, dt, reference_dt)
        point["rel_l2"] = relative_l2(force, reference_force)
        late = t >= cube.end_s - LATE_S - 1e-9
        point["late_rel_l2"] = relative_l2(force[late], reference_force[late])
        point["peak_N"] = float(force.max())
        point["hold_mean_N"] = float(force[late].mean())
    return point


def run_viscoelastic(sweep: dict, tick=lambda: None) -> dict:
    cube = cube_case.zhang_viscoelastic_cube(sweep["cells"], sweep["displacement_m"])
    model, h = cube.model, sweep["reference_dt"]
    reference = force_history("reference", {"mode": "quasistatic"}, cube, h)
    if reference["diverged"] is not None:
        raise RuntimeError(f"{CASE}: the reference failed: {reference['diverged']}")
    tick()
    coarse = force_history("reference", {"mode": "quasistatic"}, cube, 2.0 * h)
    step_error = relative_l2(coarse["force_N"], _on(reference, 2.0 * h, h))
    tick()
    small = cube_case.zhang_viscoelastic_cube(sweep["cells"], sweep["check_displacement_m"])
    check = prony_check(force_history("reference", {"mode": "quasistatic"}, small, sweep["check_dt"]), small,
                        sweep["check_dt"])
    tick()
    thesis = prony_check(reference, cube, h)
    points = []
    for iterations, dt in sweep["ebm"]:
        points.append(_point("ebm", f"{iterations} it, dt {dt:g}", {"iterations": iterations}, cube, dt, reference, h))
        tick()
    for substeps, iterations, dt in sweep["xpbd"]:
        settings = {"substeps": substeps, "iterations": iterations, "damping": XPBD_DAMPING, "material": "model"}
        points.append(_point("xpbd", f"{substeps}x{iterations}, dt {dt:g}", settings, cube, dt, reference, h))
        tick()
    measures = {"relaxes": bool(thesis["rises_during_ramp"] and thesis["falls_during_hold"] and thesis["ratio_within"]
                                and thesis["tau_within"]),
                "ratio": thesis["ratio"], "tau_s": thesis["tau_s"], "peak_ratio": thesis["peak_ratio"],
                "small_strain_prony_holds": bool(check["ratio_within"] and check["tau_within"]
                                                 and check["history_within"] and check["tau_within_continuous"]),
                "reference_step_difference": step_error}
    for p in points:
        if p["integrator"] == "ebm" and (p["settings"]["iterations"], p["dt_s"]) == tuple(CLAIM_EBM) \
                and p["diverged"] is None:
            measures["ebm_hold_mean_N"], measures["ebm_peak_N"] = p["hold_mean_N"], p["peak_N"]
    return {"case": CASE, "title": "Zhang §5.3.4 viscoelastic cube: reaction force over time (Fig. 5.9)",
            "error_key": "rel_l2", "error_label": "relative L2 of the reaction force history F(t) [-]",
            "mesh": {"nodes": int(model.n_nodes), "tets": int(model.n_tets)},
            "setup": {"side_m": cube_case.SIDE_M, "alpha": cube_case.ALPHA, "tau_s": cube_case.TAU,
                      "ramp_s": cube.ramp_s, "end_s": cube.end_s, "E_Pa": 3000.0, "nu": 0.49, "rho": 1000.0,
                      "constitutive": model.constitutive, "xpbd_damping": XPBD_DAMPING, **sweep},
            "reference": {"kind": f"quasi-static Newton, relative gradient 1e-8, Prony history per step of {h:g} s",
                          "wall_s": reference["wall_s"], "t": reference["t"], "force_N": reference["force_N"],
                          "step_difference": step_error, "coarse_dt_s": 2.0 * h},
            "prony_thesis_strain": thesis, "prony_small_strain": check,
            "points": points, "pareto": pareto_front(points, "rel_l2"), "measures": measures}


# --- the HTML section -------------------------------------------------------------------------------------------

def figure_png(case: dict) -> bytes:
    """Left: F(t) of the reference, Prony's prediction scaled by F_el, and each integrator's most accurate setting.
    Right: error against wall time per simulated second, the Pareto front joined."""
    import matplotlib

    matplotlib.use("Agg")  # off-screen
    import matplotlib.pyplot as plt

    colours = {"ebm": "tab:orange", "xpbd": "tab:blue"}
    fig, (left, right) = plt.subplots(1, 2, figsize=(11.0, 4.0), dpi=80)
    ref, thesis = case["reference"], case["prony_thesis_strain"]
    left.plot(ref["t"], ref["force_N"], "k-", lw=2, label="reference (quasi-static)")
    t = np.linspace(0.0, case["setup"]["end_s"], 400)
    predicted = thesis["elastic_N"] * cube_case.continuous_relaxation(t, case["setup"]["ramp_s"])
    left.plot(t, predicted, "k:", lw=1, label="Prony, linear viscoelasticity x F_el")
    best = {}  # per integrator, its most accurate setting
    for p in case["points"]:
        if p.get("rel_l2") is not None and p["rel_l2"] < best.get(p["integrator"], {}).get("rel_l2", math.inf):
            best[p["integrator"]] = p
    for p in best.values():
        left.plot(p["t"], p["force_N"], color=colours.get(p["integrator"]), lw=1,
                  label=f"{p['integrator']} {p['setting']}")
    left.set_xlabel("time [s]")
    left.set_ylabel("reaction force at the held face [N]")
    left.grid(True, alpha=0.3)
    left.legend(fontsize=7)
    points = case["points"]
    for name in dict.fromkeys(p["integrator"] for p in points):
        mine = [p for p in points if p["integrator"] == name and p.get("rel_l2") is not None]
        right.scatter([p["wall_s_per_sim_s"] for p in mine], [p["rel_l2"] for p in mine], color=colours.get(name),
                      label=name)
    front = [points[i] for i in case["pareto"]]
    right.plot([p["wall_s_per_sim_s"] for p in front], [p["rel_l2"] for p in front], "k-", lw=1.2, zorder=0,
               label="Pareto front")
    right.scatter([p["wall_s_per_sim_s"] for p in front], [p["rel_l2"] for p in front], s=140, facecolors="none",
                  edgecolors="k", zorder=3)
    right.set_xscale("log")
    right.set_yscale("log")
    right.set_xlabel("wall time per simulated second [s/s]")
    right.set_ylabel(case["error_label"])
    right.grid(True, which="both", alpha=0.3)
    right.legend(fontsize=8)
    fig.suptitle(case["title"] + (" (cached)" if case.get("cached") else ""), fontsize=10)
    return png_bytes(fig)


def _check_row(label: str, c: dict) -> list:
    return [label, num(c["strain"]), num(c["dt_s"]), num(c["peak_ratio"]), num(c["predicted_peak_ratio"]),
            num(c["ratio"]), num(c["predicted_ratio"]), num(c["tau_s"]), num(c["tau_discrete_s"]),
            num(c["max_deviation_from_recursion"]), num(c["tolerance"]),
            "yes" if c["ratio_within"] and c["tau_within"] else "no"]


def section_html(case: dict) -> str:
    setup, ref = case["setup"], case["reference"]
    png = base64.b64encode(figure_png(case)).decode("ascii")
    front = set(case["pareto"])
    rows = [[p["integrator"], html.escape(p["setting"]), num(p.get("rel_l2")), num(p.get("late_rel_l2")),
             num(p.get("peak_N")),
             num(p.get("hold_mean_N")), num(p["wall_s"]), num(p["wall_s_per_sim_s"]),
             "&#9679;" if i in front else "", html.escape(p["diverged"] or "")] for i, p in enumerate(case["points"])]
    cached = " <em>(cached)</em>" if case.get("cached") else ""
    return "\n".join([
        f'<h2 id="case-{CASE}">{html.escape(case["title"])}{cached}</h2>',
        f'<img class="figure" data-case="{CASE}" data-figure="reaction-force" alt="reaction force over time and error '
        f'against time, viscoelastic cube" src="data:image/png;base64,{png}">',
        f"<p>The {setup['side_m']:g} m cube ({case['mesh']['nodes']} nodes, {case['mesh']['tets']} tets, "
        f"{html.escape(setup['constitutive'])}, E {setup['E_Pa']:g} Pa, nu {setup['nu']:g}, one Prony term alpha "
        f"{setup['alpha']:g}, tau {setup['tau_s']:g} s): the face x = 0 held, the face x = 2 m moved "
        f"{setup['displacement_m']:g} m in x over {setup['ramp_s']:g} s, held to {setup['end_s']:g} s. F(t): the x "
        f"reaction at the held face, positive in compression. Reference: {html.escape(ref['kind'])} "
        f"({num(ref['wall_s'])} s); at twice its step its history differs by {num(ref['step_difference'])} "
        "(relative L2). XPBD is dynamic: the cube's inertia rings under the 0.5 s ramp, which the quasi-static test "
        "leaves out (tissuerender/report/viscoelastic.py).</p>",
        "<p>Prony's prediction (sim/cases/viscoelastic.py): F relaxes from F(T_r) towards (1 - alpha) F_el with "
        "time constant tau; the history update below Zhang 5.32 makes that dt / ln(1 + dt / tau). Bounds: the "
        "strain (linear viscoelasticity to first order).</p>",
        table(["run", "strain", "dt [s]", "F(T_r)/F_el", "predicted", "F(end)/F_el", "predicted", "tau fit [s]",
               "dt/ln(1+dt/tau) [s]", "max |F/F_el - recursion|", "bound", "within"],
              [_check_row("the thesis's 0.3 m", case["prony_thesis_strain"]),
               _check_row("small strain", case["prony_small_strain"])], "viscoelastic"),
        table(["integrator", "setting", "relative L2 of F(t)", "the same over the last 2 s", "peak [N]",
               "mean over the last 2 s [N]", "wall [s]", "wall / sim s", "Pareto", "failure"], rows, "viscoelastic"),
    ])
