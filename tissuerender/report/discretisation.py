"""The accuracy report's discretisation section (issue 17 item 1, second bullet): the error the mesh itself makes,
apart from any solver's, on the large-deflection cantilever (``sim.cases.cantilever``: 2 x 0.2 x 0.2 m, E 1 MPa,
nu 0.3, rho 1000, left end fixed, gravity).

- The quasi-static Newton reference (relative gradient 1e-8, gravity ramped in ``load_steps``) on linear tets at
  the levels ``linear_levels`` and on quadratic (10-node) tets at ``quadratic_levels``; each level halves the
  element size (level k: 60 x 8^k tets; level 3 is the issue's 30,720).
- The **mesh-converged tip deflection**: Richardson extrapolation of the quadratic levels (the observed order of the
  last three when there are three, else the assumed order 3: quadratic elements' displacement converges as h^3).
- Per linear level, the relative error of its tip deflection against that; **what it takes to reach 1 %**: the
  first level that does, or the level (and element count) extrapolated from the rate observed between the two
  finest levels (``sim.cases.cantilever.levels_to_reach``); the issue's "2.7 % at 30,720 tets" is compared when
  level 3 ran.
- **Locking** at nu = 0.49: linear tets with and without average nodal pressure against quadratic tets on the same
  case, each against the finest quadratic tip of that nu.

JSON-ready like the other cases (``cases.run_case`` calls :func:`run_discretisation`); :func:`section_html` draws it.
"""
from __future__ import annotations

import base64
import html
import io

import numpy as np

from sim.cases.cantilever import levels_to_reach, richardson, solve_cantilever

CASE = "cantilever"
TARGET = 0.01  # "what it takes to reach 1 %"
ISSUE_CLAIM = {"tets": 30720, "level": 3, "relative_error": 0.027,
               "source": "issue 17 item 1: linear tets at 30,720 elements are 2.7 % off the converged tip deflection"}
QUADRATIC_ORDER = 3.0  # assumed when fewer than three quadratic levels give no observed order

SWEEPS = {
    "full": {"base_cells": [10, 1, 1], "linear_levels": [0, 1, 2, 3], "quadratic_levels": [0, 1, 2], "load_steps": 8,
             "gravity_scale": 1.0, "locking": {"nu": 0.49, "linear_level": 2, "quadratic_levels": [0, 1]}},
    "quick": {"base_cells": [10, 1, 1], "linear_levels": [0, 1], "quadratic_levels": [0, 1], "load_steps": 8,
              "gravity_scale": 1.0, "locking": {"nu": 0.49, "linear_level": 1, "quadratic_levels": [0]}},
    # the test suite's: a cheaper beam at 1/1000 gravity (small deflection: one load step)
    "tiny": {"base_cells": [3, 1, 1], "linear_levels": [0, 1], "quadratic_levels": [0, 1], "load_steps": 1,
             "gravity_scale": 0.001, "locking": {"nu": 0.49, "linear_level": 0, "quadratic_levels": [0]}},
}


def work_units(sweep: dict) -> int:
    return len(sweep["linear_levels"]) + len(sweep["quadratic_levels"]) + 2 + len(sweep["locking"]["quadratic_levels"])


