"""Rough plastic against Mitsuba 3 on the rendering sweeps' scenes (issue 17 item 1): an independent renderer, so a
systematic difference that no sample count removes shows up as a floor.

Each scene of ``render_sweeps.SWEEP_SCENES`` at frame 1 (at rest), scaled to the level's width, with every object
given the ``plastic`` material (Mitsuba's ``roughplastic``: GGX, ``alpha`` = the preset's roughness, its IOR and
albedo, ``nonlinear = false``; ``materials.optics``), direct illumination from the scene's area light (placed as
ours places it, ``light_frame``), shadows, no SSS, AO, environment or lens, the pinhole camera. Ours: uniform light
sampling with m samples, the Monte Carlo estimator, 2 x 2 jittered supersampling (box filter); Mitsuba:
``scalar_rgb``, the ``direct`` integrator, ``spp`` independent samples per pixel, box filter. Per m: mean FLIP of
the tone-mapped images (ACES + sRGB, ``render_measure.tone_mapped``'s chain) and the brightness ratio
``mean(ours) / mean(mitsuba)`` of the linear HDR; also FLIP of Mitsuba at spp / 4 against its own spp, the
reference's own noise. As m grows our noise falls and FLIP levels off at the systematic difference (plus the 2 x 2
supersampling's aliasing against Mitsuba's fully sampled pixels).

Mitsuba is optional (``pip install tissuerender[report]``): without it the section says "not run: mitsuba not
installed" and the report's other numbers are unaffected. ``benchmarks/plastic_vs_mitsuba.py`` has the same
cross-check on three analytic scenes.
"""
from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from materials import get_preset
from sim.mesh.surface import vertex_normals
from tissuerender.golden import flip
from tissuerender.plan import make_plan
from tissuerender.render_inputs import camera_for, light_for, render_objects
from tissuerender.renderer import RenderSettings, render_frame
from tissuerender.renderer.light import light_frame
from tissuerender.report.render_measure import scaled_resolution, variant
from tissuerender.report.stage_costs import SCENES_DIR
from tissuerender.scene import load_scene
from tissuerender.stages import StageRecorder
from tissuerender.world import build_world

SCENES = ("kidney_static", "colon_mucosa", "liver_probe")
SWEEPS = {
    "full": {"max_width": 128, "samples": [1, 4, 16, 64, 256], "spp": 1024},
    "quick": {"max_width": 48, "samples": [1, 4, 16, 64], "spp": 512},
    "tiny": {"max_width": 48, "samples": [1, 16], "spp": 256, "self_check": False},
}
SUPERSAMPLING = 2


def available() -> str | None:
    """None when Mitsuba 3 can be imported, else why not (the report prints it)."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return "mitsuba not installed (pip install 'tissuerender[report]' or pip install mitsuba)"
    return None


def plastic_inputs(name: str, max_width: int):
    """The scene's frame-1 geometry with every object plastic, its pinhole camera and area light."""
    scene = load_scene(SCENES_DIR / f"{name}.toml")
    scene = variant(scene, output={"resolution": scaled_resolution(scene, max_width), "supersampling": SUPERSAMPLING})
    plan = make_plan(scene)
    world = build_world(scene, plan, StageRecorder())
    objects, _ = render_objects(world, scene, 0.0, plan, StageRecorder())
    objects = [dataclasses.replace(o, material="plastic", optics=None, uv=None, velocity=None) for o in objects]
    return scene, objects, camera_for(scene, t=0.0), light_for(scene)


def render_ours(objects, camera, light, samples: int, seed: int) -> np.ndarray:
    light = dataclasses.replace(light, sampling="uniform", samples=samples, estimator="mc", importance=(),
                                reflection_cone=False, penumbra_samples=0)
    out = render_frame(objects, camera, light, RenderSettings(shadows=True, supersampling=SUPERSAMPLING, seed=seed))
    return out.hdr.astype(np.float64)


