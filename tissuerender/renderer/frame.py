"""One frame of the deferred renderer, as named stages (docs/design.md, "Data flow of one render"):

rasterise -> G-buffer -> ray scene -> thickness -> direct light -> environment -> resolve

Each stage runs only when the settings ask for it and is timed under its name (``raster``, ``bvh``,
``thickness``, ``shade`` with ``shadow_rays``, ``mucus_reflection``, ``ao``) by the
``tissuerender.stages.StageRecorder`` passed in.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tissuerender.finite import check_finite, check_image
from tissuerender.renderer.bsdf import bsdf_for
from tissuerender.renderer.bsdf.tissue import subsurface_term
from tissuerender.renderer.camera import Camera
from tissuerender.renderer.direct import LightSamples, cone_regions, shade_fused, shade_numpy
from tissuerender.renderer.environment import ambient_light, ambient_occlusion, mucus_reflection
from tissuerender.renderer.gbuffer import material_optics, merge_objects, rasterise, shading_points
from tissuerender.renderer.light import (AreaLight, check_estimator, importance_counts, light_frame, sample_counts,
                                         sample_offsets)
from tissuerender.renderer.raster import box_downsample, scatter_radiance
from tissuerender.renderer.rays import ray_scene
from tissuerender.renderer.settings import RenderSettings
from tissuerender.renderer.thickness import thickness_map, thickness_reach
from tissuerender.stages import StageRecorder, recorder_or_new


@dataclass
class RenderObject:
    """One triangle mesh to draw: vertex ``points`` (n, 3), ``triangles`` (t, 3), vertex ``normals`` (None:
    computed), ``uv`` (n, 2) for textured materials, the preset name ``material``, per-vertex ``velocity``
    [m/s] for the motion channel, the scene's ``name`` for error messages."""

    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None
    uv: np.ndarray | None
    material: str
    object_id: int = 0
    velocity: np.ndarray | None = None
    optics: object | None = None  # a materials.optics.OpticalMaterial replacing the preset's (scene overrides)
    name: str = ""  # the scene's name of the object, for messages
    vertex_albedo: np.ndarray | None = None  # (n, 3) linear RGB replacing the material's albedo (renderer.fieldmap)


@dataclass
class FrameResult:
    """Linear HDR radiance (H, W, 3) float32, view depth (H, W) float32 (inf = background) and the G-buffer
    channels by name (per visible sample at the supersampled resolution); the stages' seconds are in the
    recorder."""

    hdr: np.ndarray
    depth: np.ndarray
    gbuffer: dict = field(default_factory=dict)
    passes: dict = field(default_factory=dict)  # ground-truth passes by name (tissuerender.groundtruth)


def check_light(light: AreaLight, settings: RenderSettings) -> bool:
    """Whether the numba passes shade every point (they do unless the reflection cone, a NumPy estimator,
    is asked for); raises where the light asks for what the chosen estimator cannot do."""
    fused = settings.fused and not light.reflection_cone
    check_estimator(light)
    if (light.estimator == "ratio" or light.penumbra_samples > 0) and not fused:
        raise NotImplementedError("light.estimator = \"ratio\" and light.penumbra_samples run in the numba shading "
                                  "pass only, which the reflection cone (NumPy estimator) does not use")
    return fused


def sample_light(points, light: AreaLight, camera: Camera, settings: RenderSettings) -> LightSamples:
    """The light's frame and every point's sample count m (adaptive or painted) and sample offsets."""
    centre, ln, eu, ev = light_frame(light, camera)
    pos = points.position
    if light.sampling == "importance":
        m = importance_counts(pos, light)
    else:
        m = sample_counts(np.sqrt(np.einsum("ij,ij->i", pos - centre, pos - centre)), light)
    rotation, stride, phase = sample_offsets(points.rows, points.cols, int(settings.supersampling), light.pattern,
                                             settings.seed)
    return LightSamples(centre, ln, eu, ev, m, rotation, stride, phase)


