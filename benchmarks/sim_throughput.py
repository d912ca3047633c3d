"""Simulation throughput: tet-constraint iterations per second (tets x iterations x substeps / s).

Beam 2 m x 0.2 m x 0.2 m, x = 0 face fixed, gravity, E = 3000 Pa, nu = 0.49, rho = 1000, at 3,840 and
30,720 tets (6 tets per hex cell), 10 substeps x 10 iterations, with 1 and 2 numba threads, for every
registered integrator that can be built. Compilation is excluded (one warm-up step first); each figure
is the median of 3 (``--quick``) or 5 timed runs.

Usage: .venv/bin/python benchmarks/sim_throughput.py [--quick] [--wait-idle SECONDS]
``--wait-idle``: on a shared machine, start each timed run only after every CPU was at least 95 % idle
for 0.5 s (Linux /proc/stat), waiting at most SECONDS per run; 2-thread figures are meaningless while
another job holds the second core (a parallel launch then waits for a time slice).
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

from sim.integrators import make_integrator
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


def _min_idle_fraction(interval: float = 0.5) -> float:
    """Smallest idle fraction over the CPUs during ``interval`` seconds (1.0 where /proc/stat is missing)."""
    def sample():
        with open("/proc/stat") as f:
            rows = [line.split() for line in f if line.startswith("cpu") and line[3] != " "]
        return [(sum(map(int, r[1:])), int(r[4]) + int(r[5])) for r in rows]  # total, idle + iowait

    if not os.path.exists("/proc/stat"):
        return 1.0
    before = sample()
    time.sleep(interval)
    after = sample()
    return min((i1 - i0) / max(t1 - t0, 1) for (t0, i0), (t1, i1) in zip(before, after))


def wait_until_idle(timeout: float) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline and _min_idle_fraction() < 0.95:
        pass


def measure(name: str, model: Model, steps: int, repeats: int = 1, dt: float = 1e-3, wait_idle: float = 0.0) -> float:
    """Median over ``repeats`` timed runs of ``steps`` steps (the machine is shared: one run can be
    slowed by other processes, the median of several is a steadier figure); with ``wait_idle`` > 0
    each run waits (at most that many seconds) for idle CPUs."""
    integrator = make_integrator(name, model, {"substeps": 10, "iterations": 10})
    state = integrator.step(State.at_rest(model), dt)  # warm-up: compilation
    iterations = 10 if name in ITERATIVE else 1  # explicit and CNN evaluate each tet once per substep
    rates = []
    for _ in range(repeats):
        if wait_idle > 0.0:
            wait_until_idle(wait_idle)
        start = time.perf_counter()
        for _ in range(steps):
            state = integrator.step(state, dt)
        rates.append(model.n_tets * 10 * iterations * steps / (time.perf_counter() - start))
    return float(np.median(rates))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps")
    parser.add_argument("--wait-idle", type=float, default=0.0, metavar="SECONDS",
                        help="before each timed run wait (at most SECONDS) until all CPUs are idle")
    args = parser.parse_args()
    steps = {3840: 3 if args.quick else 20, 30720: 1 if args.quick else 5}
    repeats = 3 if args.quick else 5
    result: dict = {}
    max_threads = numba.config.NUMBA_NUM_THREADS
    for name in CANDIDATES:
        for n_tets, cells in SIZES.items():
            model = beam_model(cells)
            for threads in (1, 2):
                if threads > max_threads:
                    continue
                numba.set_num_threads(threads)
                rate = measure(name, model, steps[n_tets], repeats, wait_idle=args.wait_idle)
                result[f"{name}_{n_tets}_t{threads}"] = float(f"{rate:.4g}")
                print(f"{name:9s} {n_tets:6d} tets  {threads} thread(s): {rate / 1e6:8.2f} M tet-constraint it/s")
    result["machine"] = f"{platform.machine()} {os.cpu_count()} cpus, numba {numba.__version__}"
    print(json.dumps(result))


if __name__ == "__main__":
    main()