def run_discretisation(sweep: dict, tick=lambda: None) -> dict:
    base = tuple(sweep["base_cells"])

    def solve(level, quadratic, nu=None, anp=False):
        extra = {} if nu is None else {"nu": nu}
        row = solve_cantilever(level, quadratic, load_steps=sweep["load_steps"], gravity_scale=sweep["gravity_scale"],
                               anp=anp, base=base, **extra).as_dict()
        tick()
        return row

    quadratic = [solve(k, True) for k in sweep["quadratic_levels"]]
    linear = [solve(k, False) for k in sweep["linear_levels"]]
    extrapolation = richardson([r["tip_deflection"] for r in quadratic], QUADRATIC_ORDER)
    converged = extrapolation["extrapolated"]
    for row in quadratic + linear:
        row["relative_error"] = abs(row["tip_deflection"] - converged) / abs(converged)
    errors = [r["relative_error"] for r in linear]
    reach = levels_to_reach(errors, sweep["linear_levels"], TARGET, base)
    claim = {**ISSUE_CLAIM, "ours": None, "verdict": "not comparable",
             "reason": "level 3 (30,720 tets) not run at this level of the report (the full report runs it)"}
    if base == (10, 1, 1) and ISSUE_CLAIM["level"] in sweep["linear_levels"] and sweep["gravity_scale"] == 1.0:
        ours = errors[sweep["linear_levels"].index(ISSUE_CLAIM["level"])]
        close = abs(ours - ISSUE_CLAIM["relative_error"]) <= 0.5 * ISSUE_CLAIM["relative_error"]
        claim.update(ours=ours, verdict="reproduced" if close else "not reproduced",
                     reason=f"ours {100 * ours:.2f} % against the issue's 2.7 % (reproduced within a factor 1.5; the "
                            "issue does not name its tet pattern or measure, ours: 6 tets per cube, mean u_z of the end "
                            "face, Neo-Hookean 5.35)")
    lock = sweep["locking"]
    locking = {"nu": lock["nu"], "linear_level": lock["linear_level"],
               "linear": solve(lock["linear_level"], False, lock["nu"]),
               "linear_anp": solve(lock["linear_level"], False, lock["nu"], anp=True),
               "quadratic": [solve(k, True, lock["nu"]) for k in lock["quadratic_levels"]]}
    finest = locking["quadratic"][-1]["tip_deflection"]
    for key in ("linear", "linear_anp"):
        locking[key]["relative_to_quadratic"] = locking[key]["tip_deflection"] / finest
    return {"case": CASE, "title": "Discretisation error: the cantilever under gravity"
            + ("" if sweep["gravity_scale"] == 1.0 else f" x {sweep['gravity_scale']:g} (small deflection)"),
            "sweep": sweep,
            "quadratic": quadratic, "linear": linear, "richardson": extrapolation, "converged_tip_m": converged,
            "to_reach_1pct": reach, "issue_claim": claim, "locking": locking,
            "measures": {"converged_tip_m": converged, "linear_finest_error": errors[-1],
                         "quadratic_finest_error": quadratic[-1]["relative_error"]}}


# --- the HTML section ------------------------------------------------------------------------------------------

def num(value) -> str:
    return "–" if value is None else f"{value:.4g}" if isinstance(value, float) else html.escape(str(value))


def error_panel(ax, series, ylabel: str) -> None:
    """Error against tets on log-log axes, one line per ``(label, marker, tets, errors)`` of ``series`` (zero
    errors, the reference level itself, left out)."""
    for label, marker, tets, errors in series:
        ok = [(t, e) for t, e in zip(tets, errors) if e is not None and e > 0.0]
        if ok:
            ax.plot([t for t, _ in ok], [e for _, e in ok], marker=marker, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("tets")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)


def figure_png(case: dict) -> bytes:
    """Left: tip deflection against tets, linear and quadratic, the extrapolated value dashed. Right: the linear
    tets' relative error against tets (log-log) and the 1 % line."""
    import matplotlib

    matplotlib.use("Agg")  # off-screen
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(9.6, 3.8), dpi=80)
    for rows, label, marker in ((case["linear"], "linear tets", "o"), (case["quadratic"], "quadratic tets", "s")):
        left.plot([r["tets"] for r in rows], [r["tip_deflection"] for r in rows], marker=marker, label=label)
    left.axhline(case["converged_tip_m"], color="k", ls="--", lw=1, label="extrapolated (quadratic)")
    left.set_xscale("log")
    left.set_xlabel("tets")
    left.set_ylabel("tip deflection [m]")
    left.legend(fontsize=8)
    left.grid(True, which="both", alpha=0.3)
    right.axhline(TARGET, color="tab:red", ls=":", lw=1, label="1 %")
    reach = case["to_reach_1pct"]
    if reach["how"] == "extrapolated" and case["linear"]:
        last = case["linear"][-1]
        right.plot([last["tets"], reach["tets"]], [last["relative_error"], TARGET], "k:", lw=1,
                   label="observed rate, extrapolated")
    error_panel(right, [(label, marker, [r["tets"] for r in rows], [r["relative_error"] for r in rows])
                        for rows, label, marker in ((case["linear"], "linear tets", "o"),
                                                    (case["quadratic"], "quadratic tets", "s"))],
                "relative tip error [-]")
    fig.suptitle(case["title"] + (" (cached)" if case.get("cached") else ""), fontsize=10)
    return png_bytes(fig)


