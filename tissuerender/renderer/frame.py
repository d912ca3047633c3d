"""One frame of the deferred renderer: raster -> G-buffer -> shade (area light, shadows, SSS).

Shading follows Qian §6.3: for each pixel the rectangular area light of area A is sampled at m
points, each weighing ``A / m`` (the corrected form of Qian eqs. 6.14/6.17, DESIGN.md), with
``L_o = sum f(wi, wo) (n.wi) L_e cos(theta_l) / r^2 A / m``. With ``sampling = "adaptive"`` the count
depends on the distance d to the light (Qian eqs. 6.15–6.16): ``m(d) = samples`` for d <= 0.08 m,
``samples / 2`` for d <= 0.16 m and ``samples / 4`` beyond (scope working distances; a design choice,
the thesis gives no thresholds). Because every sample weighs A / m(d), brightness does not jump at the
thresholds; only the noise does. Sample points are a Hammersley set per count, rotated per pixel
(Cranley–Patterson) from the frame seed, so a frame is deterministic.

Shadows test each light sample against a BVH of every triangle in view; the subsurface term needs
the thickness T along -n (Qian §6.3.1: "casting rays in the opposite direction of the surface
normal"), recomputed every frame from the deformed surface.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import materials
from tissuerender.renderer.brdf import layered_reflectance_cos, reflectance_cos
from tissuerender.renderer.plastic import roughplastic_cos
from tissuerender.renderer.rays import ray_scene
from tissuerender.renderer.raster import (box_downsample, camera_basis, interpolate_gbuffer,
                                         interpolate_vertex_scalar, material_lookup, rasterize_objects,
                                         scatter_radiance)
from tissuerender.stages import StageRecorder, recorder_or_new

ADAPTIVE_DISTANCES = (0.08, 0.16)  # [m] thresholds of m(d)


@dataclass
class Camera:
    """Pinhole laparoscope: ``fov_deg`` is horizontal; thin-lens focus/aperture feed depth of field."""

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
    """Rectangular area light; ``attach = "camera"`` places it at the scope tip (``offset`` in the
    camera frame: x right, y up, z forward) emitting along the view direction."""

    size: tuple = (0.01, 0.01)
    radiance: tuple = (2000.0, 2000.0, 2000.0)
    attach: str = "camera"
    position: tuple | None = None
    normal: tuple | None = None
    up: tuple = (0.0, 0.0, 1.0)
    offset: tuple = (0.0, 0.0, 0.0)
    sampling: str = "adaptive"
    samples: int = 16
    importance: tuple = ()  # ((centre, radius, multiplier), ...) painted regions for sampling = "importance"
    reflection_cone: bool = False  # extra samples in the part of the light inside the reflection cone
    cone_samples: int = 16
    pattern: str = "blue_noise"  # per-pixel sample offsets: "blue_noise" (tiled, bluenoise.py) or "white_noise"
    # diffuse lobe: "mc" (sum of f V A/m) or "ratio" (closed-form unshadowed x sampled ratio); scenes default to
    # "ratio" (tissuerender.scene.schema.Light), this low-level default stays the unbiased estimator
    estimator: str = "mc"
    penumbra_samples: int = 0  # > 0: pixels whose shadow rays disagree (and their neighbours) are re-shaded with this many


@dataclass
class RenderObject:
    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None
    uv: np.ndarray | None
    material: str
    object_id: int = 0
    velocity: np.ndarray | None = None
    optics: object | None = None  # a materials.optics.OpticalMaterial replacing the preset's (scene overrides)


@dataclass
class RenderSettings:
    shadows: bool = False
    sss: bool = False
    sss_thickness: str = "vertex"  # thickness rays from the vertices (interpolated) or from every shading point
    ao: bool = False
    mucus_reflection: bool = False
    light_samples: int = 16
    supersampling: int = 1
    seed: int = 0
    motion: bool = False
    ambient: tuple = (0.0, 0.0, 0.0)  # uniform environment radiance [W m^-2 sr^-1]
    environment_up: tuple = (0.0, 0.0, 0.0)  # SH gradient environment for the mucus reflection
    environment_down: tuple = (0.0, 0.0, 0.0)
    environment_axis: tuple = (0.0, 0.0, 1.0)
    ao_distance: float = 0.02  # occlusion ray length [m]
    ao_samples: int = 8
    jitter: bool = True  # supersampling: each sample at a seeded random point of its cell (False: cell centres)
    fused: bool = True  # numba direct-lighting passes (shade_kernel); False: the NumPy estimator only
    ray_backend: str = "auto"  # "auto" | "embree" | "numba" (tissuerender.renderer.rays)


@dataclass
class FrameResult:
    hdr: np.ndarray
    depth: np.ndarray
    gbuffer: dict = field(default_factory=dict)
    stage_seconds: dict = field(default_factory=dict)


def light_frame(light: AreaLight, camera: Camera):
    """Centre, emitting unit normal and half-axes (eu, ev) of the light in world space."""
    r, u, f = camera_basis(camera.position, camera.look_at, camera.up)
    if light.attach == "camera":
        off = np.asarray(light.offset, float)
        centre = np.asarray(camera.position, float) + off[0] * r + off[1] * u + off[2] * f
        normal, eu, ev = f, r, u
    else:
        normal = np.asarray(light.normal, float) / np.linalg.norm(light.normal)
        eu = np.cross(np.asarray(light.up, float), normal)
        if np.linalg.norm(eu) < 1e-9:
            eu = np.cross([1.0, 0.0, 0.0], normal)
        eu /= np.linalg.norm(eu)
        ev = np.cross(normal, eu)
        centre = np.asarray(light.position, float)
    return centre, normal, eu * light.size[0] / 2.0, ev * light.size[1] / 2.0


def sample_counts(distance: np.ndarray, light: AreaLight) -> np.ndarray:
    """m(d) per shading point (Qian eq. 6.16); constant ``samples`` for uniform sampling."""
    m = np.full(distance.shape, light.samples, np.int64)
    if light.sampling == "importance":
        raise ValueError("importance sampling needs the shading positions: use importance_counts")
    if light.sampling == "adaptive":
        m[distance > ADAPTIVE_DISTANCES[0]] = max(1, light.samples // 2)
        m[distance > ADAPTIVE_DISTANCES[1]] = max(1, light.samples // 4)
    return m


def importance_counts(pos: np.ndarray, light: AreaLight) -> np.ndarray:
    """Painted importance (Qian Fig. 6.15): ``samples`` times the largest stroke weight at each point,
    a stroke weighing ``1 + (multiplier - 1) (1 - v^2/r^2)^3`` within its radius r (the normalised poly6
    falloff of the stiffness painting) and 1 elsewhere. Each sample still weighs A / m, so painting
    moves noise, not brightness."""
    factor = np.ones(pos.shape[0])
    for centre, radius, multiplier in light.importance:
        v2 = np.sum((pos - np.asarray(centre, float)) ** 2, axis=1) / (radius * radius)
        falloff = np.where(v2 < 1.0, (1.0 - v2) ** 3, 0.0)
        factor = np.maximum(factor, 1.0 + (multiplier - 1.0) * falloff)
    return np.maximum(1, np.round(light.samples * factor)).astype(np.int64)


def radical_inverse(i: np.ndarray) -> np.ndarray:
    """Van der Corput radical inverse in base 2 (the second Hammersley coordinate)."""
    i = i.astype(np.uint64)
    out = np.zeros(i.shape)
    f = 0.5
    while np.any(i):
        out += f * (i & np.uint64(1))
        i = i >> np.uint64(1)
        f *= 0.5
    return out


def sobol2(i: np.ndarray) -> np.ndarray:
    """Second coordinate of the 2D Sobol' sequence (Kollig & Keller 2002) for indices ``i``."""
    n = np.asarray(i).astype(np.uint64)
    r = np.zeros(n.shape, np.uint64)
    v = np.full(n.shape, np.uint64(1 << 31))
    while np.any(n):
        r ^= np.where(n & np.uint64(1), v, np.uint64(0))
        n = n >> np.uint64(1)
        v ^= v >> np.uint64(1)
    return r / 4294967296.0


