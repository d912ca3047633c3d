"""The accuracy report as one self-contained HTML file: matplotlib figures (Agg backend, embedded as
base64 PNG) of error against wall time per simulated second for each case with its Pareto front, and the
tables (points, reference convergence, rates, the theses' claims, what is not covered yet)."""
from __future__ import annotations

import base64
import html
import io
import math

import matplotlib

matplotlib.use("Agg")  # off-screen: no display on a render node
import matplotlib.pyplot as plt  # noqa: E402

from tissuerender.report import discretisation  # noqa: E402
from tissuerender.report import viscoelastic  # noqa: E402
from tissuerender.report import zhang_mesh  # noqa: E402

COLOURS = {"xpbd": "tab:blue", "ebm": "tab:orange", "explicit": "tab:red", "cnn": "tab:green",
           "cnn_chainmail": "tab:purple"}
MARKERS = {"xpbd": "o", "ebm": "s", "explicit": "^", "cnn": "D", "cnn_chainmail": "v"}


def _num(value) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.3g}" if math.isfinite(value) else str(value)
    return html.escape(str(value))


def figure_png(case: dict) -> bytes:
    """Error against wall time per simulated second, one marker per setting, the Pareto front joined."""
    points, key = case["points"], case["error_key"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=80)
    for name in dict.fromkeys(p["integrator"] for p in points):
        mine = [p for p in points if p["integrator"] == name and p.get(key) is not None]
        if case["case"] == "msd" and name == "cnn":
            for K in dict.fromkeys(p["settings"]["K"] for p in mine):
                sub = [p for p in mine if p["settings"]["K"] == K]
                ax.scatter([p["wall_s_per_sim_s"] for p in sub], [p[key] for p in sub], marker=MARKERS[name],
                           label=f"cnn K={K:g}", alpha=0.8)
            continue
        ax.scatter([p["wall_s_per_sim_s"] for p in mine], [p[key] for p in mine], marker=MARKERS.get(name, "o"),
                   color=COLOURS.get(name), label=name, alpha=0.8)
    front = [points[i] for i in case["pareto"]]
    ax.plot([p["wall_s_per_sim_s"] for p in front], [p[key] for p in front], "k-", lw=1.5, zorder=0,
            label="Pareto front")
    ax.scatter([p["wall_s_per_sim_s"] for p in front], [p[key] for p in front], s=140, facecolors="none",
               edgecolors="k", zorder=3)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time per simulated second [s/s]")
    ax.set_ylabel(case["error_label"])
    ax.set_title(case["title"] + (" (cached)" if case.get("cached") else ""), fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def line_png(case: dict) -> bytes:
    """Zhang Figs. 5.5(c)-5.7(c): the measured displacement component along the measurement line, the
    reference's and, per integrator, its most accurate setting's (and EBM at 20 iterations, the thesis's)."""
    ref = case["reference"]
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=80)
    ax.plot(ref["line_coord_m"], ref["line_u_m"], "k-", lw=2, label="reference")
    chosen = {}
    for p in case["points"]:
        if p.get("line_u_m") is None:
            continue
        best = chosen.get(p["integrator"])
        if best is None or p["rel_l2"] < best["rel_l2"]:
            chosen[p["integrator"]] = p
    ebm20 = [p for p in case["points"] if p["integrator"] == "ebm" and p["settings"].get("iterations") == 20
             and p.get("line_u_m") is not None]
    for p in [*chosen.values(), *[q for q in ebm20 if q is not chosen.get("ebm")]]:
        ax.plot(ref["line_coord_m"], p["line_u_m"], marker=MARKERS.get(p["integrator"], "o"), ms=4, lw=1,
                color=COLOURS.get(p["integrator"]), alpha=0.8, label=f"{p['integrator']} {p['setting']}")
    ax.set_xlabel("position along the measurement line [m]")
    ax.set_ylabel(f"u_{ref['line_component']} [m]")
    ax.set_title(f"{case['title']}: u_{ref['line_component']} along the measurement line", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    return _png(fig)


def _png(fig) -> bytes:
    """The figure as PNG bytes (no software stamp, so the same data give the same bytes); closes it."""
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", metadata={"Software": None})
    plt.close(fig)
    return buffer.getvalue()


def _table(headers: list[str], rows: list[list], cls: str = "") -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" for row in rows)
    return f'<table class="{cls}"><tr>{head}</tr>{body}</table>'


def _unstable(point: dict) -> str:
    """What a finished run's end state shows (``inverted_tets`` and ``finite`` where the case measures them)."""
    if point.get("finite") is False:
        return "non-finite positions at the end"
    return f"{point['inverted_tets']} inverted tets at the end" if point.get("inverted_tets") else ""


def _case_section(case: dict) -> str:
    name = case["case"]
    if name in SECTIONS:
        return SECTIONS[name](case)
    parts = [f'<h2 id="case-{name}">{html.escape(case["title"])}{" <em>(cached)</em>" if case["cached"] else ""}</h2>']
    if name == "rates":
        parts.append(f"<p>{html.escape(case['statistic'])}, one process, wall time.</p>")
        parts.append(_table(["run", "integrator", "nodes", "tets", "dt [s]", "steps/s"],
                            [[r["run"], r["integrator"], r["nodes"], r["tets"], _num(r["dt_s"]), _num(r["steps_per_s"])]
                             for r in case["rows"]]))
        return "\n".join(parts)
    png = base64.b64encode(figure_png(case)).decode("ascii")
    parts.append(f'<img class="figure" data-case="{name}" data-figure="error-time" alt="error against time, {name}" '
                 f'src="data:image/png;base64,{png}">')
    if "line_u_m" in case.get("reference", {}):
        png = base64.b64encode(line_png(case)).decode("ascii")
        parts.append(f'<img class="figure" data-case="{name}" data-figure="line" alt="displacement along the line, '
                     f'{name}" src="data:image/png;base64,{png}">')
    if case.get("error_fields"):
        parts.append(error_field_html(case))
    ref = case["reference"]
    parts.append(f"<p>Reference: {html.escape(ref['kind'])}"
                 + (f"; mesh {case['mesh']['nodes']} nodes, {case['mesh']['tets']} tets; reference wall time "
                    f"{_num(ref['wall_s'])} s" if "mesh" in case else "") + ".</p>")
    conv = case["convergence"]
    if "orders" in conv:
        parts.append(f"<p>Reference convergence: {html.escape(conv['what'])} at steps {conv['dts']}: observed order "
                     f"{', '.join(_num(o) for o in conv['orders'])} (expected {conv['expected_order']}).</p>")
    else:
        parts.append(f"<p>Reference check: {html.escape(conv['what'])}: {_num(conv['relative_difference'])}.</p>")
    front = set(case["pareto"])
    mesh = "line_max_m" in {k for p in case["points"] for k in p}
    headers = ["integrator", "setting", "error", *(["line max [m]", "line mean [m]", "line RMSE [m]", "RED"] if mesh else []),
               "wall [s]", "wall / sim s", "Pareto", "failure"]
    rows = []
    for i, p in enumerate(case["points"]):
        extra = [_num(p.get(k)) for k in ("line_max_m", "line_mean_m", "line_rmse_m", "red")] if mesh else []
        rows.append([p["integrator"], html.escape(p["setting"]), _num(p.get(case["error_key"])), *extra,
                     _num(p["wall_s"]), _num(p["wall_s_per_sim_s"]), "&#9679;" if i in front else "",
                     html.escape(p["diverged"] or _unstable(p))])
    for name, why in case.get("not_applicable", {}).items():
        parts.append(f"<p>{html.escape(name)}: not applicable here ({html.escape(why)}).</p>")
    parts.append(f"<p>Error: {html.escape(case['error_label'])}.</p>")
    parts.append(_table(headers, rows))
    return "\n".join(parts)


def sweep_png(points: list[dict], pareto: list[int], error_key: str, time_key: str, xlabel: str, ylabel: str,
              title: str) -> bytes:
    """One sweep's error against its cost per frame, the scene's own setting starred, the Pareto front joined."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=80)
    ok = [p for p in points if p.get(error_key) is not None and p[error_key] > 0.0]
    ax.scatter([p[time_key] for p in ok], [p[error_key] for p in ok], color="tab:blue", label="settings")
    for p in ok:
        ax.annotate(p["label"], (p[time_key], p[error_key]), fontsize=6, xytext=(3, 3), textcoords="offset points")
    mine = [p for p in ok if p.get("scene")]
    ax.scatter([p[time_key] for p in mine], [p[error_key] for p in mine], marker="*", s=200, color="tab:red",
               zorder=4, label="the scene's")
    front = [points[i] for i in pareto if points[i] in ok]
    ax.plot([p[time_key] for p in front], [p[error_key] for p in front], "k-", lw=1.2, zorder=0, label="Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def _img(png: bytes, figure: str, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img class="figure" data-figure="{figure}" alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def error_field_html(case: dict) -> str:
    """The case's error-field picture (``pictures.py``), or why it is missing (no pyvista, no OpenGL)."""
    from tissuerender.report.pictures import error_field_png

    try:
        png = error_field_png(case["error_fields"])
    except Exception as e:  # noqa: BLE001 - a missing picture must not lose the report's numbers
        return f"<p>Error-field picture not drawn: {html.escape(type(e).__name__)}: {html.escape(str(e)[:200])}</p>"
    data = base64.b64encode(png).decode("ascii")
    return (f'<img class="figure" data-case="{case["case"]}" data-figure="error-field" alt="error field on the '
            f'deformed mesh, {case["case"]}" src="data:image/png;base64,{data}">'
            "<p>The outer surface of the most and the least accurate setting, each deformed by its own displacement "
            "and coloured by |u - u_ref| per node (viridis from 0 to that setting's largest error).</p>")


def scene_section(scene: dict) -> str:
    """The user's scene (``scene.py``): both sweeps, the reference, and the cheapest setting within the budget."""
    budget = ", ".join(f"{k} {_num(v)}" for k, v in scene["budget"].items())
    parts = [f'<h2 id="scene">Your scene: {html.escape(scene["name"])} ({html.escape(scene["path"])})</h2>',
             f"<p>Budget: {html.escape(budget)} (sim: relative L2 displacement error, largest over the frames; "
             "flip: mean FLIP; rmse: relative RMSE of the HDR).</p>"]
    sim = scene["simulation"]
    cached = " <em>(cached)</em>" if sim.get("cached") else ""
    if "skipped" in sim:
        parts.append(f"<h3>Simulation{cached}</h3><p>Not measured: {html.escape(sim['skipped'])}.</p>")
    else:
        ref = sim["reference"]
        parts.append(f"<h3>Simulation: {html.escape(sim['integrator'])}{cached}</h3>")
        parts.append(_img(sweep_png(sim["points"], sim["pareto"], "rel_l2", "wall_s_per_frame",
                                    "simulation wall time per frame [s]", "relative L2 displacement error [-]",
                                    f"{scene['name']}: simulation, {sim['frames']} frames"), "scene-simulation",
                          "simulation error against time per frame"))
        parts.append(f"<p>Reference: {html.escape(ref['kind'])}. Its own convergence ({html.escape(ref['what'])}): "
                     f"{', '.join(_num(d) for d in ref['differences'])} at steps "
                     f"{', '.join(_num(h) for h in ref['levels_s'])} s ({'falls' if ref['falls'] else 'does NOT fall'}"
                     f" under refinement).</p>")
        if "discretisation" in sim:  # the mesh's own error, apart from the solver's (scene.py)
            disc = sim["discretisation"]
            parts.append(f"<p><b>Discretisation error</b> (the scene's mesh against {html.escape(disc['kind'])}, "
                         f"{disc['tets']} tets): <b>{_num(disc['rel_l2'])}</b>; {html.escape(disc['what'])}.</p>")
        parts.append(f"<p><b>Cheapest within the budget:</b> {html.escape(sim['cheapest']['text'])}.</p>")
        parts.append(_table(["setting", "substeps", "iterations", "error (max over frames)", "+ mesh (bound)",
                             "wall [s] / frame", "Pareto", "failure"],
                            [[html.escape(p["label"]), p["substeps"], p["iterations"], _num(p["rel_l2"]),
                              _num(p.get("rel_l2_with_mesh")),
                              _num(p["wall_s_per_frame"]), "&#9679;" if i in sim["pareto"] else "",
                              html.escape(p["diverged"] or "")] for i, p in enumerate(sim["points"])]))
    ren = scene["rendering"]
    cached = " <em>(cached)</em>" if ren.get("cached") else ""
    parts.append(f"<h3>Rendering, frame {ren['frame']} at {ren['resolution'][0]}x{ren['resolution'][1]}{cached}</h3>")
    parts.append(_img(sweep_png(ren["points"], ren["pareto"], "flip", "seconds", "render time per frame [s]",
                                "mean FLIP [-]", f"{scene['name']}: rendering"), "scene-rendering",
                      "FLIP against render time per frame"))
    parts.append(f"<p>Reference: {html.escape(ren['reference']['kind'])} ({_num(ren['reference']['seconds'])} s).</p>")
    parts.append(f"<p><b>Cheapest within the budget:</b> {html.escape(ren['cheapest']['text'])}.</p>")
    parts.append(_table(["setting", "light samples", "supersampling", "FLIP", "relative RMSE", "seconds / frame",
                         "Pareto"],
                        [[html.escape(p["label"]), p["samples"], p["supersampling"], _num(p["flip"]),
                          _num(p["rel_rmse"]), _num(p["seconds"]), "&#9679;" if i in ren["pareto"] else ""]
                         for i, p in enumerate(ren["points"])]))
    return "\n".join(parts)


def stages_png(costs: dict) -> bytes:
    """Qian Fig. 7.7's spirit: one stacked bar per shipped scene, the seconds per frame of each stage."""
    rows = costs["scenes"]
    stages = list(dict.fromkeys(name for r in rows for name in r["per_frame_s"]))
    fig, ax = plt.subplots(figsize=(7.2, 4.4), dpi=80)
    bottom = [0.0] * len(rows)
    cmap = plt.get_cmap("tab20")
    for k, name in enumerate(stages):
        heights = [r["per_frame_s"].get(name, 0.0) for r in rows]
        ax.bar([r["scene"] for r in rows], heights, bottom=bottom, label=name, color=cmap(k % 20))
        bottom = [b + h for b, h in zip(bottom, heights)]
    ax.set_ylabel("seconds per frame")
    ax.set_title(f"per-stage cost of a frame ({costs['numba_threads']} numba thread(s))", fontsize=10)
    ax.tick_params(axis="x", labelsize=8)
    ax.legend(fontsize=6, ncol=2, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return _png(fig)


def stage_section(costs: dict, machine: dict) -> str:
    cached = " <em>(cached)</em>" if costs.get("cached") else ""
    parts = [f'<h2 id="stage-costs">Per-stage cost of a frame, every shipped scene{cached}</h2>',
             f"<p>{html.escape(str(machine['processor'] or machine['machine']))}, {machine['cpus']} cpus, "
             f"{costs['numba_threads']} numba thread(s); each scene's first {costs['sweep']['frames']} frames through "
             "the pipeline, at the resolution given below, after an untimed run of the same frames"
             + ("" if costs["sweep"]["warm"] else " (skipped at this level: the figures include numba's cache loading)")
             + ". Setup (meshing, loading surfaces) is listed apart. Stages with no timing of their own are part of "
             "the stage named.</p>", _img(stages_png(costs), "stage-costs", "per-stage cost of a frame")]
    stages = list(dict.fromkeys(name for r in costs["scenes"] for name in r["per_frame_s"]))
    rows = []
    for r in costs["scenes"]:
        inside = "; ".join(f"{k} in {v}" for k, v in r["timed_inside"].items())
        rows.append([html.escape(r["scene"]), f"{r['resolution'][0]}x{r['resolution'][1]}", _num(r["frame_s"]),
                     *[_num(r["per_frame_s"].get(n)) for n in stages],
                     _num(sum(r["setup_s"].values())), html.escape(inside)])
    parts.append(_table(["scene", "resolution", "frame [s]", *stages, "setup [s]", "timed inside"], rows))
    return "\n".join(parts)


FAMILY_MARKERS = {"uniform sampling": "o", "adaptive sampling": "s", "importance sampling": "D",
                  "ratio estimator": "^", "penumbra re-shading": "v", "reflection cone": "P", "SSS off": "X",
                  "no supersampling": "x"}


def render_sweep_png(scene: dict) -> bytes:
    """FLIP against seconds per frame for one scene's rendering sweep, one marker per option family."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=80)
    points = scene["points"]
    for family, marker in FAMILY_MARKERS.items():
        mine = [p for p in points if p["family"] == family and p["flip"] > 0.0]
        if mine:
            ax.scatter([p["seconds"] for p in mine], [p["flip"] for p in mine], marker=marker, label=family, alpha=0.8)
    front = [points[i] for i in scene["pareto"]]
    ax.plot([p["seconds"] for p in front], [p["flip"] for p in front], "k-", lw=1.2, zorder=0, label="Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("render time per frame [s]")
    ax.set_ylabel("mean FLIP against the reference [-]")
    ax.set_title(f"{scene['scene']} at {scene['resolution'][0]}x{scene['resolution'][1]}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return _png(fig)


def render_sweeps_section(sweeps: dict) -> str:
    cached = " <em>(cached)</em>" if sweeps.get("cached") else ""
    parts = [f'<h2 id="render-sweeps">Rendering: what each option buys and costs{cached}</h2>',
             "<p>Frame 1 of each scene, every setting at 2x2 supersampling unless marked 1x1, against a uniform, "
             "high-sample, 2x2, Monte Carlo reference of the same frame; FLIP of the tone-mapped images and relative "
             "RMSE of the HDR against seconds per frame (render_hdr only). See docs/report.md.</p>"]
    for scene in sweeps["scenes"]:
        cost = scene["painted_cost"]
        parts.append(f"<h3>{html.escape(scene['scene'])}</h3>")
        parts.append(_img(render_sweep_png(scene), "render-sweep", f"FLIP against time, {scene['scene']}"))
        parts.append(f"<p>Reference: {html.escape(scene['reference']['kind'])} ({_num(scene['reference']['seconds'])} s). "
                     f"Painted against adaptive sampling at {cost['samples']} samples: {_num(cost['importance_s'])} s "
                     f"against {_num(cost['adaptive_s'])} s ({100 * cost['extra_fraction']:+.1f} %).</p>")
        parts.append(_table(["setting", "option", "FLIP", "relative RMSE", "seconds", "Pareto"],
                            [[html.escape(p["label"]), html.escape(p["family"]), _num(p["flip"]), _num(p["rel_rmse"]),
                              _num(p["seconds"]), "&#9679;" if i in scene["pareto"] else ""]
                             for i, p in enumerate(scene["points"])]))
    return "\n".join(parts)


def indentation_png(case: dict) -> bytes:
    """Tool force against depth, XPBD's and the reference's, with the relative difference on a second axis."""
    rows = case["rows"]
    depth = [r["depth_mm"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=80)
    ax.plot(depth, [r["reference_fz_N"] for r in rows], "k-o", label="reference reaction (Newton)")
    ax.plot(depth, [r["xpbd_fz_N"] for r in rows], "s--", color="tab:blue", label="XPBD tool force")
    ax.set_xlabel("indentation depth [mm]")
    ax.set_ylabel("force on the tool, z [N]")
    ax.grid(True, alpha=0.3)
    right = ax.twinx()
    right.plot(depth, [100 * r["relative_difference"] for r in rows], "^:", color="tab:red", label="XPBD / ref - 1")
    right.set_ylabel("XPBD / reference - 1 [%]", color="tab:red")
    lines = ax.get_legend_handles_labels()
    more = right.get_legend_handles_labels()
    ax.legend(lines[0] + more[0], lines[1] + more[1], fontsize=8, loc="upper left")
    ax.set_title(case["title"], fontsize=9)
    return _png(fig)


def variational_png(case: dict) -> bytes:
    """Variational error against iterations, XPBD and Newton, log-log."""
    fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=80)
    for solver, style in (("xpbd (model)", "o-"), ("xpbd (stable_neo_hookean)", "v--"), ("newton", "s-")):
        rows = [r for r in case["rows"] if r["solver"] == solver and r["variational_error"] is not None]
        ax.plot([r["iterations"] for r in rows], [max(abs(r["variational_error"]), 1e-17) for r in rows], style,
                label=solver)
    ax.axhline(1e-4, color="tab:blue", ls=":", label="Qian: XPBD 1e-4 at 100 iterations")
    ax.axhline(1e-5, color="tab:orange", ls=":", label="Qian: Newton 1e-5 at 7 iterations")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("iterations")
    ax.set_ylabel("|variational error| (Qian eq. 4.45) [-]")
    ax.set_title(case["title"], fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return _png(fig)


def mitsuba_png(case: dict) -> bytes:
    """FLIP (left) and brightness ratio (right) of ours against Mitsuba over our light samples, one line a scene."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(8.4, 3.6), dpi=80)
    for s in case["scenes"]:
        m = [p["samples"] for p in s["points"]]
        line, = left.plot(m, [p["flip"] for p in s["points"]], "o-", label=s["scene"])
        if s["mitsuba_self_flip"] is not None and math.isfinite(s["mitsuba_self_flip"]):
            left.axhline(s["mitsuba_self_flip"], color=line.get_color(), ls=":", lw=1)
        right.plot(m, [p["brightness_ratio"] for p in s["points"]], "o-", color=line.get_color(), label=s["scene"])
    left.set_xscale("log", base=2)
    left.set_yscale("log")
    left.set_xlabel("our light samples (2x2 supersampling)")
    left.set_ylabel("mean FLIP against Mitsuba [-]")
    left.set_title("FLIP; dotted: Mitsuba spp/4 against spp", fontsize=9)
    right.axhline(1.0, color="k", lw=0.8)
    right.set_xscale("log", base=2)
    right.set_xlabel("our light samples")
    right.set_ylabel("mean(ours) / mean(Mitsuba)")
    right.set_title("brightness ratio", fontsize=9)
    for ax in (left, right):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    return _png(fig)


def indentation_section(case: dict) -> str:
    rows = case["rows"]
    setup = case["setup"]
    parts = [f'<h2 id="case-indentation">{html.escape(case["title"])}{" <em>(cached)</em>" if case["cached"] else ""}</h2>',
             f"<p>A sphere (R = {setup['sphere_radius_m']:g} m) pressed quasi-statically into a {setup['block_m']:g} m "
             f"block ({setup['cells']}^3 cells, {setup['constitutive']}, E {setup['E_Pa']:g} Pa, nu {setup['nu']:g}) "
             f"clamped at its base; XPBD {setup['substeps']} substeps x {setup['iterations']} iterations, "
             f"{setup['steps']} steps of {setup['dt']:g} s. The reference is the quasi-static Newton solution with "
             "the touched nodes held at XPBD's positions; its reaction is the elastic force at those nodes "
             "(tissuerender/report/indentation.py).</p>",
             _img(indentation_png(case), "indentation", "force against indentation")]
    parts.append(_table(["depth [mm]", "touched nodes", "XPBD f_z [N]", "reference f_z [N]", "XPBD / reference - 1",
                         "XPBD wall [s]", "reference wall [s]"],
                        [[_num(r["depth_mm"]), r["contact_nodes"], _num(r["xpbd_fz_N"]), _num(r["reference_fz_N"]),
                          f"{100 * r['relative_difference']:+.2f} %", _num(r["xpbd_wall_s"]), _num(r["reference_wall_s"])]
                         for r in rows]))
    return "\n".join(parts)


def variational_section(case: dict) -> str:
    setup, ref = case["setup"], case["reference"]
    parts = [f'<h2 id="case-liver_variational">{html.escape(case["title"])}{" <em>(cached)</em>" if case["cached"] else ""}</h2>',
             f"<p>The liver of {html.escape(setup['scene'])} ({setup['nodes']} nodes, {setup['tets']} tets, "
             f"{html.escape(setup['constitutive'])}): {html.escape(setup['what'])}, h = {_num(setup['h_s'])} s. Variational "
             "error (Qian eq. 4.45 on the implicit-Euler objective with its inertia term): (f(x_k) - f(x*)) / "
             f"(f(x_0) - f(x*)); x* by {html.escape(ref['kind'])} ({ref['iterations']} iterations). XPBD runs one substep "
             "with the model's energy as one constraint per tet (material = model) and with its default stable "
             "Neo-Hookean constraints (tissuerender/report/variational.py).</p>",
             _img(variational_png(case), "variational", "variational error against iterations")]
    parts.append(_table(["solver", "iterations", "variational error", "relative L2 to x*", "wall [s]"],
                        [[html.escape(r["solver"]), r["iterations"], _num(r["variational_error"]), _num(r.get("rel_l2")),
                          _num(r["wall_s"])] for r in case["rows"]]))
    return "\n".join(parts)


def mitsuba_section(case: dict) -> str:
    cached = " <em>(cached)</em>" if case.get("cached") else ""
    head = f'<h2 id="case-mitsuba">Rough plastic against Mitsuba 3{cached}</h2>'
    if "skipped" in case:
        return f"{head}<p>{html.escape(case['skipped'])}.</p>"
    sweep = case["sweep"]
    parts = [head, f"<p>Mitsuba {html.escape(case['mitsuba_version'])} (scalar_rgb, direct illumination, "
             f"{sweep['spp']} spp, box filter) against ours (uniform light sampling, Monte Carlo, 2x2 supersampling) "
             "on the rendering sweeps' scenes with every object plastic, no SSS or lens. As our light samples grow, "
             "FLIP falls to a floor: what no sample count removes (the models' difference and our 2x2 pixel sampling "
             "against Mitsuba's fully sampled pixels); dotted, Mitsuba's own noise (spp/4 against spp) "
             "(tissuerender/report/mitsuba.py).</p>", _img(mitsuba_png(case), "mitsuba", "FLIP and brightness against Mitsuba")]
    rows = []
    for s in case["scenes"]:
        for p in s["points"]:
            rows.append([html.escape(s["scene"]), f"{s['resolution'][0]}x{s['resolution'][1]}", p["samples"],
                         _num(p["flip"]), _num(p["brightness_ratio"]), _num(p["rel_rmse"]), _num(p["seconds"]),
                         _num(s["mitsuba_self_flip"]), _num(s["mitsuba_s"])])
    parts.append(_table(["scene", "resolution", "our samples", "FLIP", "mean ours / Mitsuba", "relative RMSE",
                         "ours [s]", "Mitsuba self-FLIP", "Mitsuba [s]"], rows))
    return "\n".join(parts)


def cnn_cube_section(case: dict) -> str:
    setup = case["setup"]
    m = case["measures"]
    parts = [f'<h2 id="case-cnn_cube">{html.escape(case["title"])}{" <em>(cached)</em>" if case["cached"] else ""}</h2>',
             f"<p>{setup['nodes']} nodes, {setup['tets']} tets, linear FEM forces, Rayleigh beta "
             f"{_num(setup['rayleigh_beta'])} s, K = {_num(setup['K'])}. At {_num(setup['small_dt'])} s the CNN and "
             f"explicit integration differ by at most {_num(m['small_step_difference_m'])} m after "
             f"{_num(setup['small_t'])} s (sag of the top centre {_num(m['small_step_sag_m'])} m) "
             "(tissuerender/report/cnn_cube.py).</p>",
             _table(["run", "simulated [s]", "peak displacement [m]", "failure", "wall [s]"],
                    [[r["run"], _num(r["simulated_s"]), _num(r["peak_m"]), html.escape(r["diverged"] or ""),
                      _num(r["wall_s"])] for r in case["rows"]])]
    return "\n".join(parts)


SECTIONS = {"cnn_cube": cnn_cube_section, "indentation": indentation_section,
            "liver_variational": variational_section, "mitsuba": mitsuba_section,
            discretisation.CASE: discretisation.section_html, zhang_mesh.CASE: zhang_mesh.section_html}
SECTIONS[viscoelastic.CASE] = viscoelastic.section_html


def render_html(report: dict) -> str:
    cases = report["cases"]
    claims = _table(
        ["claim", "source", "statement", "thesis", "thesis hardware", "ours", "verdict", "why"],
        [[f'<span class="claim" id="claim-{c["id"]}">{c["id"]}</span>', html.escape(c["source"]),
          html.escape(c["statement"]), _num(c["thesis_value"]) + (f" {c['unit']}" if c["thesis_value"] is not None else ""),
          html.escape(c["hardware"]), _num(c["ours"]), f'<b class="{c["verdict"].replace(" ", "-")}">{c["verdict"]}</b>',
          html.escape(c["reason"])] for c in report["claims"]], "claims")
    # a scene's own report with no theses' case or sweep run has nothing to compare: the table would be all
    # "not comparable"
    compared = report["cases"] or report.get("render_sweeps")
    claims = f'<h2 id="claims">The thesis\'s claims, side by side</h2>\n{claims}' if compared else ""
    machine = report["machine"]
    versions = ", ".join(f"{k} {v}" for k, v in report["versions"].items())
    body = "\n".join(_case_section(case) for case in cases.values())
    if report.get("render_sweeps"):
        body += "\n" + render_sweeps_section(report["render_sweeps"])
    if report.get("stage_costs"):
        body += "\n" + stage_section(report["stage_costs"], report["machine"])
    if report.get("scene"):
        body = scene_section(report["scene"]) + "\n" + body
    not_covered = "".join(f"<li>{html.escape(item)}</li>" for item in report["not_covered"])
    if not_covered:
        not_covered = f'<h2 id="not-covered">Not covered by this report yet</h2><ul>{not_covered}</ul>'

    style = ("body{font-family:sans-serif;max-width:70em;margin:1em auto;padding:0 1em}"
             "table{border-collapse:collapse;margin:.5em 0;font-size:90%}td,th{border:1px solid #bbb;padding:2px 6px}"
             ".reproduced{color:#060}.not-reproduced{color:#a00}.not-comparable{color:#666}img{max-width:100%}")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>tissuerender accuracy report</title>
<style>{style}</style></head><body>
<h1>Accuracy report: what accuracy costs in time</h1>
<p>Command: <code>{html.escape(report['command'])}</code> (sweeps: {report['level']}); created {report['created_utc']};
{_num(report['wall_s'])} s. Machine: {html.escape(str(machine['processor'] or machine['machine']))}, {machine['cpus']} cpus,
{machine['numba_threads']} numba thread(s), load average {_num(machine['load_average_at_start'])} at the start.
Versions: {html.escape(versions)}. Every number below was measured in this run, or is a stored case of the same
settings and code (marked cached); only the theses' values are typed in, with their source.</p>
<p>How to read it: each figure plots, per case, the error of every integrator setting against the wall time it
takes per simulated second (log-log, lower-left is better); circled points joined by the black line are the
Pareto front (no other setting is both faster and more accurate). See docs/report.md.</p>
{claims}
{body}
{not_covered}
</body></html>
"""
