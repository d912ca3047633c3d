"""Step rates of Zhang's integrators at the sizes the thesis quotes, against its figures: EBM on about
500 tets (thesis Fig. 5.13: 1 kHz at ~500 isotropic tets and at ~200 anisotropic tets, C++ on an i7-4770
core; with its time linear in the tet count (Fig. 5.12) that is 1,000 x 200 / 480 = 417 Hz for 480
anisotropic tets) and the CNN with energy propagation on about 1,500 nodes (thesis: 30 Hz on an i7-5500U),
plus explicit and linear-FEM CNN for scale. The rates at the thesis's own sizes are measured too
(``ebm_isotropic_504tets``, ``ebm_anisotropic_216tets``, ``cnn_energy_1452nodes``), not scaled.

The thesis's settings are kept: EBM 20 iterations per step (its 5.3 figures), dt = 1 ms; the CNN with
energy propagation one step per 60 Hz frame (dt = 1/60 s) with energy_rho = 1 m^2/s, which our forward
Euler (4.12) needs 1,482 potential sub-steps to resolve (printed; the numba path evaluates them in closed
form, sim/integrators/cnn/energy.py ModalPropagation). One core: numba and BLAS pinned to one thread. Each rate is the
median of ``repeats`` timed runs (wall time); the load average at the start is printed with them, because the
machine may be shared.

EBM runs with ``--kernel`` (default ``blocked``, sim/integrators/ebm/blocked.py) in float64 (the ``ebm_*_480tets_hz`` keys)
and, in the same run, with the blocked kernel's explicit float32 option (``*_float32_hz``, also at the thesis's
504 tets: not the default; its deviation from float64 is measured in docs/ebm.md) and the scalar numba kernel
(``*_scalar_hz``); the other integrators with ``numba`` (or ``numpy``).

Usage: .venv/bin/python benchmarks/zhang_rates.py [--quick] [--kernel blocked|numba|numpy]
Last line: one JSON object of steps per second ("<case>_hz") with the thesis's reference rates.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, as the thesis's figures (set before NumPy loads BLAS)

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402

import numba  # noqa: E402

from sim.cases.rates import cnn_cube, ebm_block, step_rate


def describe(name: str, integrator, settings: dict, dt: float) -> str:
    """The settings that set the cost of one step, printed beside its rate."""
    parts = [f"dt {dt:.4g} s"]
    if name == "ebm":
        parts.append(f"{integrator.iterations} iterations, {integrator.model.n_tets} tets, kernel {integrator.kernel}, "
                     f"{integrator.precision}")
    else:
        parts.append(f"{integrator.model.n_nodes} nodes, force_model {settings.get('force_model')}")
        energy = getattr(integrator, "energy", None)
        if energy is not None:
            parts.append(f"energy_rho {energy.rho:g} m^2/s, {energy.substeps(dt)} potential sub-steps/step "
                         f"({energy.propagation})")
    return ", ".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps and repeats")
    parser.add_argument("--kernel", choices=("blocked", "numba", "numpy"), default="blocked",
                        help="EBM kernel (default blocked); the other integrators use numba, or numpy with numpy")
    args = parser.parse_args()
    steps, repeats = (20, 3) if args.quick else (100, 7)
    numba.set_num_threads(1)
    result: dict = {}
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    ebm_kernel = {"kernel": args.kernel}
    kernel = {"kernel": "numpy" if args.kernel == "numpy" else "numba"}
    single = [] if args.kernel != "blocked" else [  # the explicit float32 option of the blocked kernel
        ("ebm_isotropic_480tets_float32", "ebm", ebm_block("neo_hookean"),
         {"iterations": 20, "kernel": "blocked", "precision": "float32"}, 1e-3, None),
        ("ebm_anisotropic_480tets_float32", "ebm", ebm_block("anisotropic_neo_hookean", fibre=[0.0, 0.0, 1.0]),
         {"iterations": 20, "kernel": "blocked", "precision": "float32"}, 1e-3, None)]
    scalar = [] if args.kernel != "blocked" else [
        ("ebm_isotropic_480tets_scalar", "ebm", ebm_block("neo_hookean"), {"iterations": 20, "kernel": "numba"}, 1e-3,
         None),
        ("ebm_anisotropic_480tets_scalar", "ebm", ebm_block("anisotropic_neo_hookean", fibre=[0.0, 0.0, 1.0]),
         {"iterations": 20, "kernel": "numba"}, 1e-3, None)]
    cases = [
        ("ebm_isotropic_480tets", "ebm", ebm_block("neo_hookean"), {"iterations": 20, **ebm_kernel}, 1e-3, 1000.0),
        ("ebm_anisotropic_480tets", "ebm", ebm_block("anisotropic_neo_hookean", fibre=[0.0, 0.0, 1.0]),
         {"iterations": 20, **ebm_kernel}, 1e-3, 1000.0 * 200.0 / 480.0),
        *single,
        *scalar,
        ("cnn_energy_1331nodes", "cnn", cnn_cube(), {"force_model": "energy", "K": 4.0, **kernel}, 1.0 / 60.0, 30.0),
        # the thesis's own sizes (Figs. 5.13 and 4.17): ~500 isotropic and ~200 anisotropic tets at 1 kHz,
        # ~1,500 nodes at 30 Hz, measured directly rather than scaled
        ("ebm_isotropic_504tets", "ebm", ebm_block("neo_hookean", cells=(7, 4, 3)), {"iterations": 20, **ebm_kernel},
         1e-3, 1000.0),
        *([("ebm_isotropic_504tets_float32", "ebm", ebm_block("neo_hookean", cells=(7, 4, 3)),
            {"iterations": 20, "kernel": "blocked", "precision": "float32"}, 1e-3, 1000.0)] if single else []),
        ("ebm_anisotropic_216tets", "ebm", ebm_block("anisotropic_neo_hookean", fibre=[0.0, 0.0, 1.0], cells=(4, 3, 3)),
         {"iterations": 20, **ebm_kernel}, 1e-3, 1000.0),
        ("cnn_energy_1452nodes", "cnn", cnn_cube(cells=(10, 10, 11)), {"force_model": "energy", "K": 4.0, **kernel},
         1.0 / 60.0, 30.0),
        # forward Euler needs damping of the highest modes to be stable at all (docs/integrators-zhang.md)
        ("cnn_linear_fem_1331nodes", "cnn", cnn_cube(),
         {"force_model": "linear_fem", "K": 4.0, "rayleigh_beta": 0.002, **kernel}, 1e-3, None),
        ("explicit_linear_fem_1331nodes", "explicit", cnn_cube(),
         {"force_model": "linear_fem", "rayleigh_beta": 0.002, **kernel}, 1e-3, None),
    ]
    for key, name, model, settings, dt, thesis in cases:
        hz, integrator = step_rate(name, model, settings, dt, steps, repeats)
        result[f"{key}_hz"] = round(hz, 1)
        if thesis is not None:
            result[f"{key}_thesis_hz"] = thesis
        print(f"{key:32s} {hz:9.1f} steps/s" + (f"   (thesis {thesis:g} Hz)" if thesis else "")
              + f"   [{describe(name, integrator, settings, dt)}]")
    result["settings"] = {"ebm_iterations": 20, "ebm_dt_s": 1e-3, "ebm_precision": "float64 (*_float32_hz: float32)",
                          "cnn_energy_dt_s": round(1.0 / 60.0, 6),
                          "energy_rho_m2_per_s": 1.0, "steps": steps, "repeats": repeats, "statistic": "median"}
    result["machine"] = (f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cpus, 1 numba thread, "
                         f"1 BLAS thread, ebm kernel {args.kernel}, load average {load:.2f} at the start")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