def light_sample(s: int, m: np.ndarray, rotation: np.ndarray, pos: np.ndarray, centre, ln, eu, ev,
                 stride: int = 1, phase: np.ndarray | int = 0):
    """Sample ``s`` of ``m`` on the light for each shading point: the point q, the unit direction wi
    towards it and the weight ``cos(theta_l) / r^2 * A / m`` (Qian eq. 6.14 with the A/m correction).

    The points are the 2D Sobol' sequence (van der Corput and Sobol's second coordinate, a
    (0,2)-sequence; Kollig & Keller 2002), rotated per pixel: supersample k (``phase``, 0 ... stride - 1,
    sharing the pixel's rotation) takes indices k P ... k P + m - 1 (P the power of two >= m). Each block
    of P is itself a stratified (0, log2 P, 2)-net, so every supersample's estimate converges to the full
    integral on its own (per-supersample estimators such as the reflection-cone split stay consistent),
    and the blocks together are a finer net over the pixel. (Interleaving one Hammersley set instead
    confined each supersample to a strip of the light: a per-pixel error that did not fall with m.)"""
    area = 4.0 * np.linalg.norm(eu) * np.linalg.norm(ev)
    k = np.asarray(phase, np.int64) + np.zeros(m.shape, np.int64)
    p2 = 2 ** np.ceil(np.log2(np.maximum(m, 1))).astype(np.int64)
    n = k * p2 + s
    u = np.mod(radical_inverse(n) + rotation[:, 0], 1.0)
    v = np.mod(sobol2(n) + rotation[:, 1], 1.0)
    q = centre + (2.0 * u - 1.0)[:, None] * eu + (2.0 * v - 1.0)[:, None] * ev
    wi = q - pos
    d2 = np.maximum(np.einsum("ij,ij->i", wi, wi), 1e-12)
    wi /= np.sqrt(d2)[:, None]
    cos_l = np.clip(-(wi @ ln), 0.0, None)
    return q, wi, cos_l / d2 * area / m


