"""The accuracy report's mesh-converged references for Zhang's cases (issue 17 item 1, second bullet; the
cantilever's study is ``discretisation.py``, whose Richardson extrapolation, tables and error plot this reuses).

For each case of ``sweep["cases"]`` (the report's ``MESH_CASES``: Zhang §5.3.2's cylinder moved +-0.4 m along its
axis, the cube sheared 0.5 m; Neo-Hookean 5.35, E 3,000 Pa, nu 0.49), the quasi-static Newton reference (relative
gradient 1e-8, ``load_steps`` increments over the ramp, as the report's cases) at mesh levels k = 0, 1, 2: the
``--quick`` case mesh (cylinder h 0.25 m, 656 tets; cube 4 cells, 384 tets) refined k times (1 tet -> 8,
``sim.cases.zhang``), on linear tets (``linear_levels``), on linear tets with average nodal pressure against
volumetric locking (``anp_levels``; nu = 0.49 is near-incompressible) and on quadratic 10-node tets
(``quadratic_levels``). Level 1 of the cube *is* the full report's case mesh (8 cells, the same tets); the full
report's cylinder (h 0.125 m, 4,864 tets) has level 1's element size on a finer polyhedron (the study keeps the
polyhedron of level 0: refinement keeps edges straight; ``polyhedron_volume_ratio`` says how far it is from the
round cylinder).

Measured, as the report's cases do, on the measurement line (Zhang Figs. 5.5(c)-5.7(c): u_x along the cylinder's
surface line, u_z along the cube's right face): each level's line displacement at the level-0 mesh's line nodes
(present at every level), and the **mid-line displacement** (the node nearest the line's middle, z = 1 m; the
line's ends lie on the held faces of the cylinder, so no end displacement is measured there).

- The **mesh-converged line**: Richardson extrapolation (``sim.cases.cantilever.richardson``) of the quadratic
  levels, else of the linear levels, with the order observed on the mid-line displacement of the last three levels
  (between 1 and 8), applied node by node; with no observed order, the finest quadratic level, said so.
- Per level and element, Zhang's **line errors** against it (max, mean, RMSE of |u - u_conv| [m]) and the
  relative error of the mid-line displacement: "how far linear tets on the case's mesh are" is level
  ``report_mesh_level``'s row (``measures``), which the claims against ABAQUS quote as the mesh's own error.
"""
from __future__ import annotations

import base64
import html
import time

import numpy as np

from sim.cases.cantilever import richardson
from sim.cases.zhang import Case, zhang_case
from sim.integrators.reference_quadratic import QuadraticModel, reference_for
from sim.model import State
from tissuerender.report.discretisation import QUADRATIC_ORDER, error_panel, num, png_bytes, table
from tissuerender.report.measure import line_errors

CASE = "zhang_mesh"
LINEAR_ORDER = 2.0  # linear tets' displacement converges as h^2 (assumed only to label; the fallback is the finest level)
ELEMENTS = ("linear", "linear_anp", "quadratic")
LABELS = {"linear": "linear tets", "linear_anp": "linear tets + ANP", "quadratic": "quadratic tets"}
CYLINDER_RADIUS, CYLINDER_LENGTH = 0.5, 2.0  # [m] (sim.cases.zhang)

SWEEPS = {
    "full": {"cases": ["cylinder_extension", "cylinder_compression", "cube_shear"], "cylinder_h": 0.25,
             "cube_cells": 4, "linear_levels": [0, 1, 2], "anp_levels": [0, 1], "quadratic_levels": [0, 1],
             "load_steps": 4, "report_mesh_level": 1},
    # at most the case's mesh and one refinement, on one case (issue 17's budget for --quick)
    "quick": {"cases": ["cube_shear"], "cylinder_h": 0.25, "cube_cells": 4, "linear_levels": [0, 1],
              "anp_levels": [0], "quadratic_levels": [0], "load_steps": 4, "report_mesh_level": 0},
    # the test suite's: a 2-cell cube (48 tets at level 0)
    "tiny": {"cases": ["cube_shear"], "cylinder_h": 0.25, "cube_cells": 2, "linear_levels": [0, 1],
             "anp_levels": [0, 1], "quadratic_levels": [0, 1], "load_steps": 4, "report_mesh_level": 0},
}


LEVEL_KEYS = {"quadratic": "quadratic_levels", "linear": "linear_levels", "linear_anp": "anp_levels"}


