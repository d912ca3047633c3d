"""Step rates of Zhang's integrators at the sizes the thesis quotes, against its figures: EBM on about
500 tets (thesis: 1 kHz isotropic, ~200 Hz anisotropic, C++ on an i7-4770 core) and the CNN with
energy propagation on about 1,500 nodes (thesis: 30 Hz on an i7-5500U), plus explicit and linear-FEM
CNN for scale.

Usage: .venv/bin/python benchmarks/zhang_rates.py [--quick]
Last line: one JSON object of steps per second ("<case>_hz") with the thesis's reference rates.
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
from sim.model import Model, PrescribedDisplacement, State


def ebm_block(constitutive: str, fibre=None) -> Model:
    """~500 tets: a 0.1 m block (5 x 4 x 4 cells, 480 tets), bottom fixed, top pressed 5 mm."""
    mesh = procedural.box((0.1, 0.08, 0.08), (5, 4, 4))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45, density=1000.0, constitutive=constitutive, fibre=fibre)
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    top = select.nodes_on_side(mesh.points, 2, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.array([0.0, 0.0, -0.005]), 0.0, 0.1))
    return model


def cnn_cube() -> Model:
    """1,331 nodes (11^3, 6,000 tets), sides fixed, a 1 N load on the top centre node (the contact)."""
    mesh = procedural.box((0.1, 0.1, 0.1), (10, 10, 10))
    model = Model.from_mesh(mesh, E=3500.0, nu=0.45, density=1060.0)
    for axis in (0, 1):
        for side in ("min", "max"):
            model.fixed[select.nodes_on_side(mesh.points, axis, side)] = True
    model.external_force = np.zeros_like(mesh.points)
    model.external_force[int(np.argmin(np.linalg.norm(mesh.points - [0.05, 0.05, 0.1], axis=1))), 2] = -1.0
    return model


def rate(name: str, model: Model, settings: dict, dt: float, steps: int) -> float:
    integrator = make_integrator(name, model, settings)
    state = integrator.step(State.at_rest(model), dt)  # warm-up
    start = time.perf_counter()
    for _ in range(steps):
        state = integrator.step(state, dt)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps")
    args = parser.parse_args()
    steps = 10 if args.quick else 50
    numba.set_num_threads(1)
    result: dict = {}
    cases = [
        ("ebm_isotropic_480tets", "ebm", ebm_block("neo_hookean"), {"iterations": 20}, 1e-3, 1000.0),
        ("ebm_anisotropic_480tets", "ebm", ebm_block("anisotropic_neo_hookean", fibre=[0.0, 0.0, 1.0]),
         {"iterations": 20}, 1e-3, 200.0),
        ("cnn_energy_1331nodes", "cnn", cnn_cube(), {"force_model": "energy", "K": 4.0}, 1.0 / 60.0, 30.0),
        ("cnn_linear_fem_1331nodes", "cnn", cnn_cube(), {"force_model": "linear_fem", "K": 4.0}, 1e-3, None),
        ("explicit_linear_fem_1331nodes", "explicit", cnn_cube(), {"force_model": "linear_fem"}, 1e-3, None),
    ]
    for key, name, model, settings, dt, thesis in cases:
        hz = rate(name, model, settings, dt, steps)
        result[f"{key}_hz"] = round(hz, 1)
        if thesis is not None:
            result[f"{key}_thesis_hz"] = thesis
        print(f"{key:32s} {hz:9.1f} steps/s" + (f"   (thesis {thesis:g} Hz)" if thesis else ""))
    result["machine"] = f"{platform.machine()} {os.cpu_count()} cpus, 1 numba thread, NumPy integrators"
    print(json.dumps(result))


if __name__ == "__main__":
    main()