def sample_offsets(rows: np.ndarray, cols: np.ndarray, ss: int, pattern: str, seed: int):
    """Per shading point (raster rows/cols at the supersampled resolution): the Cranley–Patterson rotation
    of its light samples, the stride and its phase in the pixel's interleaved sample set.

    ``"blue_noise"``: the rotation of the pixel (shared by its ss x ss supersamples) comes from the tiled
    blue-noise texture; the supersamples take interleaved points of one set of m ss^2 (stride ss^2,
    phase = supersample index), so a pixel's samples are jointly stratified. ``"white_noise"``: an
    independent uniform rotation per shading point, each drawing its own m-point set (stride 1)."""
    if pattern == "white_noise":
        rng = np.random.default_rng(seed)
        return rng.random((rows.shape[0], 2)), 1, np.zeros(rows.shape[0], np.int64)
    if pattern != "blue_noise":
        raise ValueError(f"light pattern must be 'blue_noise' or 'white_noise', found {pattern!r}")
    from tissuerender.renderer import bluenoise

    rotation, phase = bluenoise.rotations(rows, cols, seed, ss)
    return rotation, ss * ss, phase


def cone_angle(alpha: np.ndarray) -> np.ndarray:
    """Half-angle of the reflection cone from the GGX lobe width: the half-vector angle where D falls
    to a tenth of its peak, tan^2 theta_h = alpha^2 (sqrt(10) - 1), doubled for the reflected direction."""
    return np.minimum(2.0 * np.arctan(np.maximum(alpha, 1e-3) * np.sqrt(np.sqrt(10.0) - 1.0)), np.radians(80.0))


def cone_regions(pos, n, wo, alpha, centre, ln, eu, ev):
    """The rectangle R' of the light (in its local coordinates, edges at -1 and 1) covering the reflection
    cone's footprint: (lo_u, hi_u, lo_v, hi_v, valid). Splitting the light into R' and the rest and
    sampling each with its own weight (area / samples) keeps the estimate unbiased for any R'; a good
    R' only moves samples to where the glossy lobe is."""
    r = 2.0 * np.einsum("ij,ij->i", n, wo)[:, None] * n - wo
    denom = r @ ln
    t = np.einsum("ij,j->i", centre - pos, ln) / np.where(np.abs(denom) > 1e-12, denom, np.inf)
    hit = (denom < 0.0) & (t > 0.0) & np.isfinite(t)
    q = pos + np.where(hit, t, 0.0)[:, None] * r
    eu2, ev2 = float(eu @ eu), float(ev @ ev)
    uc, vc = (q - centre) @ eu / eu2, (q - centre) @ ev / ev2
    rho = np.where(hit, t, 0.0) * np.tan(cone_angle(alpha))
    lo_u, hi_u = np.maximum(-1.0, uc - rho / np.sqrt(eu2)), np.minimum(1.0, uc + rho / np.sqrt(eu2))
    lo_v, hi_v = np.maximum(-1.0, vc - rho / np.sqrt(ev2)), np.minimum(1.0, vc + rho / np.sqrt(ev2))
    valid = hit & (hi_u > lo_u) & (hi_v > lo_v)
    return lo_u, hi_u, lo_v, hi_v, valid


def tangent_frames(n: np.ndarray):
    """Two unit tangents (t, b) per unit normal, a right-handed frame (t, b, n) (Duff et al. 2017)."""
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    bt = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bt


def ambient_occlusion(bvh, pos: np.ndarray, n: np.ndarray, samples: int, distance: float, eps: float,
                      seed: int) -> np.ndarray:
    """Cosine-weighted visibility of the hemisphere within ``distance``: the fraction of a uniform
    environment's irradiance that reaches each point (1 in the open, 1/2 in a right-angled corner).
    Directions are a stratified Hammersley set on the cosine-weighted hemisphere, rotated per point
    (Cranley-Patterson) with a seeded generator."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xA0]))
    rotation = rng.random((pos.shape[0], 2))
    t, b = tangent_frames(n)
    visible = np.zeros(pos.shape[0])
    origin = pos + eps * n
    for s in range(samples):
        u1 = np.mod((s + 0.5) / samples + rotation[:, 0], 1.0)
        u2 = np.mod(radical_inverse(np.full(pos.shape[0], s)) + rotation[:, 1], 1.0)
        r, phi = np.sqrt(u1), 2.0 * np.pi * u2
        local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - u1, 0.0))], axis=1)
        d = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:] * n
        visible += ~bvh.occluded(origin, origin + distance * d)
    return visible / samples


def irradiance(pos: np.ndarray, n: np.ndarray, light: AreaLight, camera: Camera, m: np.ndarray,
               seed: int = 0, visible=None) -> np.ndarray:
    """Irradiance [W/m^2] from the area light at points ``pos`` with normals ``n``, estimated with
    ``m`` samples per point as the shader does, with ``light.estimator``. ``visible(points, targets)``
    (optional) says which light samples a point sees; None means no occlusion."""
    centre, ln, eu, ev = light_frame(light, camera)
    rotation = np.random.default_rng(seed).random((pos.shape[0], 2))
    E = np.zeros(pos.shape[0])
    den = np.zeros(pos.shape[0])
    for s in range(int(m.max())):
        act = np.flatnonzero(s < m)
        q, wi, weight = light_sample(s, m[act], rotation[act], pos[act], centre, ln, eu, ev)
        term = weight * np.clip(np.einsum("ij,ij->i", n[act], wi), 0.0, None)
        den[act] += term
        E[act] += term if visible is None else term * visible(pos[act], q)
    if light.estimator == "ratio":
        E = ratio_scale(pos, n, centre, ln, eu, ev, den) * E
    elif light.estimator != "mc":
        raise ValueError(f"light estimator must be 'mc' or 'ratio', found {light.estimator!r}")
    return E * np.mean(light.radiance)


def unshadowed_cosine_integral(pos: np.ndarray, n: np.ndarray, centre, ln, eu, ev) -> np.ndarray:
    """Closed-form ``int_light (n.wi) cos(theta_l) / r^2 dA`` [sr] per point (horizon-clipped polygon,
    ``shade_kernel.rect_cosine_integral``): the irradiance per unit radiance without occlusion."""
    from tissuerender.renderer.shade_kernel import cosine_integrals

    pos = np.ascontiguousarray(pos, np.float64).reshape(-1, 3)
    out = np.empty(pos.shape[0])
    cosine_integrals(pos, np.ascontiguousarray(n, np.float64).reshape(-1, 3),
                     *(np.ascontiguousarray(x, np.float64) for x in (centre, ln, eu, ev)), out)
    return out


def ratio_scale(pos, n, centre, ln, eu, ev, den):
    """The ratio estimator's factor U / sum((n.wi) w) (0 where no sample is above the horizon)."""
    U = unshadowed_cosine_integral(pos, n, centre, ln, eu, ev)
    return np.where(den > 0.0, U / np.where(den > 0.0, den, 1.0), 0.0)