def _write_obj(path: Path, points, triangles, normals) -> None:
    with open(path, "w") as f:
        f.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in points)
        f.writelines(f"vn {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in normals)
        f.writelines(f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}\n" for a, b, c in triangles)


def render_mitsuba(objects, camera, light, spp: int, folder: Path, seed: int = 0) -> np.ndarray:
    """The same frame in Mitsuba 3 (``scalar_rgb``, direct illumination, box filter), linear RGB (h, w, 3)."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    optics = get_preset("plastic").optics
    bsdf = {"type": "roughplastic", "distribution": "ggx", "alpha": optics.roughness, "int_ior": optics.ior,
            "ext_ior": 1.0, "nonlinear": False, "diffuse_reflectance": {"type": "rgb", "value": list(optics.albedo)}}
    centre, normal, eu, ev = light_frame(light, camera)
    to_world = np.eye(4)
    to_world[:3, 0], to_world[:3, 1], to_world[:3, 2], to_world[:3, 3] = eu, ev, normal, centre
    scene = {
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": camera.fov_deg, "fov_axis": "x", "near_clip": camera.near,
                   "far_clip": camera.far,
                   "to_world": mi.ScalarTransform4f.look_at(origin=list(camera.position), target=list(camera.look_at),
                                                            up=list(camera.up)),
                   "film": {"type": "hdrfilm", "width": camera.width, "height": camera.height,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp, "seed": seed}},
        "light": {"type": "rectangle", "to_world": mi.ScalarTransform4f(to_world.tolist()),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": list(light.radiance)}}},
    }
    for i, o in enumerate(objects):
        path = folder / f"mesh{i}.obj"
        normals = o.normals if o.normals is not None else vertex_normals(o.points, o.triangles)
        _write_obj(path, o.points, o.triangles, normals)
        scene[f"mesh{i}"] = {"type": "obj", "filename": str(path), "bsdf": bsdf}
    return np.asarray(mi.render(mi.load_dict(scene), spp=spp), dtype=np.float64)[..., :3]


def tonemapped(hdr: np.ndarray, camera) -> np.ndarray:
    """The linear HDR frame through the ACES + sRGB tone map (the NumPy post-effects), as FLIP compares it."""
    import postfx
    from postfx.tonemap import Tonemap

    return postfx.apply_chain(hdr.astype(np.float32), np.zeros(hdr.shape[:2], np.float32), [("tonemap", Tonemap())],
                              postfx.Lens(camera.fov_deg, hdr.shape[1], hdr.shape[0]), backend="numpy").image


def run_scene(name: str, sweep: dict, tick=lambda: None) -> dict:
    scene, objects, camera, light = plastic_inputs(name, sweep["max_width"])
    with tempfile.TemporaryDirectory(prefix="tissuerender_mitsuba_") as folder:
        start = time.perf_counter()
        reference = render_mitsuba(objects, camera, light, sweep["spp"], Path(folder))
        mitsuba_s = time.perf_counter() - start
        coarse = None
        if sweep.get("self_check", True):
            coarse = render_mitsuba(objects, camera, light, max(1, sweep["spp"] // 4), Path(folder), seed=1)
    ref_ldr = tonemapped(reference, camera)
    self_flip = float("nan") if coarse is None else flip(ref_ldr, tonemapped(coarse, camera))[0]
    render_ours(objects, camera, light, 1, scene.seed)  # compile or load the kernels before timing
    points = []
    for m in sweep["samples"]:
        start = time.perf_counter()
        ours = render_ours(objects, camera, light, m, scene.seed)
        seconds = time.perf_counter() - start
        mean_flip, _ = flip(ref_ldr, tonemapped(ours, camera))
        points.append({"samples": m, "flip": float(mean_flip),
                       "brightness_ratio": float(ours.mean() / max(reference.mean(), 1e-30)),
                       "rel_rmse": float(np.sqrt(np.mean((ours - reference) ** 2)) / max(np.sqrt(np.mean(reference ** 2)),
                                                                                        1e-30)),
                       "seconds": seconds})
        tick()
    return {"scene": name, "resolution": [camera.width, camera.height], "mitsuba_spp": sweep["spp"],
            "mitsuba_s": mitsuba_s, "mitsuba_self_flip": float(self_flip), "points": points,
            "floor_flip": points[-1]["flip"], "floor_brightness_ratio": points[-1]["brightness_ratio"]}


def run_mitsuba(sweep: dict, tick=lambda: None) -> dict:
    """Every scene, or ``{"skipped": reason}`` when Mitsuba is not installed."""
    missing = available()
    if missing is not None:
        return {"case": "mitsuba", "skipped": f"not run: {missing}", "measures": {}}
    import mitsuba

    scenes = [run_scene(name, sweep, tick) for name in SCENES]
    return {"case": "mitsuba", "title": "rough plastic against Mitsuba 3 on the rendering sweeps' scenes",
            "mitsuba_version": mitsuba.__version__, "sweep": sweep, "scenes": scenes,
            "measures": {"max_floor_flip": max(s["floor_flip"] for s in scenes)}}


def work_units(sweep: dict) -> int:
    return len(SCENES) * len(sweep["samples"])

