"""Rendering sweeps on the shipped scenes (issue 17 item 1): what each rendering option buys in error and costs in
time per frame, and Qian §6.3.2's painted-sampling cost.

Scenes (``SWEEP_SCENES``): ``kidney_static`` (an organ on a dark background), ``colon_mucosa`` (tissue fills the
whole frame) and ``liver_probe`` (shadows, a tool), each at frame 1 (at rest) and scaled to the level's width.
Every setting renders with shadows as the scene has them and against one reference per scene: uniform light
sampling with ``reference_samples`` samples, 2 x 2 (jittered) supersampling, the Monte Carlo estimator (unbiased),
the scene's SSS. Settings:

- light sampling ``uniform``, ``adaptive`` (m(d), Qian 6.15-6.16) and ``importance`` (painted, Qian Fig. 6.15: one
  stroke at the camera's look-at point, radius a quarter of the viewing distance, multiplier 4) over the samples;
- the ``ratio`` estimator (uniform) over the samples;
- penumbra re-shading (16 samples where a pixel's first shadow rays disagree; with shadows only);
- the reflection cone (as many extra samples inside the specular cone's footprint);
- SSS off (its error is what dropping the subsurface term costs in the image), and no supersampling (1 x 1).

Error: FLIP and relative RMSE (``render_measure``); cost: seconds per frame of ``render_hdr``. Pareto fronts per
scene over (seconds, FLIP).

**Painted-sampling cost** (Qian §6.3.2: +6.4 % frame time, 117 -> 110 fps): the frame time of ``importance`` over
that of ``adaptive`` at the scene's own sample count and resolution, both the median of ``cost_repeats`` timed
renders, minus one; the report's figure is the median over the scenes.
"""
from __future__ import annotations

import math
import statistics

import numpy as np

from tissuerender.report.measure import pareto_front
from tissuerender.report.render_measure import compare, render_timed, scaled_resolution, variant
from tissuerender.report.stage_costs import SCENES_DIR
from tissuerender.plan import make_plan
from tissuerender.scene import load_scene
from tissuerender.scene.schema import ImportanceStroke
from tissuerender.stages import StageRecorder
from tissuerender.world import build_world

SWEEP_SCENES = ("kidney_static", "colon_mucosa", "liver_probe")
RENDER_SWEEPS = {
    "full": {"max_width": 320, "samples": [1, 2, 4, 8, 16, 32], "reference_samples": 256, "cost_repeats": 5},
    "quick": {"max_width": 96, "samples": [1, 4, 16], "reference_samples": 64, "cost_repeats": 3},
    "tiny": {"max_width": 48, "samples": [1, 4, 16], "reference_samples": 32, "cost_repeats": 1},
}


def painted_stroke(scene) -> dict:
    """One importance stroke at the look-at point: radius a quarter of the viewing distance, multiplier 4."""
    c = scene.camera
    distance = float(np.linalg.norm(np.subtract(c.look_at, c.position)))
    return {"centre": list(c.look_at), "radius": 0.25 * distance, "multiplier": 4.0}


