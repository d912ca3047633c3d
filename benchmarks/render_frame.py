"""Seconds per frame of the CPU deferred renderer: one 640x480 frame of scenes/liver_probe.toml with
16 light samples, shadows and SSS, split into stages, with 1 and 2 numba threads.

Usage: .venv/bin/python benchmarks/render_frame.py [--quick]
Last line: one JSON object with seconds_per_frame_t1, seconds_per_frame_t2 and per-stage seconds
("<stage>_t<threads>"). Stages: raster (G-buffer), bvh (build), thickness (SSS rays), shadow_rays,
shade (light sampling and BRDF, shadow rays excluded). Post-effects are not included
(benchmarks/postfx.py measures them). The first frame (compilation) is not timed.
Rays go through Intel Embree (embreex) when it is installed, as the renderer does; the same frame is
then timed again with the project's numba BVH (keys with the suffix ``_numba_bvh``), the comparison
behind that choice.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

# benchmarks/postfx.py would shadow the postfx package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numba  # noqa: E402

from tissuerender import load_scene, make_plan  # noqa: E402
from tissuerender.pipeline import build_world, render_hdr  # noqa: E402
from tissuerender.renderer import rays  # noqa: E402
from tissuerender.stages import StageRecorder  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "liver_probe.toml"
STAGES = ("raster", "bvh", "thickness", "shadow_rays", "shade")


def benchmark_scene():
    scene = load_scene(SCENE)
    return dataclasses.replace(
        scene,
        light=scene.light.model_copy(update={"samples": 16}),
        effects=scene.effects.model_copy(update={"shadows": True, "sss": True}),
        output=scene.output.model_copy(update={"resolution": [640, 480], "supersampling": 1}),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one timed frame per thread count")
    args = parser.parse_args()
    scene = benchmark_scene()
    plan = make_plan(scene)
    world = build_world(scene, plan, StageRecorder())
    result: dict = {}
    repeats = 1 if args.quick else 3
    triangles = None
    backends = [("embree", "")] if rays.embree_available() else []
    backends.append(("numba", "_numba_bvh" if backends else ""))
    result["ray_backend"] = backends[0][0]
    for backend, suffix in backends:
        if backend == "numba":
            rays.embree_available = lambda: False  # the project's own BVH, for comparison
        for threads in (1, 2):
            if threads > numba.config.NUMBA_NUM_THREADS:
                continue
            numba.set_num_threads(threads)
            render_hdr(world, scene, plan, StageRecorder(), 0.0, scene.seed)  # warm-up (compilation)
            totals, per_stage = [], {s: [] for s in STAGES}
            for _ in range(repeats):
                rec = StageRecorder()
                start = time.perf_counter()
                render_hdr(world, scene, plan, rec, 0.0, scene.seed)
                wall = time.perf_counter() - start
                sec = dict(rec.seconds)
                sec["shade"] = sec.get("shade", 0.0) - sec.get("shadow_rays", 0.0)  # shadow rays run inside shade
                for s in STAGES:
                    per_stage[s].append(sec.get(s, 0.0))
                totals.append(wall)  # the whole call: stages, embedding and everything between them
            key = f"t{threads}{suffix}"
            result[f"seconds_per_frame_{key}"] = round(statistics.median(totals), 3)
            for s in STAGES:
                result[f"{s}_{key}"] = round(statistics.median(per_stage[s]), 3)
            line = "  ".join(f"{s} {result[f'{s}_{key}']:.3f}" for s in STAGES)
            print(f"{backend:6s} rays, {threads} thread(s): {result[f'seconds_per_frame_{key}']:.3f} s/frame  ({line})")
    triangles = sum(len(b.surface.triangles) for b in world.bodies) + sum(len(s.surface.triangles) for s in world.surfaces)
    result["render_triangles"] = int(triangles)
    result["machine"] = f"{platform.machine()} {os.cpu_count()} cpus"
    print(json.dumps(result))


if __name__ == "__main__":
    main()
