"""The rectangular area light and how it is sampled (Qian §6.3).

For each shading point the light of area A is sampled at m points, each weighing ``A / m`` (the corrected
form of Qian eqs. 6.14/6.17: docs/design.md, "Qian 6.14/6.17/6.20: area-light sample weight"), with
``L_o = sum f(wi, wo) (n.wi) L_e cos(theta_l) / r^2 A / m``. With ``sampling = "adaptive"`` the count
depends on the distance d to the light (Qian eqs. 6.15–6.16): ``m(d) = samples`` for d <= 0.08 m,
``samples / 2`` for d <= 0.16 m and ``samples / 4`` beyond (scope working distances; a design choice,
the thesis gives no thresholds). Because every sample weighs A / m(d), brightness does not jump at the
thresholds; only the noise does. ``sampling = "importance"`` takes the count from painted strokes
(Qian Fig. 6.15). Sample points are a 2D Sobol' set per count, rotated per pixel (Cranley–Patterson)
from the frame seed, so a frame is deterministic.

:func:`irradiance` is the NumPy reference of the light's irradiance that the tests hold the shading
passes to.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tissuerender.renderer import bluenoise
from tissuerender.renderer.camera import Camera, camera_basis
from tissuerender.renderer.shade_kernel import cosine_integrals

ADAPTIVE_DISTANCES = (0.08, 0.16)  # [m] thresholds of m(d)
ESTIMATORS = ("mc", "ratio")


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


def check_estimator(light: AreaLight) -> None:
    """``light.estimator`` is one of :data:`ESTIMATORS`, or ValueError."""
    if light.estimator not in ESTIMATORS:
        raise ValueError(f"light estimator must be 'mc' or 'ratio', found {light.estimator!r}")


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
    rotation, phase = bluenoise.rotations(rows, cols, seed, ss)
    return rotation, ss * ss, phase


def irradiance(pos: np.ndarray, n: np.ndarray, light: AreaLight, camera: Camera, m: np.ndarray,
               seed: int = 0, visible=None) -> np.ndarray:
    """Irradiance [W/m^2] from the area light at points ``pos`` with normals ``n``, estimated with
    ``m`` samples per point as the shader does, with ``light.estimator``. ``visible(points, targets)``
    (optional) says which light samples a point sees; None means no occlusion."""
    check_estimator(light)
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
    return E * np.mean(light.radiance)


def unshadowed_cosine_integral(pos: np.ndarray, n: np.ndarray, centre, ln, eu, ev) -> np.ndarray:
    """Closed-form ``int_light (n.wi) cos(theta_l) / r^2 dA`` [sr] per point (horizon-clipped polygon,
    ``shade_kernel.rect_cosine_integral``): the irradiance per unit radiance without occlusion."""
    pos = np.ascontiguousarray(pos, np.float64).reshape(-1, 3)
    out = np.empty(pos.shape[0])
    cosine_integrals(pos, np.ascontiguousarray(n, np.float64).reshape(-1, 3),
                     *(np.ascontiguousarray(x, np.float64) for x in (centre, ln, eu, ev)), out)
    return out


def ratio_scale(pos, n, centre, ln, eu, ev, den):
    """The ratio estimator's factor U / sum((n.wi) w) (0 where no sample is above the horizon)."""
    U = unshadowed_cosine_integral(pos, n, centre, ln, eu, ev)
    return np.where(den > 0.0, U / np.where(den > 0.0, den, 1.0), 0.0)