def _merge(objects):
    pts, tris, nrm, vel, tri_mat, names, uvs = [], [], [], [], [], [], []
    offset = 0
    for k, obj in enumerate(objects):
        p = np.asarray(obj.points, float)
        t = np.asarray(obj.triangles, np.int64)
        n = obj.normals
        if n is None:
            from sim.mesh.surface import vertex_normals

            n = vertex_normals(p, t)
        pts.append(p)
        tris.append(t + offset)
        nrm.append(np.asarray(n, float))
        vel.append(np.zeros_like(p) if obj.velocity is None else np.asarray(obj.velocity, float))
        uvs.append(np.zeros((p.shape[0], 2)) if obj.uv is None else np.asarray(obj.uv, float).reshape(-1, 2))
        tri_mat.append(np.full(t.shape[0], k, np.int64))
        names.append(obj.material)
        offset += p.shape[0]
    if not pts:
        z = np.zeros((0, 3))
        return z, np.zeros((0, 3), np.int64), z, np.zeros((0, 5)), np.zeros(0, np.int64), names
    # velocity and UV travel together as one linearly interpolated vertex attribute (n, 5)
    attributes = np.concatenate([np.concatenate(vel), np.concatenate(uvs)], axis=1)
    return np.concatenate(pts), np.concatenate(tris), np.concatenate(nrm), attributes, np.concatenate(tri_mat), names


def clip_near(P, N, V, T, tri_mat, camera: Camera):
    """Split triangles crossing the near plane so the part in front of it is still drawn.

    New vertices lie on the crossing edges at view depth ``near``; positions, normals and the vertex
    attributes ``V`` (velocity, UV) are linear along an edge, so interpolating them there is exact. Triangles wholly behind the near
    plane are dropped.
    """
    _, _, f = camera_basis(camera.position, camera.look_at, camera.up)
    z = (P - np.asarray(camera.position, float)) @ f
    near = float(camera.near)
    inside = z[T] >= near
    n_in = inside.sum(axis=1)
    crossing = np.flatnonzero((n_in > 0) & (n_in < 3))
    if crossing.size == 0:
        return P, N, V, T[n_in == 3], tri_mat[n_in == 3]
    P, N, V = list(P), list(N), list(V)
    new_tris, new_mat = [], []

    def cut(a, b):
        t = (near - z[a]) / (z[b] - z[a])
        P.append(P[a] + t * (P[b] - P[a]))
        N.append(N[a] + t * (N[b] - N[a]))
        V.append(V[a] + t * (V[b] - V[a]))
        return len(P) - 1

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
    return np.asarray(P), np.asarray(N), np.asarray(V), T, tri_mat


def textured_surface(optics, mat, uv, albedo, n, alpha):
    """Albedo, shading normals and a roughness factor of layered materials that have a texture, from their
    baked mucosa texture (``materials.textures``) sampled bilinearly at the pixels' UVs, one tile per
    ``texture_period``. The tangent-space normal map is applied in the box-projection frame (the two
    world axes the UVs were taken along), which is the surface's tangent plane on the flat faces the
    projection is made for. The roughness map (0.7 ... 1.3 x, following the mottle) scales ``alpha`` and
    is returned as a factor for the granular layer's roughness (1 where untextured)."""
    from materials.textures import sample_bilinear

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
        out_albedo[sel] = sample_bilinear(layers.baked_albedo(), st)
        factor[sel] = sample_bilinear(layers.baked_roughness_factor()[..., None], st)[:, 0]
        out_alpha[sel] = alpha[sel] * factor[sel]
        tn = sample_bilinear(layers.baked_normal(), st)
        axis = np.argmax(np.abs(n[sel]), axis=1)
        first = np.where(axis == 0, 1, 0)  # box_uv: u along y for x-facing, else along x
        second = np.where(axis == 2, 1, 2)  # v along y for z-facing, else along z
        t = np.eye(3)[first]
        b = np.eye(3)[second]
        bent = tn[:, :1] * t + tn[:, 1:2] * b + tn[:, 2:] * n[sel]
        out_n[sel] = bent / np.maximum(np.linalg.norm(bent, axis=1, keepdims=True), 1e-12)
    return out_albedo, out_n, out_alpha, factor


