"""The long soaks of the hard cases (sim.cases.soak): an undamped XPBD cantilever (1 ms steps) and the
dynamic backward-Euler reference on a clamped cube (10 ms steps), 10,000 steps each (the test suite runs
1,000). Neither may gain energy; the reference must come to rest.

Usage: .venv/bin/python benchmarks/soak.py [--quick] [--steps N]
Last line: one JSON object with each soak's start energy, peak energy, final largest displacement and speed,
and its wall time.
"""
from __future__ import annotations

import argparse
import json
import platform
import time

import numba

from sim.cases.soak import reference_cube_soak, xpbd_beam_soak


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2,000 steps instead of 10,000")
    parser.add_argument("--steps", type=int, default=None)
    args = parser.parse_args()
    steps = args.steps or (2000 if args.quick else 10_000)
    result = {"steps": steps}
    for name, run in (("xpbd_beam", xpbd_beam_soak), ("reference_cube", reference_cube_soak)):
        t0 = time.perf_counter()
        soak = run(steps)
        wall = time.perf_counter() - t0
        gain = float(soak.energy.max() - soak.e0)
        result[name] = {"e0_J": soak.e0, "peak_J": float(soak.energy.max()), "energy_gain_J": gain,
                        "bounded": bool(gain <= 1e-9 * max(1.0, abs(soak.e0))),
                        "max_displacement_m": soak.max_displacement, "max_speed_m_s": soak.max_speed,
                        "wall_s": round(wall, 2)}
        print(f"{name}: {steps} steps, peak - start {gain:.3e} J, final |v| {soak.max_speed:.2e} m/s, {wall:.1f} s")
    result["machine"] = f"{platform.machine()} {numba.config.NUMBA_NUM_THREADS} numba threads"
    print(json.dumps(result))


if __name__ == "__main__":
    main()
