"""Simulation throughput: tet-constraint iterations per second (tets x iterations x substeps / s).

Beam 2 m x 0.2 m x 0.2 m, x = 0 face fixed, gravity, E = 3000 Pa, nu = 0.49, rho = 1000, at 3,840 and
30,720 tets (6 tets per hex cell), 10 substeps x 10 iterations, with 1 and 2 numba threads, for every
registered integrator that can be built. Compilation is excluded (one warm-up step first); each figure
is the median of 3 (``--quick``) or 5 timed runs.

Usage: .venv/bin/python benchmarks/sim_throughput.py [--quick]
The last line of output is one flat JSON object, e.g. {"xpbd_30720_t1": 3.1e7, ...}.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numba
import numpy as np

from sim.integrators import REGISTRY, make_integrator
from sim.mesh import procedural, select
from sim.model import Model, State

SIZES = {3840: (40, 4, 4), 30720: (80, 8, 8)}
CANDIDATES = ["xpbd", "ebm", "cnn", "explicit"]
ITERATIVE = ("xpbd", "ebm")


def beam_model(cells) -> Model:
    mesh = procedural.box((2.0, 0.2, 0.2), cells)
    model = Model.from_mesh(mesh, E=3000.0, nu=0.49, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]))
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    return model


def measure(name: str, model: Model, steps: int, repeats: int = 1, dt: float = 1e-3) -> float:
    """Median over ``repeats`` timed runs of ``steps`` steps (the machine is shared: one run can be
    slowed by other processes, the median of several is a steadier figure)."""
    integrator = make_integrator(name, model, {"substeps": 10, "iterations": 10})
    state = integrator.step(State.at_rest(model), dt)  # warm-up: compilation
    iterations = 10 if name in ITERATIVE else 1  # explicit and CNN evaluate each tet once per substep
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            state = integrator.step(state, dt)
        rates.append(model.n_tets * 10 * iterations * steps / (time.perf_counter() - start))
    return float(np.median(rates))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps")
    args = parser.parse_args()
    steps = {3840: 3 if args.quick else 20, 30720: 1 if args.quick else 5}
    repeats = 3 if args.quick else 5
    result: dict = {}
    skipped = []
    max_threads = numba.config.NUMBA_NUM_THREADS
    for name in CANDIDATES:
        if name not in REGISTRY:
            continue
        try:
            make_integrator(name, beam_model((2, 1, 1)), {"substeps": 1, "iterations": 1})
        except NotImplementedError as e:
            skipped.append(f"{name}: {type(e).__name__}: {e}")
            continue
        for n_tets, cells in SIZES.items():
            model = beam_model(cells)
            for threads in (1, 2):
                if threads > max_threads:
                    continue
                numba.set_num_threads(threads)
                rate = measure(name, model, steps[n_tets], repeats)
                result[f"{name}_{n_tets}_t{threads}"] = float(f"{rate:.4g}")
                print(f"{name:9s} {n_tets:6d} tets  {threads} thread(s): {rate / 1e6:8.2f} M tet-constraint it/s")
    result["skipped"] = skipped
    result["machine"] = f"{platform.machine()} {os.cpu_count()} cpus, numba {numba.__version__}"
    print(json.dumps(result))


if __name__ == "__main__":
    main()
