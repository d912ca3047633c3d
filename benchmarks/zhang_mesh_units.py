"""CPU time of each unit of the accuracy report's ``zhang_mesh`` study (``tissuerender.report.zhang_mesh.units``:
one quasi-static reference per case, element and level), one at a time in this process, after a warm-up of every
element kind on the test suite's sweep (so no unit pays numba's compilation).

Usage: NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/zhang_mesh_units.py [--level full] [--skip ID,ID]
Prints one JSON line per unit as it finishes: {"unit": ID, "cpu_s": ..., "wall_s": ..., "nodes": ..., "tets": ...,
"newton_iterations_last": ...}; a skipped unit prints {"unit": ID, "skipped": true}.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

# benchmarks/postfx.py would shadow the postfx package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

from tissuerender.report import zhang_mesh  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", default="full", choices=sorted(zhang_mesh.SWEEPS))
    parser.add_argument("--skip", default="", help="comma-separated unit ids not to run")
    parser.add_argument("--only", default="", help="comma-separated unit ids to run (default: all)")
    args = parser.parse_args()
    skip = {s for s in args.skip.split(",") if s}
    only = {s for s in args.only.split(",") if s}
    zhang_mesh.run_zhang_mesh(zhang_mesh.SWEEPS["tiny"])  # warm-up: compiles every element kind's kernels
    sweep = zhang_mesh.SWEEPS[args.level]
    # cheapest first, so an interrupted run has measured the most units
    for unit in reversed(zhang_mesh.units(sweep)):
        uid = zhang_mesh.unit_id(unit)
        if uid in skip or (only and uid not in only):
            print(json.dumps({"unit": uid, "skipped": True}), flush=True)
            continue
        cpu0, wall0 = time.process_time(), time.perf_counter()
        row = zhang_mesh.run_unit(unit)
        print(json.dumps({"unit": uid, "cpu_s": round(time.process_time() - cpu0, 2),
                          "wall_s": round(time.perf_counter() - wall0, 2), "nodes": row["nodes"], "tets": row["tets"],
                          "newton_iterations_last": row["newton_iterations_last"]}), flush=True)


if __name__ == "__main__":
    main()
