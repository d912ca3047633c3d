"""The accuracy report's figures as text: per case, each integrator setting's error and wall time per simulated
second (Pareto front marked), the reference's observed convergence order, and the thesis claims' verdicts.
Runs ``tissuerender report accuracy`` in-process (``tissuerender.report.accuracy.run_report``).

Also the rendering sweeps (FLIP and seconds per frame per setting), every shipped scene's per-stage frame cost, and
with ``--scene FILE`` that scene's report instead (its sweeps and the cheapest settings within ``--budget``).

Usage: .venv/bin/python benchmarks/report_accuracy.py [--quick] [-o DIR] [--scene FILE [--budget sim=1%,flip=0.002]]
(DIR defaults to a fresh temporary folder, so nothing is reused from an earlier run.)
The last line is one JSON object: {"wall_s": ..., "part_wall_s": {...},
"<case>_<integrator>_<setting>_err": ..., "..._s_per_sim_s": ..., "claims": {...},
"render_<scene>_<setting>_flip": ..., "stage_<scene>_frame_s": ..., "scene_<part>_cheapest": ...}.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile

# benchmarks/postfx.py would shadow the postfx package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

from tissuerender import load_scene  # noqa: E402
from tissuerender.report.accuracy import run_report  # noqa: E402
from tissuerender.report.scene import parse_budget  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the --quick report: coarse meshes, fewer settings")
    parser.add_argument("-o", "--out", default=None, help="report folder (default: a new temporary folder)")
    parser.add_argument("--scene", default=None, help="a scene file: its own report")
    parser.add_argument("--budget", default=None, help="with --scene: e.g. sim=1%%,flip=0.002")
    args = parser.parse_args()
    out = args.out or tempfile.mkdtemp(prefix="report_accuracy_")
    scene = load_scene(args.scene) if args.scene else None
    report = run_report(out, quick=args.quick, scene=scene, budget=parse_budget(args.budget))
    result: dict = {"wall_s": round(report["wall_s"], 1),
                    "part_wall_s": {k: round(v, 1) for k, v in report["part_wall_s"].items()}}
    for name, case in report["cases"].items():
        if name == "indentation":
            for row in case["rows"]:
                print(f"indentation {row['depth_mm']:5.1f} mm: xpbd {row['xpbd_fz_N']:.4g} N, reference "
                      f"{row['reference_fz_N']:.4g} N ({100 * row['relative_difference']:+.2f} %)")
                result[f"indentation_{row['depth_mm']:g}mm_rel_diff"] = float(f"{row['relative_difference']:.4g}")
            continue
        if name == "liver_variational":
            for row in case["rows"]:
                print(f"liver variational error {row['solver']:26s} {row['iterations']:5d} it: "
                      f"{row['variational_error']:.3g}")
            result.update({f"liver_{k}": v for k, v in case["measures"].items()})
            continue
        if name == "cnn_cube":
            print(f"cnn cube: {case['measures']}")
            continue
        if name == "mitsuba":
            for scene in case.get("scenes", []):
                for p in scene["points"]:
                    print(f"mitsuba {scene['scene']:14s} m{p['samples']:<4d} FLIP {p['flip']:.4f} "
                          f"brightness {p['brightness_ratio']:.4f}")
                result[f"mitsuba_{scene['scene']}_floor_flip"] = float(f"{scene['floor_flip']:.4g}")
            if "skipped" in case:
                print(f"mitsuba: {case['skipped']}")
            continue
        if name == "rates":
            for row in case["rows"]:
                print(f"{row['run']:32s} {row['steps_per_s']:10.1f} steps/s")
                result[f"{row['run']}_hz"] = round(row["steps_per_s"], 1)
            continue
        if name == "cantilever":  # tissuerender/report/discretisation.py
            for row in case["linear"] + case["quadratic"]:
                kind = "quadratic" if row["quadratic"] else "linear"
                print(f"cantilever {kind:9s} level {row['level']} {row['tets']:7d} tets tip {row['tip_deflection']:.5f} m "
                      f"error {100 * row['relative_error']:.3g} %")
                result[f"cantilever_{kind}_L{row['level']}_err"] = float(f"{row['relative_error']:.4g}")
            result["cantilever_converged_tip_m"] = float(f"{case['converged_tip_m']:.6g}")
            continue
        if name == "viscoelastic_cube":  # tissuerender/report/viscoelastic.py
            for key in ("prony_thesis_strain", "prony_small_strain"):
                c = case[key]
                print(f"viscoelastic cube, strain {c['strain']:g}: F(end)/F_el {c['ratio']:.5f} (predicted "
                      f"{c['predicted_ratio']:.5f}), tau {c['tau_s']:.4f} s (history update "
                      f"{c['tau_discrete_s']:.4f} s)")
            for p in case["points"]:
                err = p.get("rel_l2")
                print(f"  {p['integrator']} {p['setting']:20s} " + (f"failed: {p['diverged'][:60]}" if err is None else
                      f"{err:10.4g} (last 2 s {p['late_rel_l2']:.4g}) {p['wall_s_per_sim_s']:10.4g} s/s"))
                key = f"{name}_{p['integrator']}_{p['setting'].replace(' ', '').replace(',', '_')}"
                result[f"{key}_err"] = None if err is None else float(f"{err:.4g}")
                result[f"{key}_s_per_sim_s"] = float(f"{p['wall_s_per_sim_s']:.4g}")
            result["viscoelastic_cube_tau_s"] = float(f"{case['measures']['tau_s']:.5g}")
        if name == "zhang_mesh":  # tissuerender/report/zhang_mesh.py
            for zhang, levels in case["cases"].items():
                print(f"{zhang}: converged by {levels['converged']['how']}")
                for element in ("linear", "linear_anp", "quadratic"):
                    for row in levels[element]:
                        print(f"  {element:10s} level {row['level']} {row['tets']:7d} tets mid {row['mid_u_m']:.5f} m "
                              f"line max {row['line_max_m']:.4g} m RMSE {row['line_rmse_m']:.4g} m")
            result.update({f"zhang_mesh_{k}": float(f"{v:.4g}") for k, v in case["measures"].items()})
            continue
        print(f"\n{case['title']} ({case['error_label']}; reference order "
              f"{', '.join(f'{o:.2f}' for o in case['convergence']['orders'])}, expected "
              f"{case['convergence']['expected_order']})")
        front = set(case["pareto"])
        for i, p in enumerate(case["points"]):
            err = p.get(case["error_key"])
            label = f"{p['integrator']} {p['setting']}"
            text = "failed: " + p["diverged"][:60] if err is None else f"{err:10.4g}"
            print(f"  {label:28s} {text:>10s} {p['wall_s_per_sim_s']:10.4g} s/s {'pareto' if i in front else ''}")
            key = f"{name}_{p['integrator']}_{p['setting'].replace(' ', '').replace(',', '_')}"
            result[f"{key}_err"] = None if err is None else float(f"{err:.4g}")
            result[f"{key}_s_per_sim_s"] = float(f"{p['wall_s_per_sim_s']:.4g}")
    for sweep in (report.get("render_sweeps") or {}).get("scenes", []):
        print(f"\nrendering sweep {sweep['scene']} {sweep['resolution']} (FLIP, relative RMSE, seconds)")
        for p in sweep["points"]:
            print(f"  {p['label']:30s} {p['flip']:9.2e} {p['rel_rmse']:9.2e} {p['seconds']:8.3f}")
            result[f"render_{sweep['scene']}_{p['label'].replace(' ', '')}_flip"] = float(f"{p['flip']:.4g}")
        print(f"  painted over adaptive frame time: {100 * sweep['painted_cost']['extra_fraction']:+.1f} %")
    for row in (report.get("stage_costs") or {}).get("scenes", []):
        stages = ", ".join(f"{k} {v:.3g}" for k, v in sorted(row["per_frame_s"].items(), key=lambda kv: -kv[1]))
        print(f"stage costs {row['scene']:16s} {row['frame_s']:.3g} s/frame: {stages}")
        result[f"stage_{row['scene']}_frame_s"] = float(f"{row['frame_s']:.4g}")
    if report.get("scene"):
        for part in ("simulation", "rendering"):
            done = report["scene"][part]
            text = done.get("skipped") or done["cheapest"]["text"]
            print(f"scene {part}: {text}")
            result[f"scene_{part}_cheapest"] = None if "skipped" in done else done["cheapest"]["setting"]
    print("\nclaims:")
    for row in report["claims"]:
        print(f"  {row['id']:38s} {row['verdict']:15s} {row['reason']}")
    result["claims"] = {row["id"]: row["verdict"] for row in report["claims"]}
    print(f"report: {out}/report.html")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
