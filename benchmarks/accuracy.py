"""Accuracy versus wall time of the integrators on the Zhang cylinder (extension by 0.4 m), against the
converged reference (quasi-static Newton, relative gradient 1e-8).

For XPBD (stable Neo-Hookean, settled by damped dynamics over a fixed simulated time) and EBM
(Neo-Hookean 5.35, quasi-static load steps): relative L2 displacement error, Qian eq. 4.45's
variational error, and seconds of wall time, per setting.

Usage: .venv/bin/python benchmarks/accuracy.py [--quick]
The last line is one JSON object: {"reference_s": ..., "xpbd_<substeps>x<iterations>_err": ..., ...}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numba

from sim.cases.zhang import relative_l2, variational_error, zhang_cylinder
from sim.errors import SimulationDiverged
from sim.integrators.ebm.solver import EBM
from sim.integrators.reference import ReferenceIntegrator
from sim.integrators.xpbd.solver import XPBD
from sim.model import State


def reference(case):
    start = time.perf_counter()
    x = ReferenceIntegrator(case.model, {"mode": "quasistatic", "load_steps": 4}).step(
        State.at_rest(case.model), case.ramp_time).x
    return x, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarser mesh, fewer settings")
    args = parser.parse_args()
    h = 0.25 if args.quick else 0.125
    result: dict = {}
    rows = []

    case = zhang_cylinder(h=h, displacement=0.4, constitutive="stable_neo_hookean")
    x_ref, seconds = reference(case)
    u_ref = x_ref - case.model.X
    result.update(tets=case.model.n_tets, reference_s=round(seconds, 2))
    XPBD(case.model, {"substeps": 1, "iterations": 1}).step(State.at_rest(case.model), 0.01)  # compile
    settings = [(1, 1), (1, 5), (5, 5), (5, 20)] if args.quick else [(1, 1), (1, 5), (5, 5), (5, 20), (5, 100)]
    for substeps, iterations in settings:
        xpbd = XPBD(case.model, {"substeps": substeps, "iterations": iterations, "damping": 2.0})
        state = State.at_rest(case.model)
        start = time.perf_counter()
        for _ in range(160):  # 8 s of simulated time: settled
            state = xpbd.step(state, 0.05)
        seconds = time.perf_counter() - start
        err = relative_l2(state.x - case.model.X, u_ref)
        var = variational_error(case.model, state.x, x_ref)
        key = f"xpbd_{substeps}x{iterations}"
        result[f"{key}_err"], result[f"{key}_var"], result[f"{key}_s"] = round(err, 5), float(f"{var:.3g}"), round(seconds, 2)
        rows.append((key, err, var, seconds))

    case = zhang_cylinder(h=h, displacement=0.4, constitutive="neo_hookean")
    x_ref, _ = reference(case)
    u_ref = x_ref - case.model.X
    for iterations in ((20, 100) if args.quick else (20, 100, 500)):
        ebm = EBM(case.model, {"iterations": iterations})
        state = State.at_rest(case.model)
        start = time.perf_counter()
        key = f"ebm_{iterations}"
        try:
            for _ in range(8):
                state = ebm.step(state, 0.125)
        except SimulationDiverged as e:
            result[f"{key}_err"] = f"diverged: {e}"
            rows.append((key, float("nan"), float("nan"), time.perf_counter() - start))
            continue
        seconds = time.perf_counter() - start
        err = relative_l2(state.x - case.model.X, u_ref)
        var = variational_error(case.model, state.x, x_ref)
        result[f"{key}_err"], result[f"{key}_var"], result[f"{key}_s"] = round(err, 5), float(f"{var:.3g}"), round(seconds, 2)
        rows.append((key, err, var, seconds))

    print(f"Zhang cylinder +0.4 m, {result['tets']} tets; reference {result['reference_s']} s")
    print(f"{'setting':14s} {'rel. L2':>9s} {'Qian 4.45':>10s} {'wall [s]':>9s}")
    for key, err, var, seconds in rows:
        print(f"{key:14s} {err:9.4f} {var:10.3g} {seconds:9.2f}")
    result["machine"] = f"{platform.machine()} {os.cpu_count()} cpus, numba threads {numba.get_num_threads()}"
    print(json.dumps(result))


if __name__ == "__main__":
    main()
