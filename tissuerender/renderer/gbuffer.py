"""Rasterise and fill the G-buffer: merge the frame's objects into one render surface, clip it at the near
plane, rasterise it (``raster``), and gather per visible sample its position, shading normal, view
direction, material and surface parameters (textured where the material has a bake), as the
:class:`ShadingPoints` the shading stages read (Qian §7.2.2).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import materials
from materials.textures import mip_chain, sample_mipmapped
from sim.mesh.surface import box_uv, vertex_normals
from tissuerender.renderer.bsdf.mucosa import layer_arrays, layer_channels
from tissuerender.renderer.camera import Camera, camera_basis
from tissuerender.renderer.fieldmap import apply_vertex_albedo
from tissuerender.renderer.raster import interpolate_gbuffer, material_lookup, rasterize_objects


@dataclass
class RenderSurface:
    """Every object's triangles in one mesh: vertex ``points`` (n, 3), ``normals`` (n, 3), ``attributes``
    (n, 8: velocity, UV and the field colour map's vertex albedo, NaN without one; linear over a triangle),
    ``triangles`` (t, 3) and each triangle's material index ``tri_material`` (t,) into the frame's material list."""

    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    attributes: np.ndarray
    tri_material: np.ndarray


@dataclass
class Raster:
    """The rasterised frame at the supersampled resolution: view ``depth`` (H, W) (inf = background),
    ``tri_id`` (H, W) (-1 = background) and perspective-correct barycentrics ``bary`` (H, W, 3)."""

    depth: np.ndarray
    tri_id: np.ndarray
    bary: np.ndarray


@dataclass
class ShadingPoints:
    """The G-buffer as arrays over the k visible samples: raster ``rows``/``cols``, the triangle ``tri``,
    ``position``, unit shading ``normal``, unit direction to the eye ``wo``, ``material`` id, ``albedo``
    (k, 3), GGX ``alpha``, ``f0``; ``rough_factor`` (the texture's roughness map, None untextured), the
    mucosa stack's per-point ``layers`` (None without a layered material); ``thickness`` and the diffuse
    correction ``sss`` once the thickness stage has run (None otherwise)."""

    rows: np.ndarray
    cols: np.ndarray
    tri: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    wo: np.ndarray
    material: np.ndarray
    albedo: np.ndarray
    alpha: np.ndarray
    f0: np.ndarray
    rough_factor: np.ndarray | None = None
    layers: dict | None = None
    thickness: np.ndarray | None = None
    sss: np.ndarray | None = None


def material_optics(objects) -> list:
    """Each object's ``materials.optics.OpticalMaterial``: its own (scene overrides) or its preset's."""
    return [o.optics if getattr(o, "optics", None) is not None else materials.get_preset(o.material).optics
            for o in objects]


def merge_objects(objects) -> RenderSurface:
    """The objects' meshes in one :class:`RenderSurface` (vertex normals computed where an object has none)."""
    pts, tris, nrm, vel, tri_mat, uvs, colours = [], [], [], [], [], [], []
    offset = 0
    for k, obj in enumerate(objects):
        p = np.asarray(obj.points, float)
        t = np.asarray(obj.triangles, np.int64)
        n = obj.normals
        if n is None:
            n = vertex_normals(p, t)
        pts.append(p)
        tris.append(t + offset)
        nrm.append(np.asarray(n, float))
        vel.append(np.zeros_like(p) if obj.velocity is None else np.asarray(obj.velocity, float))
        # without UVs, the box projection in metres of procedural bodies (a texture keeps its physical size)
        uvs.append(box_uv(p, np.asarray(n, float)) if obj.uv is None else np.asarray(obj.uv, float).reshape(-1, 2))
        tri_mat.append(np.full(t.shape[0], k, np.int64))
        vertex_albedo = getattr(obj, "vertex_albedo", None)
        colours.append(np.full_like(p, np.nan) if vertex_albedo is None else np.asarray(vertex_albedo, float))
        offset += p.shape[0]
    if not pts:
        z = np.zeros((0, 3))
        return RenderSurface(z, np.zeros((0, 3), np.int64), z, np.zeros((0, 8)), np.zeros(0, np.int64))
    # velocity, UV and vertex albedo travel together as one linearly interpolated vertex attribute (n, 8)
    attributes = np.concatenate([np.concatenate(vel), np.concatenate(uvs), np.concatenate(colours)], axis=1)
    return RenderSurface(np.concatenate(pts), np.concatenate(tris), np.concatenate(nrm), attributes,
                         np.concatenate(tri_mat))


def clip_near(P, N, V, T, tri_mat, camera: Camera):
    """Split triangles crossing the near plane so the part in front of it is still drawn.

    New vertices lie on the crossing edges at view depth ``near``; positions, normals and the vertex
    attributes ``V`` (velocity, UV) are linear along an edge, so interpolating them there is exact.
    Triangles wholly behind the near plane are dropped.
    """
    _, _, f = camera_basis(camera.position, camera.look_at, camera.up)
    z = (P - np.asarray(camera.position, float)) @ f
    near = float(camera.near)
    inside = z[T] >= near
    n_in = inside.sum(axis=1)
    crossing = np.flatnonzero((n_in > 0) & (n_in < 3))
    if crossing.size == 0:
        return P, N, V, T[n_in == 3], tri_mat[n_in == 3]
    # the new vertices are gathered apart and appended once: a list of every row (100k+) cost more than the cut
    added_P, added_N, added_V = [], [], []
    new_tris, new_mat = [], []

    def cut(a, b):
        t = (near - z[a]) / (z[b] - z[a])
        added_P.append(P[a] + t * (P[b] - P[a]))
        added_N.append(N[a] + t * (N[b] - N[a]))
        added_V.append(V[a] + t * (V[b] - V[a]))
        return len(P) + len(added_P) - 1

    for k in crossing:
        tri = T[k]
        flags = inside[k]
        # rotate so the vertex that is alone on its side comes first, keeping the winding
        lone = int(np.flatnonzero(flags if n_in[k] == 1 else ~flags)[0])
        a, b, c = tri[lone], tri[(lone + 1) % 3], tri[(lone + 2) % 3]
        ab, ac = cut(a, b), cut(a, c)
        if n_in[k] == 1:
            new_tris.append([a, ab, ac])
            new_mat.append(tri_mat[k])
        else:
            new_tris += [[ab, b, c], [ab, c, ac]]
            new_mat += [tri_mat[k], tri_mat[k]]
    keep = n_in == 3
    T = np.concatenate([T[keep], np.asarray(new_tris, np.int64)])
    tri_mat = np.concatenate([tri_mat[keep], np.asarray(new_mat, np.int64)])
    return _appended(P, added_P), _appended(N, added_N), _appended(V, added_V), T, tri_mat


def _appended(rows: np.ndarray, added: list) -> np.ndarray:
    """``rows`` (n, d) with the ``added`` rows (d,) after them (the common dtype, as np.asarray of all rows)."""
    rows = np.asarray(rows)
    return np.concatenate([rows, np.asarray(added).reshape(len(added), *rows.shape[1:])])


def rasterise(surface: RenderSurface, camera: Camera, supersampling: int, jitter: bool, seed: int):
    """Clip ``surface`` at the near plane and rasterise it at ``supersampling`` times the camera's
    resolution: (the clipped :class:`RenderSurface`, :class:`Raster`). With supersampling and ``jitter``
    each of a pixel's ss x ss samples lies at a seeded uniform point of its own cell."""
    ss = int(supersampling)
    P, N, V, T, tri_mat = clip_near(surface.points, surface.normals, surface.attributes, surface.triangles,
                                    surface.tri_material, camera)
    jitter_seed = int(seed) % (1 << 62) if ss > 1 and jitter else -1
    depth, tri_id, bary = rasterize_objects(P, T, camera, int(camera.width) * ss, int(camera.height) * ss,
                                            jitter_seed)
    return RenderSurface(P, T, N, V, tri_mat), Raster(depth, tri_id, bary)


def sample_footprint(position, normal, wo, camera: Camera, raster_width: int) -> np.ndarray:
    """Width [m] of the surface one raster sample covers (k,): its distance times the sample's angle
    ``2 tan(fov / 2) / width`` (the horizontal field of view over the raster's width), stretched by ``1 / |n . wo|``
    along the slope (at most 8 x: a grazing surface is blurred no further). The texture lookup's footprint."""
    d = np.linalg.norm(position - np.asarray(camera.position, float), axis=1)
    angle = 2.0 * np.tan(0.5 * np.radians(float(camera.fov_deg))) / max(int(raster_width), 1)
    return d * angle / np.maximum(np.abs(np.einsum("ij,ij->i", normal, wo)), 0.125)


def uv_per_metre(points: np.ndarray, triangles: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """UV units per metre of each triangle (t,): ``sqrt(UV area / world area)``, the mean linear scale of its UV
    map (a footprint is a length, the areas' ratio its square). Box-projected UVs (``box_uv``) are in metres,
    scale 1; a mesh's own UVs in [0, 1] over an organ of 10 cm are about 10 per metre. 1 where either area is
    zero or not finite (a degenerate triangle or UV map: nothing to scale by)."""
    p, t = points[triangles], uv[triangles]
    world = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    ok = (world > 0.0) & (uv_area > 0.0) & np.isfinite(uv_area) & np.isfinite(world)
    return np.where(ok, np.sqrt(np.where(ok, uv_area, 1.0) / np.where(ok, world, 1.0)), 1.0)


def textured_surface(optics, mat, uv, albedo, n, alpha, footprint=None):
    """Albedo, shading normals and a roughness factor of layered materials that have a texture, from their
    baked mucosa texture (``materials.textures``) sampled bilinearly at the pixels' UVs, one tile per
    ``texture_period``. The tangent-space normal map is applied in the box-projection frame (the two
    world axes the UVs were taken along), which is the surface's tangent plane on the flat faces the
    projection is made for. The roughness map (0.7 ... 1.3 x, following the mottle) scales ``alpha`` and
    is returned as a factor for the granular layer's roughness (1 where untextured). With ``footprint`` (k,) in UV
    units (:func:`sample_footprint` [m] times the triangle's :func:`uv_per_metre`) the lookups are mip-mapped
    (``materials.textures.sample_mipmapped``, one texture tile of ``texture_size`` texels per ``texture_period``):
    a texture seen from afar reads as its average instead of speckle; without it, bilinear."""
    out_albedo, out_n, out_alpha = albedo.copy(), n.copy(), alpha.copy()
    factor = np.ones(albedo.shape[0])
    for mid, o in enumerate(optics):
        layers = o.layers
        if layers is None or layers.texture_seed is None:
            continue
        sel = np.flatnonzero(mat == mid)
        if sel.size == 0:
            continue
        st = uv[sel] / layers.texture_period
        size = layers.baked_albedo().shape[1]
        texels = np.ones(sel.size) if footprint is None else footprint[sel] / layers.texture_period * size
        out_albedo[sel] = sample_mipmapped(mip_chain(layers.baked_albedo()), st, texels)
        factor[sel] = sample_mipmapped(mip_chain(layers.baked_roughness_factor()[..., None]), st, texels)[:, 0]
        out_alpha[sel] = alpha[sel] * factor[sel]
        tn = sample_mipmapped(mip_chain(layers.baked_normal()), st, texels)
        axis = np.argmax(np.abs(n[sel]), axis=1)
        first = np.where(axis == 0, 1, 0)  # box_uv: u along y for x-facing, else along x
        second = np.where(axis == 2, 1, 2)  # v along y for z-facing, else along z
        t = np.eye(3)[first]
        b = np.eye(3)[second]
        bent = tn[:, :1] * t + tn[:, 1:2] * b + tn[:, 2:] * n[sel]
        out_n[sel] = bent / np.maximum(np.linalg.norm(bent, axis=1, keepdims=True), 1e-12)
    return out_albedo, out_n, out_alpha, factor


def shading_points(surface: RenderSurface, raster: Raster, camera: Camera, optics, motion: bool,
                   gbuffer: dict) -> ShadingPoints:
    """Interpolate the visible samples' surface and look their materials up (textures applied); records the
    G-buffer channels in ``gbuffer`` (velocity with ``motion``, UV for textured materials, the layer
    channels when a layered material is in view)."""
    P, N, T, V = surface.points, surface.normals, surface.triangles, surface.attributes
    jj, ii, pos, n, wo, tri = interpolate_gbuffer(P, N, T, raster.tri_id, raster.bary, camera.position)
    mat, albedo, alpha, f0 = material_lookup(tri, surface.tri_material,
                                             np.array([o.diffuse_albedo for o in optics], float),
                                             np.array([o.roughness for o in optics], float),
                                             np.array([o.f0 for o in optics], float))
    gbuffer.update(depth=raster.depth, position=pos, normal=n, material_id=mat, albedo=albedo, roughness=alpha)
    textured = any(o.layers is not None and o.layers.texture_seed is not None for o in optics)
    rough_factor = None
    if motion or textured:
        corner, b = T[tri], raster.bary[jj, ii]
    if motion:
        gbuffer["velocity"] = np.einsum("kc,kcd->kd", b, V[corner][:, :, :3])
    if textured:
        uv = np.einsum("kc,kcd->kd", b, V[corner][:, :, 3:5])
        gbuffer["uv"] = uv
        # the footprint in UV units: metres on the surface times the UV map's scale there (UVs need not be metres)
        footprint = sample_footprint(pos, n, wo, camera, raster.depth.shape[1])
        seen = np.zeros(T.shape[0], bool)  # only the triangles in view (a third of the default scene's)
        seen[tri] = True
        in_view = np.flatnonzero(seen)
        scale = np.ones(T.shape[0])
        scale[in_view] = uv_per_metre(P, T[in_view], V[:, 3:5])
        footprint = footprint * scale[tri]
        albedo, n, alpha, rough_factor = textured_surface(optics, mat, uv, albedo, n, alpha, footprint)
        gbuffer.update(albedo=albedo, normal=n, roughness=alpha)
    if np.isfinite(V[:, 5:8]).any():  # a field colour map on some object (renderer.fieldmap)
        albedo = apply_vertex_albedo(albedo, V[:, 5:8], T, tri, raster.bary[jj, ii])
        gbuffer["albedo"] = albedo
    layers = layer_arrays(optics, mat, rough_factor)
    gbuffer["specular"] = f0
    if layers is not None:
        gbuffer.update(layer_channels(optics, mat, layers, n, wo))
    return ShadingPoints(rows=jj, cols=ii, tri=tri, position=pos, normal=n, wo=wo, material=mat, albedo=albedo,
                         alpha=alpha, f0=f0, rough_factor=rough_factor, layers=layers)