def units(sweep: dict) -> list[dict]:
    """The sweep's solves, each an independently schedulable and cached unit of the report (``run_unit``): one per
    (case, element, level), JSON-ready. Listed with the most refined first (a quadratic level has the nodes of the
    next linear one), so a scheduler taking them in order starts the longest solves first; ``combine`` does not
    depend on the order the results arrive in."""
    listed = [{"case": name, "element": element, "level": level, "cylinder_h": sweep["cylinder_h"],
               "cube_cells": sweep["cube_cells"], "load_steps": sweep["load_steps"]}
              for name in sweep["cases"] for element, key in LEVEL_KEYS.items() for level in sweep[key]]
    return sorted(listed, key=lambda u: -(u["level"] + (u["element"] == "quadratic")))


def unit_id(unit: dict) -> str:
    return f"{unit['case']}-{unit['element']}-{unit['level']}"


def work_units(sweep: dict) -> int:
    return len(units(sweep))


def _base(name: str, sweep: dict) -> tuple[Case, int]:
    """The level-0 case (its line nodes are every level's measurement points) and the index of the mid-line node;
    ``sweep`` is the sweep or one of its units (both carry cylinder_h and cube_cells)."""
    base = zhang_case(name, sweep["cylinder_h"], sweep["cube_cells"])
    mid = int(np.argmin(np.abs(base.line_coord - 0.5 * (base.line_coord[0] + base.line_coord[-1]))))
    return base, mid


def run_unit(unit: dict) -> dict:
    """One unit of ``units(sweep)`` (it carries the sweep's mesh and load settings): its level's row
    (``solve_level``)."""
    name, element, level = unit["case"], unit["element"], unit["level"]
    base, _ = _base(name, unit)
    case = zhang_case(name, unit["cylinder_h"], unit["cube_cells"], level, element == "quadratic")
    return solve_level(case, unit["load_steps"], element == "linear_anp", base.line, level)


def solve_level(case: Case, load_steps: int, anp: bool, line0: np.ndarray, level: int) -> dict:
    """The quasi-static reference on ``case`` (any level, linear or quadratic tets, with or without ANP): its row,
    with the line displacement at the level-0 line nodes ``line0`` (present at every level)."""
    start = time.perf_counter()
    model = case.model
    solver = reference_for(model, {"mode": "quasistatic", "load_steps": load_steps, "anp": anp})
    u = solver.step(State.at_rest(model), case.ramp_time).x - model.X
    c = case.component
    element = "quadratic" if isinstance(model, QuadraticModel) else "linear_anp" if anp else "linear"
    return {"level": level, "element": element, "tets": int(model.n_tets), "nodes": int(model.n_nodes),
            "newton_iterations_last": int(solver.last_iterations), "wall_s": time.perf_counter() - start,
            "line_u_m": u[line0, c].tolist(), "own_line_coord_m": case.line_coord.tolist(),
            "own_line_u_m": u[case.line, c].tolist()}


def mesh_converged(rows: dict[str, list[dict]], mid: int) -> dict:
    """The mesh-converged line (module docstring): Richardson of the quadratic, else the linear, levels where the
    order of the mid-line displacement is observed on three levels; else the finest quadratic level."""
    for element, assumed in (("quadratic", QUADRATIC_ORDER), ("linear", LINEAR_ORDER)):
        levels = rows[element]
        if len(levels) < 3:
            continue
        rich = richardson([r["line_u_m"][mid] for r in levels], assumed)
        if rich["order_source"] != "observed":
            continue
        coarse, fine = (np.asarray(r["line_u_m"]) for r in levels[-2:])
        line = fine + (fine - coarse) / (2.0 ** rich["order_used"] - 1.0)
        return {"source": element, "how": f"Richardson extrapolation of the {LABELS[element]} at levels "
                f"{[r['level'] for r in levels]}, observed order {rich['order_used']:.2f} (mid-line displacement)",
                "richardson": rich, "line_u_m": line.tolist()}
    finest = rows["quadratic"][-1]
    return {"source": "quadratic", "how": f"the finest quadratic level ({finest['level']}, {finest['nodes']:,} nodes): "
            "no order observed (fewer than three levels of one element, or not monotone), so not extrapolated",
            "richardson": None, "line_u_m": list(finest["line_u_m"])}