def _layer_arrays(optics, mat):
    """Per-shading-point parameters of the mucosa layer stack, or None when no material has layers."""
    if not any(o.layers is not None for o in optics):
        return None
    from materials.optics import MucosaLayers

    neutral = MucosaLayers(coat_ior=1.0, coat_thickness=0.0, granular_weight=0.0)
    stacks = [o.layers if o.layers is not None else neutral for o in optics]
    return {
        "mask": np.array([o.layers is not None for o in optics])[mat],
        "coat_alpha": np.array([st.coat_roughness for st in stacks])[mat],
        "coat_ior": np.array([st.coat_ior for st in stacks])[mat],
        "coat_thickness": np.array([st.coat_thickness for st in stacks])[mat],
        "coat_sigma": np.array([st.coat_absorption for st in stacks], float).reshape(-1, 3)[mat],
        "granular_weight": np.array([st.granular_weight for st in stacks])[mat],
        "granular_alpha": np.array([st.granular_roughness for st in stacks])[mat],
    }


def material_tables(optics):
    """Per-material parameters for the numba shading pass (``shade_kernel.shade_direct``), indexed by the
    G-buffer's material id."""
    from tissuerender.renderer import shade_kernel as sk
    from tissuerender.renderer.plastic import _coating_transmittance, internal_diffuse_reflectance

    k = max(len(optics), 1)
    kind = np.zeros(k, np.int64)
    coat, plastic = np.zeros((k, 5)), np.zeros((k, 3))
    coat_sigma = np.zeros((k, 3))
    tables = [np.ones(64)]
    for mid, o in enumerate(optics):
        if o.bsdf == "roughplastic":
            kind[mid] = sk.KIND_PLASTIC
            a, eta = max(float(o.roughness), 1e-3), float(o.ior)
            plastic[mid] = (eta, 1.0 / (1.0 - internal_diffuse_reflectance(eta, a)), len(tables))
            tables.append(_coating_transmittance(a, eta)[1])
        elif o.layers is not None:
            kind[mid] = sk.KIND_LAYERED
            st = o.layers
            coat[mid] = (st.coat_roughness, st.coat_ior, st.coat_thickness, st.granular_weight, st.granular_roughness)
            coat_sigma[mid] = st.coat_absorption

    def column(attr, width=None):
        values = np.array([getattr(o, attr) for o in optics], float) if optics else np.zeros(0)
        if width:
            values = values.reshape(-1, width)
        out = np.zeros((k, width) if width else k)
        out[:len(optics)] = values
        return out

    return dict(kind=kind, f0=column("f0"), k_sss=column("k_sss"), sigma=column("sigma", 3),
                sss_colour=column("sss_colour", 3), coat=coat, coat_sigma=coat_sigma, plastic=plastic,
                plastic_t=np.ascontiguousarray(np.stack(tables)))


def _penumbra_points(bits, pixel, shape):
    """Points to re-shade: every sample of a pixel whose first shadow rays disagree (bits 3 over the pixel's
    supersamples) or of one of its 8 neighbours (a penumbra the first rays happened to miss is often next
    to one they caught)."""
    from tissuerender.renderer.shade_kernel import pixel_or

    mixed = np.zeros(shape[0] * shape[1], np.uint8)
    pixel_or(np.ascontiguousarray(pixel, np.int64), bits, mixed)
    grid = (mixed == 3).reshape(shape)
    near = grid.copy()
    near[1:] |= grid[:-1]
    near[:-1] |= grid[1:]
    wide = near.copy()
    wide[:, 1:] |= near[:, :-1]
    wide[:, :-1] |= near[:, 1:]
    return np.flatnonzero(wide.ravel()[pixel])


