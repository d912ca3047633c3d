"""The preview renderer: a numba z-buffer rasteriser with perspective-correct interpolation and a
Lambert + GGX shade under a rectangular area light (uniform stratified samples, no shadows).

It is the simple shaded raster the pipeline falls back to when the full deferred renderer
(``tissuerender.render``) is not installed, and a baseline the full renderer is checked against.
Units: metres; radiance in W/(m^2 sr); the light emits along its normal from one side.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from tissuerender.stages import StageRecorder, recorder_or_new

# Approximate diffuse reflectance (linear sRGB) of the presets, for the preview shade only; the full
# renderer takes its optics from materials.optics. Roughness is a GGX alpha.
PREVIEW_ALBEDO = {
    "liver": ((0.42, 0.10, 0.08), 0.35),
    "kidney": ((0.45, 0.14, 0.11), 0.35),
    "colon_mucosa": ((0.60, 0.26, 0.22), 0.20),
    "fat": ((0.75, 0.62, 0.35), 0.45),
    "fascia": ((0.72, 0.66, 0.62), 0.40),
    "peritoneum": ((0.62, 0.40, 0.36), 0.30),
    "plastic": ((0.55, 0.55, 0.58), 0.25),
}


def camera_basis(position, look_at, up):
    """Orthonormal (right, up, forward) of a camera looking from ``position`` at ``look_at``."""
    f = np.asarray(look_at, float) - np.asarray(position, float)
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, float))
    r /= np.linalg.norm(r)
    return r, np.cross(r, f), f


@njit(cache=True)
def rasterize(sx, sy, zv, tris, width, height, near, depth, tri_id, bary):
    """Z-buffer raster of triangles with screen positions ``sx, sy`` and view depths ``zv``.

    Writes per pixel the nearest view depth, the triangle id and perspective-correct barycentrics
    (weights ``b_i / z_i`` renormalised). Triangles with a vertex in front of ``near`` are skipped.
    """
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        if zv[a] < near or zv[b] < near or zv[c] < near:
            continue
        x0, y0, x1, y1, x2, y2 = sx[a], sy[a], sx[b], sy[b], sx[c], sy[c]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0.0:
            continue
        i0 = max(int(np.floor(min(x0, x1, x2))), 0)
        i1 = min(int(np.ceil(max(x0, x1, x2))), width - 1)
        j0 = max(int(np.floor(min(y0, y1, y2))), 0)
        j1 = min(int(np.ceil(max(y0, y1, y2))), height - 1)
        for j in range(j0, j1 + 1):
            py = j + 0.5
            for i in range(i0, i1 + 1):
                px = i + 0.5
                w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) / area
                w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) / area
                w2 = 1.0 - w0 - w1
                if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                    continue
                p0, p1, p2 = w0 / zv[a], w1 / zv[b], w2 / zv[c]
                inv_z = p0 + p1 + p2
                z = 1.0 / inv_z
                if z < depth[j, i]:
                    depth[j, i] = z
                    tri_id[j, i] = t
                    bary[j, i, 0] = p0 * z
                    bary[j, i, 1] = p1 * z
                    bary[j, i, 2] = p2 * z


def ggx_cook_torrance(n, wo, wi, albedo, alpha, f0=0.04):
    """Lambert + GGX specular (Walter et al. 2007 D, height-correlated Smith G, Schlick F) times cos.

    Energy split (Qian eq. 6.4): the diffuse lobe is weighted by (1 - F), so the sum never exceeds
    the incident energy. Arrays: n, wo, wi (k, 3) unit vectors; albedo (k, 3); alpha (k,).
    """
    h = wo + wi
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    n_l = np.clip(np.einsum("ij,ij->i", n, wi), 0.0, 1.0)
    n_v = np.clip(np.einsum("ij,ij->i", n, wo), 1e-4, 1.0)
    n_h = np.clip(np.einsum("ij,ij->i", n, h), 0.0, 1.0)
    v_h = np.clip(np.einsum("ij,ij->i", wo, h), 0.0, 1.0)
    a2 = alpha * alpha
    D = a2 / (np.pi * (n_h * n_h * (a2 - 1.0) + 1.0) ** 2)
    lam_v = n_l * np.sqrt(n_v * n_v * (1.0 - a2) + a2)
    lam_l = n_v * np.sqrt(n_l * n_l * (1.0 - a2) + a2)
    V = 0.5 / np.maximum(lam_v + lam_l, 1e-12)  # G / (4 n.l n.v)
    F = f0 + (1.0 - f0) * (1.0 - v_h) ** 5
    spec = D * V * F
    diffuse = albedo * ((1.0 - F) / np.pi)[:, None]
    return (diffuse + spec[:, None]) * n_l[:, None]


def light_frame(light, camera):
    """Centre, emitting normal and half-axes (eu, ev) of the rectangular light in world space."""
    r, u, f = camera_basis(camera.position, camera.look_at, camera.up)
    if light.attach == "camera":
        off = np.asarray(light.offset, float)
        centre = np.asarray(camera.position, float) + off[0] * r + off[1] * u + off[2] * f
        normal, eu, ev = f, r, u
    else:
        normal = np.asarray(light.normal, float)
        normal /= np.linalg.norm(normal)
        eu = np.cross(np.asarray(light.up, float), normal)
        if np.linalg.norm(eu) < 1e-9:
            eu = np.cross([1.0, 0.0, 0.0], normal)
        eu /= np.linalg.norm(eu)
        ev = np.cross(normal, eu)
        centre = np.asarray(light.position, float)
    return centre, normal, eu * light.size[0] / 2, ev * light.size[1] / 2


def render_preview(objects, camera, light, settings, recorder: StageRecorder | None = None):
    """Raster and shade ``objects`` (points, triangles, normals, material): (hdr (H,W,3), depth (H,W))."""
    rec = recorder_or_new(recorder)
    W, H = int(camera.width), int(camera.height)
    r, u, f = camera_basis(camera.position, camera.look_at, camera.up)
    tan_x = np.tan(np.radians(camera.fov_deg) / 2.0)
    tan_y = tan_x * H / W
    with rec.run("raster"):
        pts, tris, nrm, alb, rough = [], [], [], [], []
        offset = 0
        for obj in objects:
            p = np.asarray(obj.points, float)
            n = obj.normals if obj.normals is not None else None
            if n is None:
                from sim.mesh.surface import vertex_normals

                n = vertex_normals(p, np.asarray(obj.triangles))
            colour, alpha = PREVIEW_ALBEDO.get(obj.material, PREVIEW_ALBEDO["plastic"])
            pts.append(p)
            nrm.append(np.asarray(n, float))
            tris.append(np.asarray(obj.triangles, np.int64) + offset)
            alb.append(np.tile(colour, (p.shape[0], 1)))
            rough.append(np.full(p.shape[0], alpha))
            offset += p.shape[0]
        P = np.concatenate(pts) if pts else np.zeros((0, 3))
        T = np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)
        rel = P - np.asarray(camera.position, float)
        xv, yv, zv = rel @ r, rel @ u, rel @ f
        safe = np.where(zv > 1e-12, zv, 1e-12)
        sx = (xv / safe / tan_x + 1.0) * 0.5 * W
        sy = (1.0 - yv / safe / tan_y) * 0.5 * H
        depth = np.full((H, W), np.inf)
        tri_id = np.full((H, W), -1, np.int64)
        bary = np.zeros((H, W, 3))
        if T.shape[0]:
            rasterize(sx, sy, zv, T, W, H, float(camera.near), depth, tri_id, bary)
        depth[depth > camera.far] = np.inf
    hdr = np.zeros((H, W, 3), np.float32)
    with rec.run("shade"):
        jj, ii = np.nonzero(np.isfinite(depth))
        if jj.size:
            corner = T[tri_id[jj, ii]]
            b = bary[jj, ii]
            pos = np.einsum("kc,kcd->kd", b, P[corner])
            n = np.einsum("kc,kcd->kd", b, np.concatenate(nrm)[corner])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            albedo = np.einsum("kc,kcd->kd", b, np.concatenate(alb)[corner])
            alpha = np.einsum("kc,kc->k", b, np.concatenate(rough)[corner])
            wo = np.asarray(camera.position, float) - pos
            wo /= np.linalg.norm(wo, axis=1, keepdims=True)
            n = np.where((np.einsum("ij,ij->i", n, wo) < 0.0)[:, None], -n, n)  # seen from behind
            centre, ln, eu, ev = light_frame(light, camera)
            area = 4.0 * np.linalg.norm(eu) * np.linalg.norm(ev)
            m = int(np.ceil(np.sqrt(light.samples)))
            rng = np.random.default_rng(settings.seed)
            jitter = rng.random((m * m, 2))
            radiance = np.zeros((jj.size, 3))
            for s in range(m * m):
                su = ((s % m) + jitter[s, 0]) / m * 2.0 - 1.0
                sv = ((s // m) + jitter[s, 1]) / m * 2.0 - 1.0
                q = centre + su * eu + sv * ev
                wi = q - pos
                d2 = np.maximum(np.einsum("ij,ij->i", wi, wi), 1e-12)
                wi /= np.sqrt(d2)[:, None]
                cos_l = np.clip(-(wi @ ln), 0.0, None)
                f_cos = ggx_cook_torrance(n, wo, wi, albedo, alpha)
                radiance += f_cos * (cos_l / d2)[:, None]
            radiance *= np.asarray(light.radiance, float) * area / (m * m)
            hdr[jj, ii] = radiance.astype(np.float32)
    return hdr, depth.astype(np.float32)


# The renderer interface (the same names and fields as ``tissuerender.render``), so the pipeline can
# drive either renderer.
from dataclasses import dataclass, field  # noqa: E402


@dataclass
class Camera:
    position: tuple
    look_at: tuple
    up: tuple
    fov_deg: float
    near: float
    far: float
    width: int
    height: int
    focus_distance: float | None = None
    aperture: float = 0.0


@dataclass
class AreaLight:
    size: tuple = (0.01, 0.01)
    radiance: tuple = (40.0, 40.0, 40.0)
    attach: str = "camera"
    position: tuple | None = None
    normal: tuple | None = None
    up: tuple = (0.0, 0.0, 1.0)
    offset: tuple = (0.0, 0.0, 0.0)
    sampling: str = "uniform"
    samples: int = 16


@dataclass
class RenderObject:
    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None
    uv: np.ndarray | None
    material: str
    object_id: int = 0
    velocity: np.ndarray | None = None


@dataclass
class RenderSettings:
    shadows: bool = False
    sss: bool = False
    ao: bool = False
    mucus_reflection: bool = False
    light_samples: int = 16
    supersampling: int = 1
    seed: int = 0
    motion: bool = False
    textures: bool = True


@dataclass
class FrameResult:
    hdr: np.ndarray
    depth: np.ndarray
    gbuffer: dict = field(default_factory=dict)
    stage_seconds: dict = field(default_factory=dict)


def render_frame(objects, camera, light, settings, recorder: StageRecorder | None = None) -> FrameResult:
    """The preview renderer behind the renderer interface (shadows, SSS and AO are not available)."""
    if settings.shadows or settings.sss or settings.ao or settings.mucus_reflection:
        raise NotImplementedError("the preview renderer has no shadows, SSS, AO or mucus reflection")
    rec = recorder_or_new(recorder)
    hdr, depth = render_preview(objects, camera, light, settings, rec)
    return FrameResult(hdr=hdr, depth=depth, stage_seconds=dict(rec.seconds))