def direct_light(points, bsdfs, optics, light: AreaLight, camera: Camera, settings: RenderSettings, fused: bool,
                 rays, eps: float, rec: StageRecorder, gbuffer: dict) -> np.ndarray:
    """Radiance (k, 3) of the area light reflected at every point towards the eye."""
    ls = sample_light(points, light, camera, settings)
    gbuffer["light_samples"] = ls.m
    radiance = np.zeros((points.position.shape[0], 3))
    shadow_rays = rays if settings.shadows else None
    if fused:
        ss = int(settings.supersampling)
        pixel = (points.rows // ss) * camera.width + points.cols // ss
        shade_fused(points, bsdfs, optics, ls, shadow_rays, eps, radiance, rec, light.estimator == "ratio",
                    int(light.penumbra_samples), pixel, (int(camera.height), int(camera.width)))
    else:
        cone = None
        if light.reflection_cone and points.position.shape[0]:
            spec_alpha = points.alpha.copy()
            if points.layers is not None:
                mask = points.layers["mask"]
                spec_alpha[mask] = points.layers["coat_alpha"][mask]
            cone = cone_regions(points.position, points.normal, points.wo, spec_alpha, ls.centre, ls.ln, ls.eu, ls.ev)
            gbuffer["cone"] = cone[4]
        shade_numpy(points, bsdfs, ls, cone, light.cone_samples, shadow_rays, eps, radiance, rec)
    radiance *= np.asarray(light.radiance, float)
    return radiance


def environment_light(points, settings: RenderSettings, rays, eps: float, radiance, rec: StageRecorder,
                      gbuffer: dict) -> None:
    """Add the mucus coat's environment reflection and the ambient light (with its occlusion) to ``radiance``."""
    if settings.mucus_reflection and points.layers is not None and points.layers["mask"].any():
        with rec.run("mucus_reflection"):
            mucus_reflection(points, settings, radiance)
    ambient = np.asarray(settings.ambient, float)
    if np.any(ambient > 0.0):
        visibility = np.ones(points.position.shape[0])
        if settings.ao:
            with rec.run("ao"):
                visibility = ambient_occlusion(rays, points.position, points.normal, int(settings.ao_samples),
                                               float(settings.ao_distance), 2 * eps, settings.seed)
                gbuffer["ao"] = visibility
        ambient_light(points, ambient, visibility, radiance)


def resolve(radiance, points, raster, camera: Camera, supersampling: int, rec: StageRecorder):
    """The image: every point's radiance into its raster cell, box-filtered down from the supersampled
    resolution: (linear HDR (H, W, 3) float32, view depth (H, W) float32)."""
    ss = int(supersampling)
    hdr = np.zeros((int(camera.height) * ss, int(camera.width) * ss, 3), np.float32)
    with rec.run("shade"):
        scatter_radiance(radiance, points.rows, points.cols, hdr)
    depth = raster.depth.astype(np.float32)
    if ss > 1:
        hdr, depth = box_downsample(hdr, depth, ss)
    return hdr, depth


def check_objects(objects) -> None:
    """Every object's vertex positions (and normals, where given) are finite: the raster stage would
    silently drop or smear a triangle with a NaN corner."""
    for index, obj in enumerate(objects):
        check_finite(obj.points, "vertex positions", "raster", lambda i, index=index: index)
        if obj.normals is not None:
            check_finite(obj.normals, "vertex normals", "raster", lambda i, index=index: index)


def check_points(values, what: str, stage: str, points, supersampling: int, allow_inf: bool = False) -> None:
    """``values`` per shading point are finite (``allow_inf``: +inf allowed); the error names the pixels and
    the object (the G-buffer's material id: one per render object) of the first bad one."""
    ss = int(supersampling)
    check_finite(values, what, stage, lambda i: points.material[i],
                 lambda rows: np.stack([points.rows[rows] // ss, points.cols[rows] // ss], axis=1), allow_inf)


def object_at(surface, raster, row: int, col: int) -> int | None:
    """The render object covering raster sample (row, col), None for the background."""
    tri = raster.tri_id[row, col]
    return int(surface.tri_material[tri]) if tri >= 0 else None


def render_frame(objects, camera: Camera, light: AreaLight, settings: RenderSettings,
                 recorder: StageRecorder | None = None) -> FrameResult:
    """Render one frame: linear HDR radiance (H, W, 3) float32, view depth (H, W) (inf = background)."""
    rec = recorder_or_new(recorder)
    fused = check_light(light, settings)
    check_objects(objects)
    optics = material_optics(objects)
    bsdfs = [bsdf_for(o) for o in optics]
    surface = merge_objects(objects)
    gbuffer: dict = {}
    with rec.run("raster"):
        surface, raster = rasterise(surface, camera, settings.supersampling, settings.jitter, settings.seed)
        points = shading_points(surface, raster, camera, optics, settings.motion, gbuffer)
    rays = None
    if settings.shadows or settings.sss or settings.ao:
        with rec.run("bvh"):
            rays = ray_scene(surface.points, surface.triangles, settings.ray_backend)
    scale = float(np.ptp(surface.points, axis=0).max()) if surface.points.size else 1.0
    eps = 2e-4 * max(scale, 1e-9)  # ray offset: larger than the facet-vs-shading-normal gap (no acne)
    if settings.sss:
        with rec.run("thickness"):
            points.thickness = thickness_map(rays, surface, raster, points, thickness_reach(optics, bsdfs),
                                             settings.sss_thickness == "vertex", scale)
            gbuffer["thickness"] = points.thickness
            check_points(points.thickness, "thickness", "thickness", points, settings.supersampling, allow_inf=True)
        if not fused:
            points.sss = subsurface_term(optics, points.material, points.thickness, points.albedo)
    with rec.run("shade"):
        radiance = direct_light(points, bsdfs, optics, light, camera, settings, fused, rays, eps, rec, gbuffer)
    environment_light(points, settings, rays, eps, radiance, rec, gbuffer)
    check_points(radiance, "radiance", "shade", points, settings.supersampling)
    hdr, depth = resolve(radiance, points, raster, camera, settings.supersampling, rec)
    # finite float64 radiance beyond float32's range would become inf here
    ss = int(settings.supersampling)
    check_image(hdr, "radiance", "resolve", lambda row, col: object_at(surface, raster, row * ss, col * ss))
    return FrameResult(hdr=hdr, depth=depth, gbuffer=gbuffer)
