"""What the accuracy report measures: timed integrator runs, the errors against a reference, the
Pareto front of (error, time).

- **Relative L2** of the displacement over all nodes: ``||u - u_ref|| / ||u_ref||`` (``sim.cases.zhang``).
- **Line errors** (Zhang §5.3.2, Figs. 5.5(c)-5.7(c)): on the case's measurement line, the absolute
  difference of one displacement component (u_x on the cylinder, u_z on the cube) from the reference's:
  its maximum, mean and root mean square [m].
- **Wall time per simulated second**: ``time.perf_counter`` around the steps only (the integrator is
  built, and every numba kernel it calls compiled or loaded from the cache, by a warm-up step of a
  separate instance first), divided by the simulated time the steps cover.
"""
from __future__ import annotations

import math
import time

import numpy as np

from sim.cases.zhang import relative_l2
from sim.errors import SimulationDiverged
from sim.integrators import make_integrator
from sim.model import State


def line_errors(u, u_ref, line, component: int) -> dict[str, float]:
    """Max, mean and RMSE [m] of ``|u - u_ref|`` in ``component`` at the nodes ``line``."""
    d = np.abs(u[line, component] - u_ref[line, component])
    return {"line_max_m": float(d.max()), "line_mean_m": float(d.mean()),
            "line_rmse_m": float(np.sqrt(np.mean(d * d)))}


def timed_run(name: str, model, settings: dict, dt: float, steps: int):
    """Run ``steps`` steps of ``dt`` from rest; (final state or None, wall seconds of the steps, the
    integrator, the failure message or None). A warm-up step of another instance comes first so the
    timing excludes numba's compilation (or cache load)."""
    make_integrator(name, model, settings).step(State.at_rest(model), dt)
    integrator = make_integrator(name, model, settings)
    state = State.at_rest(model)
    start = time.perf_counter()
    try:
        for _ in range(steps):
            state = integrator.step(state, dt)
    except SimulationDiverged as e:
        return None, time.perf_counter() - start, integrator, str(e).splitlines()[0]
    return state, time.perf_counter() - start, integrator, None


def mesh_point(integrator: str, label: str, settings: dict, case, u_ref, component: int, dt: float,
               steps: int) -> dict:
    """One swept setting on a mesh case: its errors against ``u_ref`` and its cost."""
    state, seconds, solver, failure = timed_run(integrator, case.model, settings, dt, steps)
    simulated = dt * steps
    point = {"integrator": integrator, "setting": label, "settings": settings, "dt_s": dt, "steps": steps,
             "simulated_s": simulated, "wall_s": seconds, "wall_s_per_sim_s": seconds / simulated,
             "diverged": failure}
    if failure is None:
        u = state.x - case.model.X
        point["rel_l2"] = relative_l2(u, u_ref)
        point.update(line_errors(u, u_ref, case.line, component))
        point["line_u_m"] = u[case.line, component].tolist()
        point["_u"] = u  # popped by report.pictures.error_fields: the best and worst are drawn
        red = getattr(solver, "red_history", None)
        if red:
            point["red"] = float(red[-1])
    return point


def refusal(name: str, model) -> str | None:
    """The first line of the error ``name``'s constructor raises for ``model`` (an integrator that does not take such a
    model, e.g. the geometric ChainMail under forces), or None when it takes it: a case lists it as not applicable."""
    try:
        make_integrator(name, model, {})
    except ValueError as e:
        return str(e).splitlines()[0]
    return None


def pareto_front(points: list[dict], error_key: str, time_key: str = "wall_s_per_sim_s") -> list[int]:
    """Indices of the points no other point dominates (no worse in both error and time, better in one),
    sorted by time; points without a finite error are left out."""
    ok = [i for i, p in enumerate(points) if isinstance(p.get(error_key), float) and math.isfinite(p[error_key])]
    front = []
    for i in ok:
        e, t = points[i][error_key], points[i][time_key]
        dominated = any(points[j][error_key] <= e and points[j][time_key] <= t
                        and (points[j][error_key] < e or points[j][time_key] < t) for j in ok if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (points[i][time_key], points[i][error_key]))


def observed_order(coarse: float, fine: float) -> float:
    """log2 of the ratio of two successive differences (or errors) at steps h and h/2: the convergence order."""
    return float(math.log2(coarse / fine)) if coarse > 0.0 and fine > 0.0 else float("nan")
