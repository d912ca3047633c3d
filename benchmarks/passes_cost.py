"""What the ground-truth passes cost (issue 18, "Performance"): one 640x480 frame of scenes/liver_probe.toml,
colour alone (render, post-effects, PNG) against colour plus all four passes (depth, normal, segmentation,
material_coords: their raster, each pass, and the passes/*.npy files), then plus the EXR and 16-bit depth PNG.

Usage: .venv/bin/python benchmarks/passes_cost.py [--quick]
The two variants run in interleaved rounds (colour, colour + passes, colour, ...) after one warm-up each, so
a machine that slows down or speeds up during the run affects both alike; the figures are medians over the
rounds. ``--quick``: 160x120 and two rounds, to check the script works. Last line: one JSON object with
``seconds_colour``, ``seconds_colour_passes`` (passes and their .npy files), ``seconds_colour_passes_files``
(and the EXR and depth PNG), the ratios ``ratio_passes`` and ``ratio_passes_files`` (to colour alone) and the
per-stage medians of the passes variant from its stage recorder (``stage_<name>``).
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

import postfx  # noqa: E402
from tissuerender import groundtruth, load_scene  # noqa: E402
from tissuerender.checks import check_scene  # noqa: E402
from tissuerender.files import write_png  # noqa: E402
from tissuerender.groundtruth import formats  # noqa: E402
from tissuerender.pipeline import frame_seed, postprocess, render_hdr  # noqa: E402
from tissuerender.render_inputs import camera_for  # noqa: E402
from tissuerender.stages import StageRecorder  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "liver_probe.toml"


def frame(world, scene, plan, out: Path, passes: list[str], files: bool) -> tuple[float, StageRecorder]:
    """One frame as the pipeline makes it: render, post-effects, PNG, and the passes' files when asked.
    Returns (wall seconds, the stage recorder)."""
    rec = StageRecorder()
    seed = frame_seed(scene, 1)
    start = time.perf_counter()
    result, _ = render_hdr(world, scene, plan, rec, 0.0, seed, passes=passes)
    image, _ = postprocess(scene, result.hdr, result.depth, rec, seed, frame=1)
    with rec.run("write_png"):
        write_png(out / "frame_0001.png", postfx.to_uint8(image))
    if passes:
        with rec.run("write_passes"):
            groundtruth.write_passes(out, 1, result.passes, list(range(1, len(world.bodies) + 1)),
                                     groundtruth.scope_mask_id(scene))
    if files:
        K = groundtruth.intrinsics(camera_for(scene))
        formats.write_frame_formats(out, 1, ["exr", "depth_png"], result.hdr, result.passes, K,
                                    formats.depth_png_scale(scene.camera.far), rec)
    return time.perf_counter() - start, rec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="160x120, two rounds: checks the script works")
    args = parser.parse_args()
    scene = load_scene(SCENE)
    width, height = (160, 120) if args.quick else (640, 480)
    scene = dataclasses.replace(scene, output=scene.output.model_copy(update={"resolution": [width, height]}))
    checked = check_scene(scene)
    world, plan = checked.world, checked.plan
    rounds = 2 if args.quick else 7
    variants = {"colour": ([], False), "colour_passes": (list(groundtruth.PASS_NAMES), False),
                "colour_passes_files": (list(groundtruth.PASS_NAMES), True)}
    seconds = {name: [] for name in variants}
    stages: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for name, (passes, files) in variants.items():
            frame(world, scene, plan, out, passes, files)  # warm-up: compilation, caches
        for _ in range(rounds):
            for name, (passes, files) in variants.items():
                wall, rec = frame(world, scene, plan, out, passes, files)
                seconds[name].append(wall)
                if name == "colour_passes_files":
                    for stage, s in rec.seconds.items():
                        stages.setdefault(stage, []).append(s)
    med = {name: statistics.median(v) for name, v in seconds.items()}
    result = {f"seconds_{name}": round(v, 4) for name, v in med.items()}
    result["ratio_passes"] = round(med["colour_passes"] / med["colour"], 4)
    result["ratio_passes_files"] = round(med["colour_passes_files"] / med["colour"], 4)
    result.update({f"stage_{s}": round(statistics.median(v), 4) for s, v in sorted(stages.items())})
    result.update(resolution=[width, height], rounds=rounds, machine=f"{platform.machine()} {os.cpu_count()} cpus")
    print(f"liver_probe {width}x{height}, median of {rounds} interleaved rounds:")
    for name, v in med.items():
        print(f"  {name:20s} {v:8.3f} s  ({v / med['colour']:.3f} x colour)")
    for s in sorted(stages):
        if s.startswith(("passes", "write_")):
            print(f"  stage {s:24s} {result[f'stage_{s}']:8.4f} s")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