def _shade_fused(pos, n, wo, albedo, alpha, mat, thickness, rough_factor, optics, m, rotation, stride, phase, centre,
                 ln, eu, ev, rays, eps, radiance, rec, ratio=False, penumbra_samples=0, pixel=None, shape=None):
    """Direct light of every point through the numba passes of ``shade_kernel``, added to ``radiance``;
    ``rays`` (the frame's ray scene) None means no shadows. ``penumbra_samples`` > 0 (with shadows): points
    of pixels (``pixel``: each point's index in the output image of ``shape``) whose shadow rays disagree,
    and of their neighbours, are shaded again with that many samples, which replace the first ones."""
    from tissuerender.renderer.shade_kernel import cosine_integrals, light_rays, shade_direct, visibility_bits

    k = pos.shape[0]
    if k == 0:
        return
    f64 = np.float64
    pos, n, wo, rotation = (np.ascontiguousarray(a, dtype=f64) for a in (pos, n, wo, rotation))
    m, phase, mat = (np.ascontiguousarray(a, dtype=np.int64) for a in (m, phase, mat))
    centre, ln, eu, ev = (np.asarray(c, f64) for c in (centre, ln, eu, ev))
    ray_offsets = np.zeros(k, np.int64)
    occluded = np.zeros(0, np.bool_)
    if rays is not None:
        with rec.run("shadow_rays"):
            np.cumsum(m[:-1], out=ray_offsets[1:])
            total = int(ray_offsets[-1] + m[-1])
            origins, dirs, tfar = (np.empty((total, 3), np.float32), np.empty((total, 3), np.float32),
                                   np.empty(total, np.float32))
            light_rays(pos, n, m, rotation, int(stride), phase, centre, ln, eu, ev, float(eps), ray_offsets, origins,
                       dirs, tfar)
            occluded = np.ascontiguousarray(rays.occluded_rays(origins, dirs, tfar), dtype=np.bool_)
    t = material_tables(optics)
    unshadowed = np.zeros(k if ratio else 0)
    if ratio:
        cosine_integrals(pos, n, centre, ln, eu, ev, unshadowed)
    has_sss = thickness is not None
    albedo = np.ascontiguousarray(albedo, dtype=f64)
    alpha = np.ascontiguousarray(alpha, dtype=f64)
    thickness = np.ascontiguousarray(thickness, dtype=f64) if has_sss else np.zeros(1)
    rough_factor = np.ascontiguousarray(rough_factor, dtype=f64) if rough_factor is not None else np.ones(k)
    redo = np.zeros(0, np.int64)
    if rays is not None and penumbra_samples > 0:
        with rec.run("shadow_rays"):
            bits = np.empty(k, np.uint8)
            visibility_bits(pos, n, m, rotation, int(stride), phase, centre, ln, eu, ev, float(eps), ray_offsets,
                            occluded, bits)
            redo = _penumbra_points(bits, pixel, shape)

    def shade(sel, m_sel, offsets, occ, out):
        shade_direct(pos[sel], n[sel], wo[sel], albedo[sel], alpha[sel], mat[sel],
                     thickness[sel] if has_sss else thickness, has_sss, rough_factor[sel], m_sel, rotation[sel],
                     int(stride), phase[sel], centre, ln, eu, ev, float(eps), rays is not None, offsets, occ,
                     t["kind"], t["f0"], t["k_sss"], t["sigma"], t["sss_colour"], t["coat"], t["coat_sigma"],
                     t["plastic"], t["plastic_t"], bool(ratio), unshadowed[sel] if ratio else unshadowed, out)

    before = radiance[redo]  # (a copy) what the penumbra points held before their first estimate
    shade(slice(None), m, ray_offsets, occluded, radiance)
    if redo.size == 0:
        return
    # the penumbra points again, with their own sample sets of penumbra_samples (at least m) each
    m_redo = np.maximum(m[redo], int(penumbra_samples))
    offsets = np.zeros(redo.size, np.int64)
    np.cumsum(m_redo[:-1], out=offsets[1:])
    total = int(offsets[-1] + m_redo[-1])
    with rec.run("shadow_rays"):
        origins, dirs, tfar = (np.empty((total, 3), np.float32), np.empty((total, 3), np.float32),
                               np.empty(total, np.float32))
        light_rays(pos[redo], n[redo], m_redo, rotation[redo], int(stride), phase[redo], centre, ln, eu, ev, float(eps),
                   offsets, origins, dirs, tfar)
        occ = np.ascontiguousarray(rays.occluded_rays(origins, dirs, tfar), dtype=np.bool_)
    out = before.copy()
    shade(redo, m_redo, offsets, occ, out)
    radiance[redo] = out


