"""The passes: what the ray through each pixel's centre hits, rasterised once at the output resolution.

The render surface of the frame (every object's triangles, as the renderer draws them) is rasterised again at
the camera's own resolution with one sample at each pixel centre (no jitter), whatever the colour image's
supersampling: every pass value belongs to exactly the ray ``K`` describes, and ids, depths and normals are
never averaged across an edge. Per pixel the raster keeps the nearest triangle and its perspective-correct
barycentrics ``b`` (``tissuerender.renderer.raster``); every pass interpolates a vertex quantity with them:

- ``depth`` (H, W) float32: camera z [m] of the hit, ``1 / sum_i (w_i / z_i)`` for screen-space weights
  ``w_i``, exact for a planar triangle; inf where nothing is hit.
- ``normal`` (H, W, 3) float32: the interpolated vertex normal (the shading normal before any normal map),
  unit length, turned towards the camera, in OpenCV camera axes (x right, y down, z forward); NaN where
  nothing is hit.
- ``segmentation`` (H, W) int32: instance id, 0 the background, render object ``k`` has id ``k + 1``
  (``tissuerender.groundtruth.cameras.labels``).
- ``material_coords`` (H, W, 3) float32: rest position [m] of the simulated tissue point seen, ``sum_i b_i X_i``
  over the rest positions ``X_i`` of the hit triangle's vertices; NaN where no simulated body is seen.

The rest position of a render-surface vertex is where the surface was built, before any deformation: the
surface (subdivided and smoothed at rest, ``tissuerender.bodies.build_body``) is embedded in the rest tets, so
``deform(embedding, tets, X_rest)`` gives these points back and ``deform(embedding, tets, x)`` the deformed ones.
Triangles cut by the near plane get new vertices on their edges; the rest positions travel through the cut
as a vertex attribute, linear along an edge like the positions, so they stay exact.
"""
from __future__ import annotations

import numpy as np

from tissuerender.groundtruth.cameras import world_to_camera
from tissuerender.groundtruth.pass_kernels import camera_normals, interpolate_pixels
from tissuerender.renderer.camera import Camera
from tissuerender.renderer.gbuffer import RenderSurface, merge_objects, rasterise
from tissuerender.scene.schema import PASSES as PASS_NAMES
from tissuerender.stages import StageRecorder, recorder_or_new


def rest_positions(world, objects) -> list:
    """Each render object's vertex rest positions (n, 3) [m], None for what is not simulated tissue. Render
    objects come bodies first (``tissuerender.render_inputs.render_objects``), in ``world.bodies`` order."""
    rest = [body.surface.points for body in world.bodies]
    return rest + [None] * (len(objects) - len(rest))


def _pass_surface(objects, rest) -> RenderSurface:
    """The frame's render surface with the rest positions (NaN off the bodies) as its vertex attribute."""
    surface = merge_objects(objects)
    attribute = [np.full((np.asarray(o.points).shape[0], 3), np.nan) if r is None else np.asarray(r, float)
                 for o, r in zip(objects, rest)]
    attribute = np.concatenate(attribute) if attribute else np.zeros((0, 3))
    return RenderSurface(surface.points, surface.triangles, surface.normals, attribute, surface.tri_material)


def ground_truth(objects, rest, camera: Camera, wanted, recorder: StageRecorder | None = None) -> dict:
    """The passes named in ``wanted`` for the frame's render ``objects`` seen by ``camera``: a dict name ->
    array at the camera's resolution (see the module docstring for each). ``rest``: per object its vertex
    rest positions or None (``rest_positions``). Each pass is timed under ``passes.<name>``."""
    rec = recorder_or_new(recorder)
    wanted = list(wanted)
    h, w = int(camera.height), int(camera.width)
    with rec.run("passes.raster"):
        surface, raster = rasterise(_pass_surface(objects, rest), camera, 1, False, 0)
    out = {}
    if "depth" in wanted:
        with rec.run("passes.depth"):
            out["depth"] = raster.depth.astype(np.float32)  # inf where nothing is hit
    if "normal" in wanted:
        with rec.run("passes.normal"):
            normal = np.empty((h, w, 3), np.float32)
            camera_normals(np.ascontiguousarray(surface.normals, float), surface.points, surface.triangles,
                           raster.tri_id, raster.bary, np.asarray(camera.position, float),
                           np.ascontiguousarray(world_to_camera(camera)[:3, :3]), normal)
            out["normal"] = normal
    if "segmentation" in wanted:
        with rec.run("passes.segmentation"):
            ids = np.zeros((h, w), np.int32)
            covered = raster.tri_id >= 0
            ids[covered] = surface.tri_material[raster.tri_id[covered]] + 1
            out["segmentation"] = ids
    if "material_coords" in wanted:
        with rec.run("passes.material_coords"):
            coords = np.empty((h, w, 3), np.float32)
            interpolate_pixels(np.ascontiguousarray(surface.attributes, float), surface.triangles, raster.tri_id,
                               raster.bary, coords)
            out["material_coords"] = coords
    return out