def settings(scene, sweep: dict) -> list[dict]:
    """Every swept setting of one scene: label, option family and the table keys it changes."""
    out = []
    stroke = painted_stroke(scene)
    for sampling in ("uniform", "adaptive", "importance"):
        for m in sweep["samples"]:
            light = {"sampling": sampling, "samples": m, "estimator": "mc", "importance": []}
            if sampling == "importance":
                light["importance"] = [ImportanceStroke(**stroke)]
            out.append({"family": f"{sampling} sampling", "label": f"{sampling} m{m}", "samples": m, "light": light})
    for m in sweep["samples"]:
        out.append({"family": "ratio estimator", "label": f"ratio m{m}", "samples": m,
                    "light": {"sampling": "uniform", "samples": m, "estimator": "ratio", "importance": []}})
    few = sweep["samples"][:2]
    if scene.effects.shadows:
        for m in few:
            out.append({"family": "penumbra re-shading", "label": f"ratio m{m} + penumbra 16", "samples": m,
                        "light": {"sampling": "uniform", "samples": m, "estimator": "ratio", "penumbra_samples": 16,
                                  "importance": []}})
    for m in few:
        out.append({"family": "reflection cone", "label": f"uniform m{m} + cone m{m}", "samples": m,
                    "light": {"sampling": "uniform", "samples": m, "estimator": "mc", "reflection_cone": True,
                              "cone_samples": m, "importance": []}})
    top = sweep["samples"][-1]
    uniform_top = {"sampling": "uniform", "samples": top, "estimator": "mc", "importance": []}
    if scene.effects.sss:
        out.append({"family": "SSS off", "label": f"uniform m{top}, SSS off", "samples": top, "light": uniform_top,
                    "effects": {"sss": False}})
    for m in sweep["samples"]:
        out.append({"family": "no supersampling", "label": f"uniform m{m}, 1x1", "samples": m,
                    "light": {**uniform_top, "samples": m}, "output": {"supersampling": 1}})
    return out


def run_scene(name: str, sweep: dict, tick=lambda: None) -> dict:
    scene = load_scene(SCENES_DIR / f"{name}.toml")
    base = variant(scene, output={"resolution": scaled_resolution(scene, sweep["max_width"]), "supersampling": 2})
    world = build_world(base, make_plan(base), StageRecorder())  # at rest: every variant renders it
    reference = render_timed(variant(base, light={"sampling": "uniform", "samples": sweep["reference_samples"],
                                                  "estimator": "mc", "importance": []}), world)
    points, warmed = [], set()
    for s in settings(scene, sweep):
        run = variant(base, light=s["light"], effects=s.get("effects"), output=s.get("output"))
        frame = render_timed(run, world, warm=warmed)
        point = {k: v for k, v in s.items() if k in ("family", "label", "samples")}
        point["supersampling"] = (s.get("output") or {}).get("supersampling", 2)
        points.append({**point, **compare(reference, frame)})
        tick()
    cost = painted_cost(base, scene, sweep["cost_repeats"], world)
    return {"scene": name, "resolution": base.output.resolution, "frame": 1,
            "reference": {"kind": f"uniform, {sweep['reference_samples']} samples, 2x2 supersampling, Monte Carlo",
                          "seconds": reference["seconds"]},
            "points": points, "pareto": pareto_front(points, "flip", "seconds"), "painted_cost": cost}


def painted_cost(base, scene, repeats: int, world=None) -> dict:
    """Frame time of painted (importance) sampling against adaptive m(d), at the scene's sample count."""
    m = scene.light.samples
    times = {}
    for sampling in ("adaptive", "importance"):
        light = {"sampling": sampling, "samples": m, "importance": [ImportanceStroke(**painted_stroke(scene))]
                 if sampling == "importance" else []}
        run = variant(base, light=light)
        times[sampling] = statistics.median(render_timed(run, world, warm=(k == 0))["seconds"] for k in range(repeats))
    return {"samples": m, "adaptive_s": times["adaptive"], "importance_s": times["importance"],
            "extra_fraction": times["importance"] / times["adaptive"] - 1.0}


def run_render_sweeps(sweep: dict, names=SWEEP_SCENES, tick=lambda: None) -> dict:
    scenes = [run_scene(name, sweep, tick) for name in names]
    extras = [s["painted_cost"]["extra_fraction"] for s in scenes]
    finite = [e for e in extras if math.isfinite(e)]
    return {"title": "rendering sweeps (light sampling, estimator, penumbra, reflection cone, SSS, supersampling)",
            "sweep": sweep, "scenes": scenes,
            "measures": {"painted_extra_frame_time": statistics.median(finite) if finite else float("nan")}}


def work_units(sweep: dict, names=SWEEP_SCENES) -> int:
    return sum(len(settings(load_scene(SCENES_DIR / f"{n}.toml"), sweep)) for n in names)
