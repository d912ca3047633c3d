"""``tissuerender report accuracy SCENE -o DIR [--budget sim=1%,flip=0.002]``: how accurate the user's own
scene is, and what more (or less) accuracy would cost per frame (issue 17 item 2).

**Simulation.** The scene's integrator at the scene's ``[simulation]`` settings and at cheaper and dearer ones
(``iterations`` halved and doubled for the integrators that iterate — xpbd, ebm, cnn_chainmail —, and
``substeps`` halved and doubled for every integrator: the step each substep takes, ``dt / substeps``, doubles
and halves with it), over the scene's first frames. Each is measured against the reference integrator
(backward Euler solved by Newton, ``sim.integrators.reference``, the scene's ``[simulation.reference]``
tolerance) **on the scene's mesh** at the step ``h = dt / substeps / 4`` (a quarter of the scene's own substep;
a half with ``--quick``, which also measures 4 frames, not all),
after a convergence check at ``4h``, ``2h``, ``h``: the reference's own time-step error is about
``|x_2h - x_h|`` (first order), and it must fall under refinement. The error of a setting is the largest,
over the frame times ``(k - 1) / fps`` after the first, of the relative L2 displacement error over every
body's nodes, ``||x - x_ref|| / ||x_ref - X||``: the solver and time-step error on the mesh the scene renders.
**Discretisation**, reported apart: the same reference on every body's mesh refined once (1 tet -> 8, the scene's
regions re-applied to the refined nodes) at the step ``levels[refined_level]``, against the scene-mesh reference at
that step, on the scene's nodes; each setting also gets ``rel_l2_with_mesh``, its error plus that one (a bound).
A scene with tools is not compared: the reference integrator has no contact.

**Rendering.** Frame 1 of the scene (at rest) at the scene's light samples and supersampling, and at cheaper
and dearer ones, against the same frame with ``REFERENCE_SAMPLES`` times the samples, 2 x 2 supersampling (or
the scene's, if more) and the Monte Carlo estimator (unbiased; the ratio estimator is only consistent):
FLIP and relative RMSE (``render_measure``). The scene's effects (shadows, SSS, ...) stay as they are.

**Budget.** ``sim=`` a relative L2 error (``1%`` or ``0.01``), ``flip=`` a mean FLIP, ``rmse=`` a relative RMSE
(optional); the report names the cheapest setting (least wall time per frame) within it, or says none is.
"""
from __future__ import annotations

import math
import time

import numpy as np

from sim.integrators import make_integrator
from sim.mesh.refine import refine
from sim.mesh.surface import boundary_surface
from sim.model import State
from tissuerender.bodies import build_model
from tissuerender.errors import UserError
from tissuerender.plan import make_plan
from tissuerender.report.measure import pareto_front
from tissuerender.report.render_measure import compare, render_timed, scaled_resolution, variant
from tissuerender.stages import StageRecorder
from tissuerender.world import SimulationFailed, advance, build_world

DEFAULT_BUDGET = {"sim": 0.01, "flip": 0.002}
BUDGET_KEYS = {"sim": "relative L2 displacement error", "flip": "mean FLIP", "rmse": "relative RMSE of the HDR"}
ITERATING = ("xpbd", "ebm", "cnn_chainmail")  # the integrators whose [simulation] iterations mean something
REFERENCE_SAMPLES = 16  # the render reference's light samples per the scene's (at most 4096, the schema's limit)