def render_frame(objects, camera: Camera, light: AreaLight, settings: RenderSettings,
                 recorder: StageRecorder | None = None) -> FrameResult:
    """Render one frame: linear HDR radiance (H, W, 3) float32, view depth (H, W) (inf = background)."""
    rec = recorder_or_new(recorder)
    ss = int(settings.supersampling)
    W, H = int(camera.width) * ss, int(camera.height) * ss
    P, T, N, V, tri_mat, names = _merge(objects)
    optics = [o.optics if getattr(o, "optics", None) is not None else materials.get_preset(name).optics
              for o, name in zip(objects, names)]
    gbuffer: dict = {}
    with rec.run("raster"):
        P, N, V, T, tri_mat = clip_near(P, N, V, T, tri_mat, camera)
        # with supersampling, each of a pixel's ss x ss samples at a seeded uniform point of its own cell
        jitter_seed = int(settings.seed) % (1 << 62) if ss > 1 and settings.jitter else -1
        depth, tri_id, bary = rasterize_objects(P, T, camera, W, H, jitter_seed)
        jj, ii, pos, n, wo, tri = interpolate_gbuffer(P, N, T, tri_id, bary, camera.position)
        mat, albedo, alpha, f0 = material_lookup(tri, tri_mat, np.array([o.diffuse_albedo for o in optics], float),
                                                 np.array([o.roughness for o in optics], float),
                                                 np.array([o.f0 for o in optics], float))
        gbuffer.update(depth=depth, position=pos, normal=n, material_id=mat, albedo=albedo, roughness=alpha)
        rough_factor = None
        if settings.motion or any(o.layers is not None and o.layers.texture_seed is not None for o in optics):
            corner, b = T[tri], bary[jj, ii]
        if settings.motion:
            gbuffer["velocity"] = np.einsum("kc,kcd->kd", b, V[corner][:, :, :3])
        if any(o.layers is not None and o.layers.texture_seed is not None for o in optics):
            uv = np.einsum("kc,kcd->kd", b, V[corner][:, :, 3:])
            gbuffer["uv"] = uv
            albedo, n, alpha, rough_factor = textured_surface(optics, mat, uv, albedo, n, alpha)
            gbuffer.update(albedo=albedo, normal=n, roughness=alpha)
    bvh = None
    if settings.shadows or settings.sss or settings.ao:
        with rec.run("bvh"):
            bvh = ray_scene(P, T, settings.ray_backend)
    scale = float(np.ptp(P, axis=0).max()) if P.size else 1.0
    eps = 2e-4 * max(scale, 1e-9)  # ray offset: larger than the facet-vs-shading-normal gap (no acne)
    sss = thickness = None
    if settings.sss:
        with rec.run("thickness"):
            # inward rays start just below the surface (a small offset: a self-hit of the front face
            # is at t ~ 0, while a thin layer's back face may be closer than the shadow-ray offset)
            inward = 1e-6 * max(scale, 1e-9)
            # exp(-sigma T) < 1e-4 beyond T = ln(1e4) / sigma: the rays stop there (thickness inf), which
            # prunes most of the traversal through a large organ and changes no visible value
            sigmas = [min(o.sigma) for o in optics if o.k_sss > 0.0 and o.bsdf != "roughplastic"]
            reach = np.log(1e4) / max(min(sigmas), 1e-9) if sigmas else 0.0
            if reach > 0.0 and settings.sss_thickness == "vertex":
                # one ray per render-surface vertex along its inward normal, interpolated over each
                # triangle with the raster's barycentrics (a thickness map on the surface)
                # (only the vertices of triangles in view: the interpolation reads no other)
                seen = np.zeros(T.shape[0], bool)
                seen[tri] = True
                used = np.zeros(P.shape[0], bool)
                used[T[seen]] = True
                idx = np.flatnonzero(used)
                nv = N[idx] / np.maximum(np.linalg.norm(N[idx], axis=1, keepdims=True), 1e-12)
                at_vertex = np.full(P.shape[0], np.nan)
                at_vertex[idx] = bvh.closest_hit(P[idx] - inward * nv, -nv, reach) + inward
                thickness = interpolate_vertex_scalar(at_vertex, T, tri_id, bary, jj, ii)
            elif reach > 0.0:
                thickness = bvh.closest_hit(pos - inward * n, -n, reach) + inward
            else:
                thickness = np.full(pos.shape[0], np.inf)  # no material scatters below its surface
            gbuffer["thickness"] = thickness
    # the numba passes cover every point unless the reflection cone (NumPy estimator) is asked for
    fused = settings.fused and not light.reflection_cone
    if light.estimator not in ("mc", "ratio"):
        raise ValueError(f"light estimator must be 'mc' or 'ratio', found {light.estimator!r}")
    if (light.estimator == "ratio" or light.penumbra_samples > 0) and not fused:
        raise NotImplementedError("light.estimator = \"ratio\" and light.penumbra_samples run in the numba shading "
                                  "pass only, which the reflection cone (NumPy estimator) does not use")
    if settings.sss and not fused:
        k_sss = np.array([o.k_sss for o in optics], float)[mat]
        sigma = np.array([o.sigma for o in optics], float).reshape(-1, 3)[mat]
        colour = np.array([o.sss_colour for o in optics], float).reshape(-1, 3)[mat]
        transmit = np.exp(-sigma * np.where(np.isfinite(thickness), thickness, np.inf)[:, None])
        sss = k_sss[:, None] * (colour / np.pi * transmit - albedo / np.pi)
    layered = _layer_arrays(optics, mat)
    if layered is not None and rough_factor is not None:
        layered["granular_alpha"] = layered["granular_alpha"] * rough_factor
    gbuffer["specular"] = f0
    if layered is not None:
        # the layer channels exist only when a layered material is in view: each point's connective and
        # submucosa colours (k, 2, 3), and the weight of the wet (mucus) reflection, the coat's Fresnel
        # reflectance at the viewing angle (0 off the mucosa)
        from tissuerender.renderer.brdf import dielectric_F

        stacks = [o.layers for o in optics]
        colours = np.array([[st.connective_colour, st.submucosa_colour] if st is not None else [[0.0] * 3] * 2
                            for st in stacks], float)
        gbuffer["layer_albedo"] = colours[mat]
        nv = np.clip(np.einsum("ij,ij->i", n, wo), 0.0, 1.0)
        gbuffer["mucus_weight"] = np.where(layered["mask"], dielectric_F(nv, layered["coat_ior"]), 0.0)
    hdr = np.zeros((H, W, 3), np.float32)
    with rec.run("shade"):
        centre, ln, eu, ev = light_frame(light, camera)
        if light.sampling == "importance":
            m = importance_counts(pos, light)
        else:
            m = sample_counts(np.sqrt(np.einsum("ij,ij->i", pos - centre, pos - centre)), light)
        gbuffer["light_samples"] = m
        rotation, stride, phase = sample_offsets(jj, ii, ss, light.pattern, settings.seed)
        radiance = np.zeros((pos.shape[0], 3))
        cone = None
        if light.reflection_cone and pos.shape[0]:
            spec_alpha = alpha.copy()
            if layered is not None:
                spec_alpha[layered["mask"]] = layered["coat_alpha"][layered["mask"]]
            cone = cone_regions(pos, n, wo, spec_alpha, centre, ln, eu, ev)
            gbuffer["cone"] = cone[4]

        def contribute(act, q, wi, weight):
            if settings.shadows:
                with rec.run("shadow_rays"):
                    weight = weight * ~bvh.occluded(pos[act] + 2 * eps * n[act], q)
            f_cos = reflectance_cos(n[act], wo[act], wi, albedo[act], alpha[act], f0[act],
                                    None if sss is None else sss[act])
            for mid, o in enumerate(optics):
                if o.bsdf == "roughplastic":
                    sel = mat[act] == mid
                    if sel.any():
                        idx = act[sel]
                        f_cos[sel] = roughplastic_cos(n[idx], wo[idx], wi[sel], albedo[idx], o.roughness, o.ior)
            if layered is not None:
                sel = layered["mask"][act]
                if sel.any():
                    idx = act[sel]
                    f_cos[sel] = layered_reflectance_cos(
                        n[idx], wo[idx], wi[sel], f_cos[sel], layered["coat_alpha"][idx], layered["coat_ior"][idx],
                        layered["coat_thickness"][idx], layered["coat_sigma"][idx], layered["granular_weight"][idx],
                        layered["granular_alpha"][idx])
            radiance[act] += f_cos * weight[:, None]

        eu2, ev2 = float(eu @ eu), float(ev @ ev)
        if fused:
            _shade_fused(pos, n, wo, albedo, alpha, mat, thickness, rough_factor, optics, m, rotation, stride, phase,
                         centre, ln, eu, ev, bvh if settings.shadows else None, eps, radiance, rec,
                         light.estimator == "ratio", int(light.penumbra_samples), (jj // ss) * camera.width + ii // ss,
                         (int(camera.height), int(camera.width)))
        for s in range(int(m.max()) if m.size and not fused else 0):
            act = np.flatnonzero(s < m)
            q, wi, weight = light_sample(s, m[act], rotation[act], pos[act], centre, ln, eu, ev, stride, phase[act])
            if cone is not None:
                # uniform samples landing in R' are replaced by the cone samples below (stratification)
                u, v = (q - centre) @ eu / eu2, (q - centre) @ ev / ev2
                inside = (cone[4][act] & (u >= cone[0][act]) & (u < cone[1][act]) & (v >= cone[2][act])
                          & (v < cone[3][act]))
                weight = np.where(inside, 0.0, weight)
            contribute(act, q, wi, weight)
        if cone is not None:
            act = np.flatnonzero(cone[4])
            mc = int(light.cone_samples)
            lo_u, hi_u, lo_v, hi_v = (c[act] for c in cone[:4])
            area = (hi_u - lo_u) * (hi_v - lo_v) * np.sqrt(eu2 * ev2)  # of R' [m^2]
            for s in range(mc):
                u = lo_u + (hi_u - lo_u) * np.mod((s + 0.5) / mc + rotation[act, 0], 1.0)
                v = lo_v + (hi_v - lo_v) * np.mod(radical_inverse(np.full(act.size, s)) + rotation[act, 1], 1.0)
                q = centre + u[:, None] * eu + v[:, None] * ev
                wi = q - pos[act]
                d2 = np.maximum(np.einsum("ij,ij->i", wi, wi), 1e-12)
                wi /= np.sqrt(d2)[:, None]
                cos_l = np.clip(-(wi @ ln), 0.0, None)
                contribute(act, q, wi, cos_l / d2 * area / mc)
        radiance *= np.asarray(light.radiance, float)
    if settings.mucus_reflection and layered is not None and layered["mask"].any():
        with rec.run("mucus_reflection"):
            from tissuerender.renderer import sh
            from tissuerender.renderer.brdf import dielectric_F

            idx = np.flatnonzero(layered["mask"])
            env = sh.gradient_environment(settings.environment_up, settings.environment_down,
                                          settings.environment_axis)
            nv = np.clip(np.einsum("ij,ij->i", n[idx], wo[idx]), 0.0, 1.0)
            mirror = 2.0 * nv[:, None] * n[idx] - wo[idx]
            reflected = sh.evaluate(env, mirror, layered["coat_alpha"][idx])
            fresnel = dielectric_F(nv, layered["coat_ior"][idx])
            radiance[idx] += fresnel[:, None] * np.maximum(reflected, 0.0)
    ambient = np.asarray(settings.ambient, float)
    if np.any(ambient > 0.0):
        # a uniform environment L_a on a Lambertian surface: int (albedo / pi) L_a cos dw = albedo L_a,
        # times the cosine-weighted visibility when ambient occlusion is on
        visibility = np.ones(pos.shape[0])
        if settings.ao:
            with rec.run("ao"):
                visibility = ambient_occlusion(bvh, pos, n, int(settings.ao_samples), float(settings.ao_distance),
                                               2 * eps, settings.seed)
                gbuffer["ao"] = visibility
        radiance += albedo * ambient[None, :] * visibility[:, None]
    with rec.run("shade"):
        scatter_radiance(radiance, jj, ii, hdr)
    out_depth = depth.astype(np.float32)
    if ss > 1:
        hdr, out_depth = box_downsample(hdr, out_depth, ss)
    return FrameResult(hdr=hdr, depth=out_depth, gbuffer=gbuffer, stage_seconds=dict(rec.seconds))
