"""What the ground-truth passes cost (issue 18, "Performance"): one 640x480 frame of scenes/liver_probe.toml,
colour alone (render, post-effects, PNG) against colour plus all four single-frame passes (depth, normal,
segmentation, material_coords: their raster, each pass, and the passes/*.npy files), then plus the EXR and 16-bit
depth PNG; then every pass with its master files only (the four plus flow, scene_flow and tracks: the frame's
render geometry and its geometry file, and the frame's share of the sequence's motion passes,
``groundtruth.finish_sequence`` over MOTION_FRAMES frames writing the flow .npy masters and tracks.npz with its
TAP-Vid layouts, divided by MOTION_FRAMES), then every pass with every file (the EXR, depth PNG, and the flow's
.flo / KITTI PNG / EXR layers).

Usage: .venv/bin/python benchmarks/passes_cost.py [--quick] [--rounds N]
The variants run in interleaved rounds (colour, colour + passes, ..., colour, ...) after one warm-up each, so
a machine that slows down or speeds up during the run affects them alike; the figures are medians over the
rounds. ``--quick``: 160x120 and two rounds, to check the script works. Last line: one JSON object with
``seconds_colour``, ``seconds_colour_passes`` (passes and their .npy files), ``seconds_colour_passes_files``
(and the EXR and depth PNG), ``seconds_colour_all`` (every pass and its master files, the motion passes' share
included), ``seconds_colour_all_files`` (and every other format), the ratios ``ratio_passes``,
``ratio_passes_files``, ``ratio_all`` and ``ratio_all_files`` (to colour alone) and the per-stage medians of the
last variant from its stage recorder (``stage_<name>``, per frame).
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
from tissuerender.groundtruth.sequence import MOTION_PASSES  # noqa: E402
from tissuerender.pipeline import frame_seed, postprocess, render_hdr  # noqa: E402
from tissuerender.render_inputs import camera_for  # noqa: E402
from tissuerender.stages import StageRecorder  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "liver_probe.toml"
MOTION_FRAMES = 4  # frames of the short sequence whose motion passes are timed (the probe moves between them)


def frame(world, scene, plan, out: Path, passes: list[str], files: bool, index: int = 1) -> tuple[float, StageRecorder]:
    """One frame as the pipeline makes it: render, post-effects, PNG, and the passes' files when asked (the
    render geometry of frame ``index`` when a motion pass is). Returns (wall seconds, the stage recorder)."""
    rec = StageRecorder()
    t = (index - 1) / scene.output.fps
    seed = frame_seed(scene, index)
    start = time.perf_counter()
    result, _ = render_hdr(world, scene, plan, rec, t, seed, passes=passes)
    image, _ = postprocess(scene, result.hdr, result.depth, rec, seed, frame=1)
    with rec.run("write_png"):
        write_png(out / "frame_0001.png", postfx.to_uint8(image))
    if passes:
        with rec.run("write_passes"):
            groundtruth.write_passes(out, index, result.passes, list(range(1, len(world.bodies) + 1)),
                                     groundtruth.scope_mask_id(scene))
    if any(name in MOTION_PASSES for name in passes):
        with rec.run("write_geometry"):
            groundtruth.write_geometry(out, index, result.geometry, t)
    if files:
        K = groundtruth.intrinsics(camera_for(scene, t=t))
        formats.write_frame_formats(out, index, ["exr", "depth_png"], result.hdr, result.passes, K,
                                    formats.depth_png_scale(scene.camera.far), rec)
    return time.perf_counter() - start, rec


def motion_share(scene, out: Path, files: bool) -> tuple[float, StageRecorder]:
    """The sequence's motion passes from the MOTION_FRAMES frames' geometry in ``out`` (flows of each frame to
    its neighbours, tracks.npz and its TAP-Vid files; with ``files`` the flow's .flo / KITTI / EXR layers), per
    frame: (wall seconds / MOTION_FRAMES, the stage recorder)."""
    rec = StageRecorder()
    frames = range(1, MOTION_FRAMES + 1)
    start = time.perf_counter()
    groundtruth.finish_sequence(out, scene, set(frames), MOTION_FRAMES, rec)
    if files:
        with rec.run("write_flow_files"):
            formats.complete_from_masters(out, list(frames), ["exr"])
    return (time.perf_counter() - start) / MOTION_FRAMES, rec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="160x120, two rounds: checks the script works")
    parser.add_argument("--rounds", type=int, default=None, help="interleaved rounds (default 7, --quick 2)")
    args = parser.parse_args()
    scene = load_scene(SCENE)
    width, height = (160, 120) if args.quick else (640, 480)
    every = list(groundtruth.ALL_PASS_NAMES)
    scene = dataclasses.replace(scene, output=scene.output.model_copy(update={"resolution": [width, height],
                                                                             "passes": every}))
    checked = check_scene(scene)
    world, plan = checked.world, checked.plan
    rounds = args.rounds or (2 if args.quick else 7)
    variants = {"colour": ([], False), "colour_passes": (list(groundtruth.PASS_NAMES), False),
                "colour_passes_files": (list(groundtruth.PASS_NAMES), True), "colour_all": (every, False),
                "colour_all_files": (every, True)}
    seconds = {name: [] for name in variants}
    stages: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for name, (passes, files) in variants.items():
            frame(world, scene, plan, out, passes, files)  # warm-up: compilation, caches
        for index in range(2, MOTION_FRAMES + 1):  # the rest of the motion passes' sequence (frame 1 is there)
            frame(world, scene, plan, out, every, True, index)
        # their EXRs as a frame writes them, before finish_sequence adds the flow layers: put back before each
        # timed finish_sequence, so every round rewrites every frame's EXR as a render does (untimed copy)
        fresh = {k: formats.exr_path(out, k).read_bytes() for k in range(2, MOTION_FRAMES + 1)}
        motion_share(scene, out, True)
        for _ in range(rounds):
            for name, (passes, files) in variants.items():
                wall, rec = frame(world, scene, plan, out, passes, files)
                if name.startswith("colour_all"):
                    if files:
                        for k, data in fresh.items():
                            formats.exr_path(out, k).write_bytes(data)
                    share, motion_rec = motion_share(scene, out, files)
                    wall += share
                    for stage, s in motion_rec.seconds.items():
                        rec.seconds[stage] = rec.seconds.get(stage, 0.0) + s / MOTION_FRAMES
                    if files:
                        for stage, s in rec.seconds.items():
                            stages.setdefault(stage, []).append(s)
                seconds[name].append(wall)
    med = {name: statistics.median(v) for name, v in seconds.items()}
    result = {f"seconds_{name}": round(v, 4) for name, v in med.items()}
    result["ratio_passes"] = round(med["colour_passes"] / med["colour"], 4)
    result["ratio_passes_files"] = round(med["colour_passes_files"] / med["colour"], 4)
    result["ratio_all"] = round(med["colour_all"] / med["colour"], 4)
    result["ratio_all_files"] = round(med["colour_all_files"] / med["colour"], 4)
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
