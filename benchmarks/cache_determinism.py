"""Same positions whether numba compiles the kernels or loads them from its cache (docs/xpbd.md, "Determinism").

Steps the model of benchmarks/contact_cost.py (liver_probe's liver and a fat slab, probe, grasp, contacts; xpbd)
in two fresh processes sharing an empty ``NUMBA_CACHE_DIR``: the first compiles every kernel (and saves it),
the second loads them. Prints the SHA-256 of the node positions after steps 1, 5, 20 (and 60 without
``--quick``) of each. Usage: .venv/bin/python benchmarks/cache_determinism.py [--quick]
Last line: one JSON object with both runs' hashes and ``equal``. Takes a few minutes (the first run compiles).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import hashlib, importlib.util, os, sys
import numpy as np
spec = importlib.util.spec_from_file_location("contact_cost", sys.argv[1])
cc = importlib.util.module_from_spec(spec); spec.loader.exec_module(cc)
from sim.model import State
from tissuerender.checks import check_scene
scene = cc.scene_with_contact()
stepper = check_scene(scene).world.integrators[0]
state, dt = State.at_rest(stepper.group.group.model), scene.simulation.dt
marks = [int(m) for m in sys.argv[2].split(",")]
for i in range(1, marks[-1] + 1):
    state = stepper.integrator.step(state, dt)
    if i in marks:
        print(i, hashlib.sha256(np.ascontiguousarray(state.x).tobytes()).hexdigest())
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 steps, not 60")
    args = parser.parse_args()
    marks = "1,5,20" if args.quick else "1,5,20,60"
    runs = {}
    with tempfile.TemporaryDirectory(prefix="tissuerender-numba-cache-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "NUMBA_NUM_THREADS": "1"}
        for name in ("compiled", "cached"):
            out = subprocess.run([sys.executable, "-c", CHILD, str(HERE / "contact_cost.py"), marks], env=env,
                                 cwd=HERE.parent, capture_output=True, text=True, check=True).stdout
            runs[name] = dict(line.split() for line in out.splitlines() if line[:1].isdigit())
            print(name, runs[name], flush=True)
    print(json.dumps({"runs": runs, "equal": runs["compiled"] == runs["cached"]}))


if __name__ == "__main__":
    main()