def png_bytes(fig) -> bytes:
    """The figure as PNG bytes (no software stamp, so the same data give the same bytes); closes it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", metadata={"Software": None})
    plt.close(fig)
    return buffer.getvalue()


def table(headers, rows, css: str = "discretisation") -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f'<table class="{css}"><tr>{head}</tr>{body}</table>'


def section_html(case: dict) -> str:
    sweep, rich, reach, claim, lock = (case["sweep"], case["richardson"], case["to_reach_1pct"], case["issue_claim"],
                                       case["locking"])
    png = base64.b64encode(figure_png(case)).decode("ascii")
    rows = [[("quadratic" if r["quadratic"] else "linear"), r["level"], r["tets"], r["nodes"], num(r["tip_deflection"]),
             num(r["tip_axial"]), f"{100 * r['relative_error']:.3g} %", r["newton_iterations"], num(r["wall_s"])]
            for r in case["linear"] + case["quadratic"]]
    if reach["how"] == "measured":
        reach_text = f"level {reach['level']} ({reach['tets']:,} tets) is within 1 %"
    elif reach["how"] == "extrapolated":
        reach_text = (f"not reached by the levels run; at the rate observed between the two finest levels "
                      f"({reach['rate']:.2f} halvings of the error per halving of h) about level {reach['level']:.1f}, "
                      f"{reach['tets']:,.0f} linear tets")
    else:
        reach_text = reach["how"]
    lock_rows = [["linear", lock["linear_level"], lock["linear"]["tets"], num(lock["linear"]["tip_deflection"]),
                  num(lock["linear"]["relative_to_quadratic"])],
                 ["linear + ANP", lock["linear_level"], lock["linear_anp"]["tets"],
                  num(lock["linear_anp"]["tip_deflection"]), num(lock["linear_anp"]["relative_to_quadratic"])]]
    lock_rows += [["quadratic", r["level"], r["tets"], num(r["tip_deflection"]), "1" if r is lock["quadratic"][-1]
                   else "–"] for r in lock["quadratic"]]
    cached = " <em>(cached)</em>" if case.get("cached") else ""
    return "\n".join([
        f'<h2 id="case-{CASE}">{html.escape(case["title"])}{cached}</h2>',
        f'<img class="figure" data-case="{CASE}" data-figure="discretisation" alt="tip deflection and error against '
        f'tets" src="data:image/png;base64,{png}">',
        f"<p>The quasi-static Newton reference on linear and quadratic (10-node) tets, beam cells "
        f"{sweep['base_cells']} x 2^level, gravity x {sweep['gravity_scale']:g} ramped in {sweep['load_steps']} load "
        f"steps. Tip deflection: minus the mean u_z of the end face. This is the error of the mesh alone; the "
        f"integrators' errors in the other sections are against the reference on their own mesh.</p>",
        f"<p><b>Mesh-converged tip deflection</b> (Richardson, quadratic levels {sweep['quadratic_levels']}, "
        f"{rich['order_source']} order {rich['order_used']:.2f}): <b>{case['converged_tip_m']:.5g} m</b> "
        f"(estimated error of the finest quadratic level {num(rich['error_estimate'])} m).</p>",
        f"<p><b>What it takes to reach 1 % with linear tets:</b> {html.escape(reach_text)}.</p>",
        f"<p>The issue's figure ({html.escape(claim['source'])}): <b>{claim['verdict']}</b>"
        + (f", ours {100 * claim['ours']:.2f} %" if claim["ours"] is not None else "")
        + f" — {html.escape(claim['reason'])}.</p>",
        table(["elements", "level", "tets", "nodes", "tip deflection [m]", "tip u_x [m]", "error", "Newton it.",
                "wall [s]"], rows),
        f"<h3>Near-incompressible locking (nu = {lock['nu']:g})</h3>"
        f"<p>Tip deflection relative to the finest quadratic level at the same nu.</p>",
        table(["elements", "level", "tets", "tip deflection [m]", "relative"], lock_rows),
    ])
