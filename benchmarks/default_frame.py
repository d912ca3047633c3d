"""Seconds per frame of ``make render``'s scene (scenes/default.toml) at 640x480 with every effect it uses
(XPBD step, render-surface embedding, raster, SSS thickness, light sampling with shadows, wet coats, the lens,
the hd_scope post-effects with depth of field, PNG encoding), per stage, on the machine's cores (2 numba threads
where it has them). Issue 19 asks for at most 1 s per frame on 2 cores.

Usage: .venv/bin/python benchmarks/default_frame.py [--quick]
Frames 1 and 2 (compilation, tables) are not timed; then frames 3, 4, ... are simulated and rendered in order,
as ``tissuerender render`` does (``--quick``: 2 timed frames, else 6), and the median of each stage is reported.
Last line: one JSON object: ``seconds_per_frame`` (median wall time of a whole frame), ``stages`` (median seconds
per stage, the pipeline's own stage names; ``shade`` excludes ``shadow_rays``, which run inside it), ``threads``,
``resolution``, ``target_seconds`` (1.0), ``machine``. On a shared machine the figure is an upper bound.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

# benchmarks/postfx.py would shadow the postfx package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numba  # noqa: E402

import postfx  # noqa: E402
from tissuerender import load_scene  # noqa: E402
from tissuerender.checks import check_scene  # noqa: E402
from tissuerender.files import write_png  # noqa: E402
from tissuerender.pipeline import frame_seed, postprocess, render_hdr  # noqa: E402
from tissuerender.stages import StageRecorder  # noqa: E402
from tissuerender.world import advance  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "default.toml"
RESOLUTION = (640, 480)
TARGET_SECONDS = 1.0


def one_frame(scene, plan, world, k: int, folder: Path) -> tuple[float, dict]:
    """Advance to frame ``k`` and render it as ``tissuerender render`` does: (wall seconds, stage seconds)."""
    rec = StageRecorder()
    start = time.perf_counter()
    if "simulate" in plan:
        advance(world, scene, rec)
    seed = frame_seed(scene, k)
    t = (k - 1) / scene.output.fps
    result, _ = render_hdr(world, scene, plan, rec, t, seed, *RESOLUTION)
    image, _ = postprocess(scene, result.hdr, result.depth, rec, seed, *RESOLUTION, frame=k)
    with rec.run("png"):
        write_png(folder / f"frame_{k:04d}.png", postfx.to_uint8(image))
    wall = time.perf_counter() - start
    seconds = dict(rec.seconds)
    seconds["shade"] = seconds.get("shade", 0.0) - seconds.get("shadow_rays", 0.0)  # shadow rays run inside shade
    return wall, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 timed frames instead of 6")
    args = parser.parse_args()
    threads = min(2, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(threads)
    scene = load_scene(SCENE)
    scene = dataclasses.replace(scene, output=scene.output.model_copy(update={"resolution": list(RESOLUTION)}))
    checked = check_scene(scene)
    plan, world = checked.plan, checked.world
    frames = 2 if args.quick else 6
    walls, stages = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rec = StageRecorder()  # frames 1 and 2, untimed: compilation (renderer, then solver) and material tables
        result, _ = render_hdr(world, scene, plan, rec, 0.0, frame_seed(scene, 1), *RESOLUTION)
        postprocess(scene, result.hdr, result.depth, rec, frame_seed(scene, 1), *RESOLUTION, frame=1)
        one_frame(scene, plan, world, 2, folder)
        for k in range(3, 3 + frames):
            wall, seconds = one_frame(scene, plan, world, k, folder)
            walls.append(wall)
            for name, s in seconds.items():
                stages.setdefault(name, []).append(s)
            print(f"frame {k}: {wall:.3f} s", flush=True)
    median = {name: round(statistics.median(v + [0.0] * (frames - len(v))), 4) for name, v in stages.items()}
    ordered = dict(sorted(median.items(), key=lambda kv: -kv[1]))
    per_frame = statistics.median(walls)
    for name, s in ordered.items():
        print(f"  {name:24s} {s:7.3f} s  {100.0 * s / per_frame:5.1f} %")
    print(f"default at {RESOLUTION[0]}x{RESOLUTION[1]}, {threads} thread(s): {per_frame:.3f} s/frame "
          f"(target {TARGET_SECONDS} s)")
    print(json.dumps({"seconds_per_frame": round(per_frame, 3), "stages": ordered, "threads": threads,
                      "resolution": list(RESOLUTION), "frames_timed": frames, "target_seconds": TARGET_SECONDS,
                      "machine": f"{platform.machine()} {os.cpu_count()} cpus"}))


if __name__ == "__main__":
    main()