def add_errors(row: dict, u_conv: np.ndarray, mid: int) -> None:
    """Zhang's line errors of ``row`` against the converged line ``u_conv``, and its mid-line relative error."""
    u = np.asarray(row["line_u_m"])
    row.update(line_errors(u[:, None], u_conv[:, None], np.arange(u.size), 0))
    row["mid_u_m"] = float(u[mid])
    row["mid_relative_error"] = abs(u[mid] - u_conv[mid]) / abs(u_conv[mid])


def case_study(name: str, sweep: dict, solved: dict[str, dict]) -> dict:
    """One case's study from its levels' rows (``solved``: ``unit_id`` -> ``run_unit``'s row): the converged line
    and each row's errors against it."""
    base, mid = _base(name, sweep)
    rows = {element: [dict(solved[unit_id({"case": name, "element": element, "level": level})])
                      for level in sweep[key]] for element, key in LEVEL_KEYS.items()}
    conv = mesh_converged(rows, mid)
    u_conv = np.asarray(conv["line_u_m"])
    for row in (r for element in ELEMENTS for r in rows.get(element, ())):
        add_errors(row, u_conv, mid)
    result = {"case": name, "component": "xyz"[base.component], "line_coord_m": base.line_coord.tolist(),
              "mid_coord_m": float(base.line_coord[mid]), "converged": {**conv, "mid_u_m": float(u_conv[mid]),
                                                                        "peak_m": float(np.abs(u_conv).max())},
              **rows}
    if name.startswith("cylinder"):
        # the polyhedron every level meshes, against the round cylinder (pi r^2 L)
        result["polyhedron_volume_ratio"] = float(base.model.volume.sum() / (np.pi * CYLINDER_RADIUS**2 * CYLINDER_LENGTH))
    at = sweep["report_mesh_level"]
    result["report_mesh"] = {element: next((r for r in rows[element] if r["level"] == at), None)
                             for element in ELEMENTS}
    return result


def combine(sweep: dict, solved: dict[str, dict]) -> dict:
    """The study (the report's ``zhang_mesh`` case) from every unit's row, keyed by ``unit_id``."""
    cases = {name: case_study(name, sweep, solved) for name in sweep["cases"]}
    measures = {}
    for name, case in cases.items():
        for element, row in case["report_mesh"].items():
            if row is None:
                continue
            for key in ("line_max_m", "line_mean_m", "line_rmse_m", "mid_relative_error"):
                measures[f"{name}_{element}_{key}"] = row[key]
        measures[f"{name}_converged_mid_u_m"] = case["converged"]["mid_u_m"]
    return {"case": CASE, "title": "Mesh-converged references for Zhang's cases (linear and quadratic tets)",
            "sweep": sweep, "cases": cases, "measures": measures}


def run_zhang_mesh(sweep: dict, tick=lambda: None) -> dict:
    """The study in one process: every unit in turn, then ``combine`` (the report runs the units as its own tasks)."""
    solved = {}
    for unit in units(sweep):
        solved[unit_id(unit)] = run_unit(unit)
        tick()
    return combine(sweep, solved)


def mesh_bound(study: dict, case_name: str, case_tets: int | None, statistic: str) -> dict | None:
    """Linear tets' own line error (``statistic``: line_max_m, line_mean_m or line_rmse_m) against the mesh-converged
    line at the level of the case's mesh (the level with its tet count, else the report's level, said so); None when
    the study did not run the case."""
    case = study["cases"].get(case_name)
    if case is None or not case["linear"] or case_tets is None:
        return None
    exact = [r for r in case["linear"] if r["tets"] == case_tets]
    row = exact[0] if exact else case["report_mesh"]["linear"] or case["linear"][0]
    note = ("the case's mesh" if exact else f"level {row['level']} ({row['tets']:,} tets), the element size of the "
            f"case's {case_tets:,}-tet mesh on a coarser polyhedron")
    return {"value": row[statistic], "level": row["level"], "tets": row["tets"], "where": note,
            "converged": case["converged"]["source"]}


# --- the HTML section ------------------------------------------------------------------------------------------