# per level: frames simulated (None: all of the scene's), the factors applied to iterations and substeps, the
# render's largest width (None: the scene's) and the factors applied to the light samples; the reference's step
# is the scene's substep divided by reference_refinement; the refined-mesh reference runs at the step
# levels[refined_level] (0: 4h, 1: 2h, 2: h) and is compared with the scene-mesh reference at that same step
SCENE_SWEEPS = {
    "full": {"frames": None, "factors": [0.25, 0.5, 1.0, 2.0, 4.0], "max_width": None,
             "sample_factors": [0.25, 0.5, 1.0, 2.0, 4.0], "supersampling": [-1, 1], "reference_refinement": 4,
             "refined_level": 1},
    "quick": {"frames": 4, "factors": [0.5, 1.0, 2.0], "max_width": 128, "sample_factors": [0.25, 1.0, 2.0],
              "supersampling": [1], "reference_refinement": 2, "refined_level": 0},
    # the test suite's: no refined reference (19 s on its 384-tet block; tests/test_report_discretisation.py runs
    # it on a smaller one)
    "tiny": {"frames": 3, "factors": [0.25, 0.5, 1.0, 2.0], "max_width": 64, "sample_factors": [0.25, 1.0, 4.0],
             "supersampling": [], "reference_refinement": 4, "refined_level": None},
}


def parse_budget(text: str | None) -> dict[str, float]:
    """``--budget sim=1%,flip=0.002[,rmse=0.05]`` as ``{"sim": 0.01, "flip": 0.002, ...}``; the defaults
    (``DEFAULT_BUDGET``) for keys not given; a user error naming the bad item."""
    budget = dict(DEFAULT_BUDGET)
    if text is None:
        return budget
    for item in text.split(","):
        key, sep, value = (part.strip() for part in item.partition("="))
        if not sep or key not in BUDGET_KEYS:
            raise UserError(f"--budget: {item.strip()!r}: expected key=value with key one of "
                            f"{', '.join(BUDGET_KEYS)} (e.g. --budget sim=1%,flip=0.002)")
        try:
            number = float(value[:-1]) / 100.0 if value.endswith("%") else float(value)
        except ValueError:
            number = float("nan")
        if not (math.isfinite(number) and number > 0.0):
            raise UserError(f"--budget: {key}={value!r}: expected a positive number or percentage (e.g. {key}="
                            f"{'1%' if key == 'sim' else '0.002'}), found {value!r}")
        budget[key] = number
    return budget


# --- simulation ---------------------------------------------------------------------------------------------

def simulation_settings(scene, factors: list[float]) -> list[dict]:
    """The scene's ``(substeps, iterations)`` first, then each one scaled by ``factors`` (the other kept)."""
    sim = scene.simulation
    base = {"substeps": sim.substeps, "iterations": sim.iterations}
    chosen = [{**base, "label": f"scene's ({sim.substeps} substeps x {sim.iterations} iterations)", "scene": True}]
    keys = ["iterations", "substeps"] if sim.integrator in ITERATING else ["substeps"]
    for key in keys:
        for f in factors:
            value = max(1, int(round(base[key] * f)))
            setting = {**base, key: value}
            if all((c["substeps"], c["iterations"]) != (setting["substeps"], setting["iterations"]) for c in chosen):
                chosen.append({**setting, "label": f"{key} {value}", "scene": False})
    return chosen


def trajectory(scene, frames: int) -> tuple[list[np.ndarray], list[float], str | None]:
    """Every body's nodes at frames 1..``frames`` (concatenated, (n, 3)), the wall seconds of each frame
    interval's simulation, and the failure message if the integrator diverged."""
    plan = make_plan(scene)
    world = build_world(scene, plan, StageRecorder())
    xs = [np.concatenate([s.x for s in world.states])]
    seconds = []
    for _ in range(1, frames):
        start = time.perf_counter()
        try:
            advance(world, scene, StageRecorder())
        except SimulationFailed as e:
            return xs, seconds, str(e)
        seconds.append(time.perf_counter() - start)
        xs.append(np.concatenate([s.x for s in world.states]))
    return xs, seconds, None


def relative_errors(xs: list[np.ndarray], ref: list[np.ndarray], rest: np.ndarray) -> list[float | None]:
    """Per frame ``||x - x_ref|| / ||x_ref - X||`` (None where the reference has not moved: frame 1)."""
    out = []
    for x, r in zip(xs, ref):
        norm = float(np.linalg.norm(r - rest))
        out.append(float(np.linalg.norm(x - r)) / norm if norm > 0.0 else None)
    return out


