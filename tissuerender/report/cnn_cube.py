"""Zhang §4.3.2.2's cube for the CNN claims (docs/integrators-zhang.md): 11 x 11 x 11 nodes (6,000 tets), 1 m, side
faces fixed, 100 Pa normal load on the top face, E = 3,500 Pa, nu = 0.45, rho = 1,060 kg/m^3, linear FEM forces,
stiffness damping ``rayleigh_beta`` 2 ms (the thesis gives neither the cube's size nor its damping).

- small step (1 ms): the CNN (K = 4) and explicit integration agree (no cell reaches K): the largest node distance
  between the two after ``small_t`` s, against the explicit run's sag of the top centre;
- large step (20 ms): explicit integration diverges (``SimulationDiverged``) within ``large_t`` s, the CNN stays
  finite: its peak displacement over the run, against the cube's size.
"""
from __future__ import annotations

import time

import numpy as np

from sim.cases.zhang import zhang_cnn_cube
from sim.errors import SimulationDiverged
from sim.integrators import make_integrator
from sim.model import State

SWEEPS = {
    "full": {"small_dt": 0.001, "small_t": 1.0, "large_dt": 0.02, "large_t": 2.0},
    "quick": {"small_dt": 0.001, "small_t": 0.3, "large_dt": 0.02, "large_t": 2.0},
    "tiny": {"small_dt": 0.001, "small_t": 0.05, "large_dt": 0.02, "large_t": 1.0},
}
SETTINGS = {"force_model": "linear_fem", "rayleigh_beta": 0.002}


def _run(model, name: str, dt: float, t_end: float, **extra) -> dict:
    integrator = make_integrator(name, model, {**SETTINGS, **extra})
    state, peak, failure = State.at_rest(model), 0.0, None
    start = time.perf_counter()
    try:
        for _ in range(int(round(t_end / dt))):
            state = integrator.step(state, dt)
            peak = max(peak, float(np.abs(state.x - model.X).max()))
    except SimulationDiverged as e:
        failure = str(e).splitlines()[0]
    return {"x": state.x, "peak_m": peak, "diverged": failure, "wall_s": time.perf_counter() - start,
            "simulated_s": state.t}


def run_cnn_cube(sweep: dict, tick=lambda: None) -> dict:
    model, centre = zhang_cnn_cube()
    runs = {}
    for key, name, dt, t_end in (("explicit_small", "explicit", sweep["small_dt"], sweep["small_t"]),
                                 ("cnn_small", "cnn", sweep["small_dt"], sweep["small_t"]),
                                 ("explicit_large", "explicit", sweep["large_dt"], sweep["large_t"]),
                                 ("cnn_large", "cnn", sweep["large_dt"], sweep["large_t"])):
        runs[key] = _run(model, name, dt, t_end, **({"K": 4.0} if name == "cnn" else {}))
        tick()
    sag = float(model.X[centre, 2] - runs["explicit_small"]["x"][centre, 2])
    difference = float(np.abs(runs["cnn_small"]["x"] - runs["explicit_small"]["x"]).max())
    rows = [{"run": k, "peak_m": r["peak_m"], "diverged": r["diverged"], "simulated_s": r["simulated_s"],
             "wall_s": r["wall_s"]} for k, r in runs.items()]
    return {"case": "cnn_cube", "title": "Zhang §4.3.2.2: the CNN and explicit integration on the cube", "rows": rows,
            "setup": {"nodes": int(model.n_nodes), "tets": int(model.n_tets), **SETTINGS, "K": 4.0, **sweep},
            "measures": {"small_step_difference_m": difference, "small_step_sag_m": sag,
                         "explicit_large_step_diverged": runs["explicit_large"]["diverged"] is not None,
                         "cnn_large_step_finite": runs["cnn_large"]["diverged"] is None,
                         "cnn_large_step_peak_m": runs["cnn_large"]["peak_m"], "cube_size_m": 1.0}}


def work_units(sweep: dict) -> int:
    return 4
