"""What the report measures on a rendered frame: one frame of a scene variant (other light samples, sampling,
estimator, supersampling, effects), timed, and its error against a high-sample reference of the same frame.

- **FLIP**: the mean of NVIDIA FLIP (``flip_evaluator``, LDR; ``tissuerender.golden.flip``) between the two
  frames after an ACES tone map + sRGB only (no lens effects: the error is the renderer's, and a noise or grain
  effect would add its own).
- **Relative RMSE** of the linear HDR: ``sqrt(mean((hdr - ref)^2)) / sqrt(mean(ref^2))``.
- **Seconds per frame**: ``time.perf_counter`` around ``pipeline.render_hdr`` (raster, BVH, shadows,
  thickness, shading) after an untimed warm-up render of the first variant with each ``kernel_key`` (sampling,
  estimator, cone, penumbra, effects), which compiles (or loads) every numba kernel it calls. One timed render:
  a shared machine varies by some tens of per cent.

Every variant renders with the same seed, hence the same sample pattern, as ``benchmarks/render_convergence.py``.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

import postfx
from postfx.tonemap import Tonemap
from tissuerender.golden import flip
from tissuerender.pipeline import render_hdr
from tissuerender.plan import make_plan
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder
from tissuerender.world import build_world


def variant(scene: Scene, light: dict | None = None, effects: dict | None = None, output: dict | None = None,
            simulation: dict | None = None) -> Scene:
    """``scene`` with some keys of its ``[light]``, ``[effects]``, ``[output]`` or ``[simulation]`` tables replaced."""
    return dataclasses.replace(
        scene, light=scene.light.model_copy(update=light or {}),
        effects=scene.effects.model_copy(update=effects or {}),
        output=scene.output.model_copy(update=output or {}),
        simulation=scene.simulation.model_copy(update=simulation or {}))


def scaled_resolution(scene: Scene, max_width: int | None) -> list[int]:
    """The scene's resolution, scaled down (aspect kept) to at most ``max_width`` pixels wide."""
    w, h = scene.width, scene.height
    if max_width is None or w <= max_width:
        return [w, h]
    return [max_width, max(8, round(h * max_width / w))]


def kernel_key(scene: Scene) -> tuple:
    """What selects the renderer's compiled code paths: a variant with a new key gets a warm-up render."""
    lt, e = scene.light, scene.effects
    return (lt.sampling, lt.estimator, lt.reflection_cone, lt.penumbra_samples > 0, lt.pattern, e.shadows, e.sss,
            e.sss_thickness, e.ao, e.mucus_reflection, scene.output.supersampling > 1)


def render_timed(scene: Scene, world=None, warm: bool | set = True) -> dict:
    """Frame 1 (t = 0) of ``scene``: linear HDR, tone-mapped LDR and the seconds ``render_hdr`` took (after a
    warm-up render when ``warm`` is True, or when it is a set of ``kernel_key``s not holding this scene's, which
    is then added). ``world`` is reused when given (its bodies at rest or as left)."""
    plan = make_plan(scene)
    if world is None:
        world = build_world(scene, plan, StageRecorder())
    if isinstance(warm, set):
        key = kernel_key(scene)
        warm, _ = key not in warm, warm.add(key)
    if warm:
        render_hdr(world, scene, plan, StageRecorder(), 0.0, scene.seed)
    start = time.perf_counter()
    result, _ = render_hdr(world, scene, plan, StageRecorder(), 0.0, scene.seed)
    seconds = time.perf_counter() - start
    return {"hdr": result.hdr, "ldr": tone_mapped(scene, result), "seconds": seconds}


def tone_mapped(scene: Scene, result) -> np.ndarray:
    lens = postfx.Lens(scene.camera.fov_deg, result.hdr.shape[1], result.hdr.shape[0])
    return postfx.apply_chain(result.hdr, result.depth, [("tonemap", Tonemap())], lens, backend="numpy").image


def compare(reference: dict, frame: dict) -> dict:
    """FLIP and relative RMSE of ``frame`` against ``reference`` (both from ``render_timed``)."""
    mean_flip, _ = flip(reference["ldr"], frame["ldr"])
    ref = reference["hdr"].astype(np.float64)
    rel = float(np.sqrt(np.mean((frame["hdr"] - ref) ** 2)) / max(np.sqrt(np.mean(ref ** 2)), 1e-30))
    return {"flip": float(mean_flip), "rel_rmse": rel, "seconds": float(frame["seconds"])}