def reference_trajectory(scene, frames: int, h: float) -> tuple[list[np.ndarray], float]:
    """The reference integrator (backward Euler, the scene's Newton tolerance) at step ``h``, which divides
    the scene's ``dt``; the wall seconds it took."""
    reference = scene.simulation.reference.model_copy(update={"mode": "dynamic"})
    ref_scene = variant(scene, simulation={"integrator": "reference", "dt": h, "substeps": 1, "iterations": 1,
                                           "reference": reference})
    start = time.perf_counter()
    xs, _, failure = trajectory(ref_scene, frames)
    if failure is not None:
        raise UserError(f"{scene.path}: report accuracy: the reference integrator failed at step {h:.4g} s: {failure}")
    return xs, time.perf_counter() - start


def refined_reference_trajectory(scene, frames: int, h: float) -> tuple[list[np.ndarray], float, int]:
    """The reference integrator at step ``h`` on every body's mesh refined once (1 tet -> 8, ``sim.mesh.refine``),
    its material and boundary conditions rebuilt on the refined nodes (every node in a fixed or prescribed region is
    held, edge midpoints included); the positions of the scene-mesh nodes (the refined mesh's first ones) per frame,
    the wall seconds, and the refined tet count."""
    reference = scene.simulation.reference.model_copy(update={"mode": "dynamic"})
    ref_scene = variant(scene, simulation={"integrator": "reference", "dt": h, "substeps": 1, "iterations": 1,
                                           "reference": reference})
    world = build_world(ref_scene, make_plan(ref_scene), StageRecorder())
    settings = {**reference.model_dump(), "substeps": 1, "iterations": 1}
    coarse, tets = [], 0
    for i, body in enumerate(world.bodies):
        fine = refine(body.mesh)
        index = next(k for k, o in enumerate(scene.objects) if o is body.spec)
        model = build_model(body.spec, index, fine, ref_scene, boundary_surface(fine))
        world.integrators[i] = make_integrator("reference", model, settings)
        world.states[i] = State.at_rest(model)
        coarse.append(body.mesh.n_points)
        tets += fine.n_tets

    def positions():
        return np.concatenate([s.x[:n] for s, n in zip(world.states, coarse)])

    start = time.perf_counter()
    xs = [positions()]
    for _ in range(1, frames):
        try:
            advance(world, ref_scene, StageRecorder())
        except SimulationFailed as e:
            raise UserError(f"{scene.path}: report accuracy: the reference integrator on the refined mesh failed at "
                            f"step {h:.4g} s: {e}") from None
        xs.append(positions())
    return xs, time.perf_counter() - start, tets


def why_no_simulation(scene) -> str | None:
    plan = make_plan(scene)
    if "simulate" not in plan:
        return f"not simulated: {scene.why_not_simulated()}"
    if "contact" in plan:
        return ("the scene has tools, and the reference integrator (backward Euler) has no contact, so there is no "
                "converged reference to measure against")
    return None


