"""Post-effects cost: milliseconds per effect on a 640x480 frame, NumPy reference vs OSMesa GLSL.

Usage: .venv/bin/python benchmarks/postfx.py [--quick]
Last line: one JSON object with numpy_ms_total, osmesa_ms_total (the whole chain of all ten effects,
end to end: for osmesa with its one upload and one read-back), numpy_ms_core and osmesa_ms_core (the
required effects only, without the optional bloom, blur, sharpen, sensor noise, lens flare),
"<effect>_<backend>_ms" keys (each effect timed inside the chain; the osmesa backend waits for the GL
side to finish after each effect) and osmesa_over_numpy, the median over runs of the ratio of the two
totals measured back to back (the machine is shared: compare within one run).
Each figure is the median of several runs after one warm-up (compilation, context creation).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

# This script is called postfx.py: keep its own folder off the import path so that
# "import postfx" finds the package, not this file.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numba  # noqa: E402
import numpy as np  # noqa: E402

import postfx  # noqa: E402
from postfx import osmesa  # noqa: E402
from postfx.params import (Bloom, Blur, ChromaticAberration, ColorGrade, DepthOfField, LaparoscopeMask,  # noqa: E402
                           LensFlare, SensorNoise, Sharpen, Tonemap)

W, H = 640, 480
CHAIN = [("depth_of_field", DepthOfField(focus_distance=0.1, aperture=0.002, max_radius_px=8.0)),
         ("chromatic_aberration", ChromaticAberration()),
         ("lens_flare", LensFlare()),
         ("bloom", Bloom()),
         ("blur", Blur()),
         ("sensor_noise", SensorNoise()),
         ("tonemap", Tonemap()),
         ("color_grade", ColorGrade(contrast=1.2, curve=[[0.0, 0.0], [0.5, 0.45], [1.0, 1.0]], saturation=0.9)),
         ("sharpen", Sharpen()),
         ("laparoscope_mask", LaparoscopeMask())]

# the required effects (bloom, blur, sharpen, sensor noise and lens flare are its optional ones)
CORE = ("depth_of_field", "chromatic_aberration", "tonemap", "color_grade", "laparoscope_mask")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    repeats = 5 if args.quick else 15
    rng = np.random.default_rng(0)
    hdr = (rng.random((H, W, 3)) * 3.0).astype(np.float32)
    hdr[200:204, 420:424] = 60.0  # a specular highlight for the bloom and the lens flare
    depth = (0.05 + rng.random((H, W)) * 0.2).astype(np.float32)
    lens = postfx.Lens(70.0, W, H)
    backends = ["numpy"] + (["osmesa"] if osmesa.library_available() else [])
    runs: dict = {b: [] for b in backends}
    for backend in backends:  # warm-up: compilation, context creation, shader compilation
        postfx.apply_chain(hdr, depth, CHAIN, lens, backend=backend, seed=1)
    for r in range(repeats):  # the backends alternate, so both see the same machine load
        for backend in backends:
            runs[backend].append(postfx.apply_chain(hdr, depth, CHAIN, lens, backend=backend, seed=r))
    result: dict = {}
    for backend in backends:
        for name, _ in CHAIN:
            ms = float(np.median([run.seconds[name] for run in runs[backend]])) * 1e3
            result[f"{name}_{backend}_ms"] = round(ms, 2)
            print(f"{backend:7s} {name:22s} {ms:8.2f} ms")
        total = float(np.median([run.total_seconds for run in runs[backend]])) * 1e3
        result[f"{backend}_ms_total"] = round(total, 2)
        result[f"{backend}_ms_core"] = round(sum(result[f"{n}_{backend}_ms"] for n in CORE), 2)
        print(f"{backend:7s} {'total':22s} {total:8.2f} ms")
    if "osmesa" in backends:
        ratios = [o.total_seconds / n.total_seconds for n, o in zip(runs["numpy"], runs["osmesa"])]
        result["osmesa_over_numpy"] = round(float(np.median(ratios)), 3)
        print(f"osmesa / numpy (median of {repeats} back-to-back runs): {result['osmesa_over_numpy']:.3f}")
    if "osmesa" not in backends:
        result["osmesa_ms_total"] = None
        result["osmesa_skipped"] = "libOSMesa missing (Debian package libosmesa6)"
    result["machine"] = (f"{platform.machine()} {os.cpu_count()} cpus, numba threads {numba.get_num_threads()}, "
                         f"LP_NUM_THREADS {os.environ.get('LP_NUM_THREADS', 'default')}, "
                         f"load average {os.getloadavg()[0]:.2f}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