def figure_png(case: dict, cached: bool) -> bytes:
    """Left: the line displacement of the finest level of each element and of the case's mesh, and the converged
    line. Right: each element's line RMSE against the converged line, against tets (log-log)."""
    import matplotlib

    matplotlib.use("Agg")  # off-screen
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(9.6, 3.8), dpi=80)
    for element, style, colour in (("linear", "--", "tab:blue"), ("linear_anp", ":", "tab:orange"),
                                   ("quadratic", "-", "tab:green")):
        rows = case[element]
        for row in rows[:1] + rows[1:][-1:]:  # the coarsest and the finest level
            left.plot(row["own_line_coord_m"], row["own_line_u_m"], style, color=colour,
                      lw=1.8 if row is rows[-1] else 0.9, label=f"{LABELS[element]}, level {row['level']}")
    left.plot(case["line_coord_m"], case["converged"]["line_u_m"], "ko", ms=3, label="mesh-converged")
    left.set_xlabel("along the line [m]")
    left.set_ylabel(f"u_{case['component']} [m]")
    left.legend(fontsize=7)
    left.grid(True, alpha=0.3)
    error_panel(right, [(LABELS[e], m, [r["tets"] for r in case[e]], [r["line_rmse_m"] for r in case[e]])
                        for e, m in (("linear", "o"), ("linear_anp", "^"), ("quadratic", "s"))],
                "line RMSE against the converged line [m]")
    fig.suptitle(f"Zhang §5.3.2 {case['case'].replace('_', ' ')}: mesh levels" + (" (cached)" if cached else ""),
                 fontsize=10)
    return png_bytes(fig)


def section_html(study: dict) -> str:
    sweep = study["sweep"]
    cached = bool(study.get("cached"))
    parts = [f'<h2 id="case-{CASE}">{html.escape(study["title"])}{" <em>(cached)</em>" if cached else ""}</h2>',
             f"<p>The quasi-static Newton reference (relative gradient 1e-8, {sweep['load_steps']} load steps) at mesh "
             f"levels: the <code>--quick</code> case mesh refined 1 tet -&gt; 8 per level, on linear tets (levels "
             f"{sweep['linear_levels']}), linear tets with average nodal pressure ({sweep['anp_levels']}; nu = 0.49) "
             f"and quadratic 10-node tets ({sweep['quadratic_levels']}). Errors are Zhang's line errors against the "
             f"mesh-converged line, at the level-0 mesh's line nodes. The integrators' errors elsewhere in this "
             f"report are against the reference on their own mesh: this is the error that mesh makes, which no "
             f"integrator on it can get below (tissuerender/report/zhang_mesh.py).</p>"]
    for name, case in study["cases"].items():
        png = base64.b64encode(figure_png(case, cached)).decode("ascii")
        conv = case["converged"]
        at = case["report_mesh"]["linear"]
        summary = (f"linear tets at level {at['level']} ({at['tets']:,} tets) are off by max {num(at['line_max_m'])} m, "
                   f"RMSE {num(at['line_rmse_m'])} m along the line ({100 * at['line_max_m'] / conv['peak_m']:.3g} % "
                   f"of the converged line's peak {num(conv['peak_m'])} m), the mid-line displacement by "
                   f"{100 * at['mid_relative_error']:.3g} %" if at else "the report's level did not run")
        geometry = (f" Every level meshes the level-0 polyhedron, whose volume is "
                    f"{100 * (1 - case['polyhedron_volume_ratio']):.2f} % below the round cylinder's."
                    if "polyhedron_volume_ratio" in case else "")
        rows = [[LABELS[r["element"]], r["level"], r["tets"], r["nodes"], num(r["mid_u_m"]),
                 f"{100 * r['mid_relative_error']:.3g} %", num(r["line_max_m"]), num(r["line_mean_m"]),
                 num(r["line_rmse_m"]), r["newton_iterations_last"], num(r["wall_s"])]
                for e in ELEMENTS for r in case[e]]
        parts += [f'<h3 id="zhang-mesh-{name}">{html.escape(name.replace("_", " "))}</h3>',
                  f'<img class="figure" data-case="{CASE}" data-figure="levels-{name.replace("_", "-")}" alt="line displacement per level '
                  f'and line error against tets" src="data:image/png;base64,{png}">',
                  f"<p><b>Mesh-converged</b> ({html.escape(conv['how'])}): mid-line u_{case['component']} "
                  f"<b>{num(conv['mid_u_m'])} m</b> at {num(case['mid_coord_m'])} m. <b>How far linear tets on the "
                  f"case's mesh are:</b> {summary}.{geometry}</p>",
                  table(["elements", "level", "tets", "nodes", "mid-line u [m]", "mid error", "line max [m]",
                         "line mean [m]", "line RMSE [m]", "Newton it. (last)", "wall [s]"], rows, CASE)]
    return "\n".join(parts)