def run_simulation(scene, sweep: dict, tick=lambda: None) -> dict:
    """The simulation sweep (module docstring); JSON-ready."""
    reason = why_no_simulation(scene)
    if reason is not None:
        return {"skipped": reason}
    sim = scene.simulation
    frames = scene.output.frames if sweep["frames"] is None else min(sweep["frames"], scene.output.frames)
    if frames < 2:
        return {"skipped": "the scene has one frame: nothing moves before it"}
    # the finest step any setting takes is dt / (substeps * the largest factor); the reference takes the scene's
    # own substep over reference_refinement (full: 4, --quick: 2), and its convergence is checked at 4h, 2h and h
    h = sim.dt / sim.substeps / sweep["reference_refinement"]
    levels = [4.0 * h, 2.0 * h, h]
    refs, ref_seconds = [], []
    for step in levels:
        xs, seconds = reference_trajectory(scene, frames, step)
        refs.append(xs)
        ref_seconds.append(seconds)
        tick()
    rest = refs[-1][0]
    differences = [max(e for e in relative_errors(a, b, rest) if e is not None) for a, b in zip(refs, refs[1:])]
    reference = refs[-1]
    # discretisation: the scene-mesh reference against the refined-mesh one at the same step (the step's error,
    # nearly the same on both meshes, cancels), on the scene-mesh nodes
    k = sweep["refined_level"]
    discretisation = None
    if k is not None:
        refined, refined_seconds, refined_tets = refined_reference_trajectory(scene, frames, levels[k])
        tick()
        mesh_error = max(e for e in relative_errors(refs[k], refined, rest) if e is not None)
        discretisation = {
            "kind": f"the reference on the scene's mesh refined once (1 tet -> 8), same integrator and tolerance, step "
                    f"{levels[k]:.4g} s", "step_s": levels[k], "tets": refined_tets, "wall_s": refined_seconds,
            "rel_l2": mesh_error,
            "what": "largest relative L2 difference over the frames, on the scene's nodes, between the reference on the "
                    "scene's mesh and on the refined mesh at the same step: the error the mesh makes whatever the "
                    "solver (a setting's rel_l2_with_mesh: its solver error plus this, a bound by the triangle "
                    "inequality)"}
    trajectory(scene, 2)  # warm-up: numba compiles (or loads) the integrator's kernels outside the timings
    points = []
    for setting in simulation_settings(scene, sweep["factors"]):
        run = variant(scene, simulation={"substeps": setting["substeps"], "iterations": setting["iterations"]})
        xs, seconds, failure = trajectory(run, frames)
        errors = relative_errors(xs, reference, rest) if failure is None else []
        measured = [e for e in errors if e is not None]
        points.append({**setting, "integrator": sim.integrator, "dt_s": sim.dt, "frames": frames,
                       "diverged": failure, "rel_l2": max(measured) if measured else None,
                       "rel_l2_per_frame": errors, "wall_s": float(sum(seconds)),
                       "wall_s_per_frame": float(sum(seconds) / max(len(seconds), 1))})
        if discretisation is not None:
            error = points[-1]["rel_l2"]
            points[-1]["rel_l2_with_mesh"] = None if error is None else error + discretisation["rel_l2"]
        tick()
    return {"integrator": sim.integrator, "frames": frames, "fps": scene.output.fps,
            "frame_times_s": [k / scene.output.fps for k in range(frames)],
            "nodes": int(rest.shape[0]),
            "reference": {"kind": f"reference integrator (backward Euler, Newton tolerance {sim.reference.tol:g}) on "
                                  f"the scene's mesh (no mesh refinement), step {h:.4g} s",
                          "step_s": h, "levels_s": levels, "wall_s": ref_seconds,
                          "differences": differences,
                          "what": "largest relative L2 difference over the frames between successive levels "
                                  "(4h against 2h, 2h against h)",
                          "falls": bool(differences[1] < differences[0])},
            **({} if discretisation is None else {"discretisation": discretisation}),
            "error_key": "rel_l2", "points": points,
            "pareto": pareto_front(points, "rel_l2", "wall_s_per_frame")}


# --- rendering ----------------------------------------------------------------------------------------------

def render_settings(scene, sweep: dict) -> list[dict]:
    """The scene's (light samples, supersampling) first, then the samples scaled by ``sample_factors`` at the
    scene's supersampling and at the reference's (whose aliasing, with the same seed and jitter, cancels: what
    remains there is the light sampling's error alone), then the scene's samples at other supersampling."""
    m, ss = scene.light.samples, scene.output.supersampling
    chosen = [{"samples": m, "supersampling": ss, "label": f"scene's ({m} samples, {ss}x{ss})", "scene": True}]

    def add(samples, k):
        if 1 <= samples <= 4096 and 1 <= k <= 8 and all((c["samples"], c["supersampling"]) != (samples, k)
                                                         for c in chosen):
            chosen.append({"samples": samples, "supersampling": k, "label": f"{samples} samples, {k}x{k}",
                           "scene": False})

    for k in dict.fromkeys([ss, reference_supersampling(scene)]):
        for f in sweep["sample_factors"]:
            add(max(1, int(round(m * f))), k)
    for d in sweep["supersampling"]:
        add(m, ss + d)
    return chosen


