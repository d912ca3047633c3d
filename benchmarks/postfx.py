"""Post-effects cost: milliseconds per effect on a 640x480 frame, NumPy reference vs OSMesa GLSL.

Usage: .venv/bin/python benchmarks/postfx.py [--quick] [--refresh-frame] [--pause-ms 50] [--backends numpy,osmesa]
Two frames, each through the whole chain of all ten effects:
- synthetic (the keys without suffix): uniform random HDR in [0, 3] with a 60x highlight, depth
  uniform random per pixel in [0.05, 0.25] m (focus 0.1 m, aperture 2 mm, max CoC 8 px): every pixel
  has its own random CoC, the worst case for a DoF gather;
- rendered (suffix ``_rendered``): the HDR and depth of scenes/liver_probe.toml at 640x480 from the
  renderer (cached in the temporary directory; ``--refresh-frame`` renders it again), with the
  scene's hd_scope preset (chromatic aberration, tone map, mask parameters), the default
  depth of field (the preset has no DoF table: focus 0.1 m, aperture 1 mm, max radius 12 px, the
  scene's 75 degree field of view) and the synthetic chain's other effects.
Last line: one JSON object with numpy_ms_total, osmesa_ms_total (the whole chain end to end: for
osmesa with its one upload and one read-back), osmesa_over_numpy (the median over runs of the ratio
of the two totals measured back to back: the machine is shared, compare within one run), the same
three with ``_rendered``, "<effect>_<backend>_ms" (each effect alone, on the image it receives in
the synthetic chain, medians; in the chain the osmesa backend draws a run of pointwise effects in
the last pass of the effect before it, so the chain total is less than their sum), numpy_ms_core
and osmesa_ms_core (the sum of the required effects alone: DoF, CA, tone map, grade, mask),
numpy_cpu_ms_total / osmesa_cpu_ms_total (and _rendered): the median CPU time of the process over
the chain, all threads (numba's and llvmpipe's), which a busy machine inflates less than the wall
time (OpenMP workers spinning while they wait count too); osmesa_pass_ms (and _rendered): the
osmesa chain pass by pass ("<pass>[+fused effects] <width>x<height>", plus the DoF's CPU steps and
the read-back), each draw waited for before and after, medians over the runs after the chains.
Each figure is the median of several runs after one warm-up (compilation, context creation); every
timed chain starts after a 50 ms pause (PAUSE_S: numba's OpenMP workers stop spinning); the effects
alone run back to back, each backend's runs together. ``--backends osmesa`` (or ``numpy``) times one
backend in the process (no ratio keys).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

# This script is called postfx.py: keep its own folder off the import path so that
# "import postfx" finds the package, not this file.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numba  # noqa: E402
import numpy as np  # noqa: E402

import postfx  # noqa: E402
from postfx.bloom import Bloom  # noqa: E402
from postfx.blur import Blur  # noqa: E402
from postfx.chromatic_aberration import ChromaticAberration  # noqa: E402
from postfx.color_grade import ColorGrade  # noqa: E402
from postfx.depth_of_field import DepthOfField  # noqa: E402
from postfx.gl.context import Context  # noqa: E402
from postfx.gl.library import library_available  # noqa: E402
from postfx.laparoscope_mask import LaparoscopeMask  # noqa: E402
from postfx.lens_flare import LensFlare  # noqa: E402
from postfx.sensor_noise import SensorNoise  # noqa: E402
from postfx.sharpen import Sharpen  # noqa: E402
from postfx.tonemap import Tonemap  # noqa: E402
from tissuerender import load_scene, make_plan  # noqa: E402
from tissuerender.pipeline import build_world, render_hdr  # noqa: E402
from tissuerender.stages import StageRecorder  # noqa: E402

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
SCENE = Path(__file__).resolve().parents[1] / "scenes" / "liver_probe.toml"


def synthetic_frame():
    rng = np.random.default_rng(0)
    hdr = (rng.random((H, W, 3)) * 3.0).astype(np.float32)
    hdr[200:204, 420:424] = 60.0  # a specular highlight for the bloom and the lens flare
    depth = (0.05 + rng.random((H, W)) * 0.2).astype(np.float32)
    return hdr, depth, postfx.Lens(70.0, W, H), CHAIN


def rendered_frame(refresh: bool):
    """liver_probe's HDR and depth at 640x480 (cached by the scene file's hash), its lens and chain."""
    scene = load_scene(SCENE)
    digest = hashlib.sha256(SCENE.read_bytes()).hexdigest()[:12]
    cache = Path(tempfile.gettempdir()) / f"tissuerender_postfx_liver_probe_{W}x{H}_{digest}.npz"
    if refresh or not cache.exists():
        plan = make_plan(scene)
        world = build_world(scene, plan, StageRecorder())
        result, _ = render_hdr(world, scene, plan, StageRecorder(), 0.0, scene.seed, W, H)
        np.savez(cache, hdr=result.hdr.astype(np.float32), depth=result.depth.astype(np.float32))
    data = np.load(cache)
    preset = dict(scene.effect_chain())  # hd_scope: chromatic aberration, tone map, mask
    chain = [(name, preset.get(name, params)) for name, params in CHAIN]
    chain[0] = ("depth_of_field", DepthOfField())  # the preset has no DoF table: the defaults
    return data["hdr"], data["depth"], postfx.Lens(scene.camera.fov_deg, W, H), chain


# Every timed run starts after this pause. numba's OpenMP workers (libgomp) spin for a while after each
# parallel region before they sleep, and an osmesa chain started right after a numpy chain shared the
# two cores with them. A program uses one backend; the pause keeps one backend's idle workers out of
# the other's time (docs/postfx.md, "How fast, and why").
PAUSE_S = 0.05


def _set_pause(seconds: float) -> None:
    global PAUSE_S
    PAUSE_S = seconds


def time_chains(hdr, depth, lens, chain, backends, repeats):
    """Whole-chain runs, the backends alternating (and which goes first) so that both see the same machine
    load."""
    for backend in backends:  # warm-up: compilation, context creation, shader compilation
        postfx.apply_chain(hdr, depth, chain, lens, backend=backend, seed=1)
    runs: dict = {b: [] for b in backends}
    cpu: dict = {b: [] for b in backends}
    for r in range(repeats):
        # the order alternates: in one process a chain ran slower right after the other backend's chain
        # than after its own
        for backend in (backends if r % 2 == 0 else backends[::-1]):
            time.sleep(PAUSE_S)
            c0 = time.process_time()
            runs[backend].append(postfx.apply_chain(hdr, depth, chain, lens, backend=backend, seed=r))
            cpu[backend].append(time.process_time() - c0)
    return runs, cpu


def profile_passes(hdr, depth, lens, chain, repeats):
    """The osmesa chain pass by pass: each draw waits for the one before and for itself (so the sum is a
    little above the chain's own time), medians over ``repeats`` chains, in ms, keyed by pass and size."""
    ctx = Context.get()
    runs = []
    for r in range(repeats + 1):
        time.sleep(PAUSE_S)
        ctx.profile = {}
        try:
            postfx.apply_chain(hdr, depth, chain, lens, backend="osmesa", seed=r)
        finally:
            profile, ctx.profile = ctx.profile, None
        if r:  # the first run compiles
            runs.append(profile)
    return {k: round(float(np.median([run.get(k, 0.0) for run in runs]) * 1e3), 2) for k in runs[0]}


def time_effects(hdr, depth, lens, chain, backends, repeats):
    """Each effect alone on the image it receives in the chain (the NumPy chain's intermediates), each
    backend's runs back to back."""
    inputs, img = [], hdr
    for name, params in chain:
        inputs.append(img)
        img = postfx.apply_effect(name, img, depth, params, lens, seed=0).astype(np.float32, copy=False)
    ms: dict = {}
    for (name, params), img in zip(chain, inputs):
        for backend in backends:
            postfx.apply_chain(img, depth, [(name, params)], lens, backend=backend)  # warm-up
        samples: dict = {b: [] for b in backends}
        for backend in backends:  # each backend's runs back to back (warm), no pause: a pause would make
            for r in range(repeats):  # these short runs pay numba's / llvmpipe's thread wake-up each time
                run = postfx.apply_chain(img, depth, [(name, params)], lens, backend=backend, seed=r)
                samples[backend].append(run.seconds[name])
        for backend in backends:
            ms[(name, backend)] = float(np.median(samples[backend])) * 1e3
    return ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--refresh-frame", action="store_true", help="render the liver_probe frame again")
    parser.add_argument("--pause-ms", type=float, default=50.0,
                        help="idle time before each timed run (default %(default)s; 0: back to back)")
    parser.add_argument("--backends", default="numpy,osmesa",
                        help="comma-separated backends to time in this process (default %(default)s)")
    args = parser.parse_args()
    _set_pause(args.pause_ms * 1e-3)
    repeats = 5 if args.quick else 15
    asked = [b.strip() for b in args.backends.split(",") if b.strip()]
    if not asked or set(asked) - {"numpy", "osmesa"}:
        parser.error("--backends takes numpy and/or osmesa")
    backends = [b for b in ("numpy", "osmesa") if b in asked and (b == "numpy" or library_available())]
    result: dict = {}
    frames = {"": synthetic_frame(), "_rendered": rendered_frame(args.refresh_frame)}
    for suffix, (hdr, depth, lens, chain) in frames.items():
        label = "rendered" if suffix else "synthetic"
        runs, cpu = time_chains(hdr, depth, lens, chain, backends, repeats)
        for backend in backends:
            total = float(np.median([run.total_seconds for run in runs[backend]])) * 1e3
            cpu_ms = float(np.median(cpu[backend])) * 1e3
            result[f"{backend}_ms_total{suffix}"] = round(total, 2)
            result[f"{backend}_cpu_ms_total{suffix}"] = round(cpu_ms, 2)
            print(f"{label:9s} {backend:7s} chain total {total:8.2f} ms (CPU time of all threads {cpu_ms:8.2f} ms)")
        if backends == ["numpy", "osmesa"]:
            ratio = float(np.median([o.total_seconds / n.total_seconds for n, o in zip(runs["numpy"], runs["osmesa"])]))
            result[f"osmesa_over_numpy{suffix}"] = round(ratio, 3)
            print(f"{label:9s} osmesa / numpy (median of {repeats} back-to-back runs): {ratio:.3f}")
        for backend in backends:
            last = runs[backend][-1]
            groups = {"+".join([k, *last.fused.get(k, [])]): float(np.median([run.seconds[k] for run in runs[backend]])) * 1e3
                      for k in last.seconds}
            print(f"{label:9s} {backend} in the chain [ms]: " + ", ".join(f"{k} {v:.1f}" for k, v in groups.items()))
        if "osmesa" in backends:
            passes = profile_passes(hdr, depth, lens, chain, repeats)
            result[f"osmesa_pass_ms{suffix}"] = passes
            print(f"{label:9s} osmesa pass by pass (each waited for) [ms]: "
                  + ", ".join(f"{k} {v:.2f}" for k, v in passes.items()) + f"; sum {sum(passes.values()):.1f}")
    hdr, depth, lens, chain = frames[""]
    ms = time_effects(hdr, depth, lens, chain, backends, repeats)
    for backend in backends:
        for name, _ in chain:
            result[f"{name}_{backend}_ms"] = round(ms[(name, backend)], 2)
            print(f"{backend:7s} {name:22s} {ms[(name, backend)]:8.2f} ms (alone)")
        result[f"{backend}_ms_core"] = round(sum(ms[(n, backend)] for n in CORE), 2)
    if "osmesa" in asked and "osmesa" not in backends:
        result["osmesa_ms_total"] = result["osmesa_ms_total_rendered"] = None
        result["osmesa_skipped"] = "libOSMesa missing (Debian package libosmesa6)"
    result["machine"] = (f"{platform.machine()} {os.cpu_count()} cpus, numba threads {numba.get_num_threads()}, "
                         f"LP_NUM_THREADS {os.environ.get('LP_NUM_THREADS', 'default')}, "
                         f"numba threading layer {numba.threading_layer()}, pause {PAUSE_S * 1e3:.0f} ms before each run, "
                         f"load average {os.getloadavg()[0]:.2f}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