def reference_supersampling(scene) -> int:
    return max(2, scene.output.supersampling)


def run_rendering(scene, sweep: dict, tick=lambda: None) -> dict:
    """The rendering sweep (module docstring); JSON-ready."""
    resolution = scaled_resolution(scene, sweep["max_width"])
    small = variant(scene, output={"resolution": resolution})
    ref_samples = min(4096, REFERENCE_SAMPLES * scene.light.samples)
    ref_ss = reference_supersampling(scene)
    world = build_world(small, make_plan(small), StageRecorder())  # at rest: every variant renders it
    reference = render_timed(variant(small, light={"samples": ref_samples, "estimator": "mc"},
                                     output={"supersampling": ref_ss}), world)
    tick()
    points, warmed = [], set()
    for setting in render_settings(scene, sweep):
        frame = render_timed(variant(small, light={"samples": setting["samples"]},
                                     output={"supersampling": setting["supersampling"]}), world, warm=warmed)
        points.append({**setting, **compare(reference, frame)})
        tick()
    return {"resolution": resolution, "frame": 1,
            "reference": {"kind": f"{ref_samples} light samples ({scene.light.sampling}), {ref_ss}x{ref_ss} "
                                  "supersampling, Monte Carlo estimator", "seconds": reference["seconds"]},
            "points": points, "pareto": pareto_front(points, "flip", "seconds")}


# --- the verdict --------------------------------------------------------------------------------------------

def cheapest(points: list[dict], limits: dict[str, float], time_key: str) -> dict:
    """The point with the least ``time_key`` among those whose every measure named in ``limits`` is within it."""
    ok = [p for p in points if all(p.get(k) is not None and p[k] <= v for k, v in limits.items())]
    if not ok:
        return {"setting": None, "text": "no setting in the sweep is within the budget"}
    best = min(ok, key=lambda p: p[time_key])
    return {"setting": best["label"], "index": points.index(best), "time_s": best[time_key],
            "text": f"{best['label']}: {best[time_key]:.3g} s per frame"}


def run_scene_parts(scene, budget: dict, sweep: dict, cached_part, tick=lambda: None) -> dict:
    """Both sweeps (each through ``cached_part(name, compute)``, which stores and reuses it) and the verdicts."""
    simulation = cached_part("simulation", lambda: run_simulation(scene, sweep, tick))
    rendering = cached_part("rendering", lambda: run_rendering(scene, sweep, tick))
    if "points" in simulation:
        simulation["cheapest"] = cheapest(simulation["points"], {"rel_l2": budget["sim"]}, "wall_s_per_frame")
    limits = {"flip": budget["flip"], **({"rel_rmse": budget["rmse"]} if "rmse" in budget else {})}
    rendering["cheapest"] = cheapest(rendering["points"], limits, "seconds")
    return {"path": str(scene.path), "name": scene.name, "sha256": scene.sha256, "budget": budget,
            "sweep": sweep, "simulation": simulation, "rendering": rendering}


def part_units(scene, sweep: dict, part: str) -> int:
    """How many times a part calls its ``tick``: the progress bar's share of it."""
    if part == "rendering":
        return 1 + len(render_settings(scene, sweep))
    refined = sweep["refined_level"] is not None
    return 3 + refined + len(simulation_settings(scene, sweep["factors"])) if why_no_simulation(scene) is None else 0


def work_units(scene, sweep: dict) -> int:
    return part_units(scene, sweep, "simulation") + part_units(scene, sweep, "rendering")
