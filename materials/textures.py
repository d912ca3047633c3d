"""Procedural organic textures (Qian §6.2.1–6.2.2): a seeded quadtree stamp generator with per-level
randomness and blend modes, palette gradients, and per-layer bakes (albedo, roughness, height,
tangent-space normal, vessel mask).

Quadtree generator: level L splits the unit square into 2^L × 2^L cells; every cell stamps one soft
ellipse whose centre is the cell centre moved by a polar offset (radius up to ``offset`` cell sizes,
uniform angle), whose size is the cell size scaled by ``1 ± size_jitter``, rotated by up to
``rotation`` radians, stretched to ``aspect`` (long thin stamps read as fibres), with an opacity drawn
around the level's opacity. Each level is blended onto the canvas with its blend mode. Each pixel only
evaluates the stamps of its own and the eight neighbouring cells, so a level costs nine passes over the
image whatever its depth. Everything comes from one ``numpy.random.Generator`` seeded by the caller:
the same seed gives the same texture, bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

BLEND_MODES = ("normal", "multiply", "screen", "overlay", "add", "max")


def blend(base: np.ndarray, layer: np.ndarray, alpha: np.ndarray, mode: str) -> np.ndarray:
    """Blend ``layer`` (values in [0, 1]) onto ``base`` with coverage ``alpha`` using ``mode``."""
    if mode == "normal":
        mixed = layer
    elif mode == "multiply":
        mixed = base * layer
    elif mode == "screen":
        mixed = 1.0 - (1.0 - base) * (1.0 - layer)
    elif mode == "overlay":
        mixed = np.where(base < 0.5, 2.0 * base * layer, 1.0 - 2.0 * (1.0 - base) * (1.0 - layer))
    elif mode == "add":
        mixed = np.minimum(base + layer, 1.0)
    elif mode == "max":
        mixed = np.maximum(base, layer)
    else:
        raise ValueError(f"unknown blend mode {mode!r}; expected one of {', '.join(BLEND_MODES)}")
    return base * (1.0 - alpha) + mixed * alpha


@dataclass(frozen=True)
class Level:
    """Randomness of one quadtree level."""

    opacity: float = 0.5
    opacity_jitter: float = 0.3
    offset: float = 0.35  # polar offset radius, in cell sizes
    size_jitter: float = 0.3
    rotation: float = np.pi  # largest rotation [rad]
    aspect: float = 1.0  # length / width of the stamp
    value: tuple[float, float] = (0.0, 1.0)  # stamp value drawn uniformly in this range
    blend: str = "normal"


@dataclass(frozen=True)
class Quadtree:
    levels: tuple[Level, ...] = field(default_factory=lambda: tuple(Level() for _ in range(6)))
    start_level: int = 1
    background: float = 0.5
    softness: float = 0.5  # width of the stamp's soft edge, as a fraction of its radius


def quadtree(size: int, spec: Quadtree, seed: int) -> np.ndarray:
    """(size, size) float64 texture in [0, 1] from the quadtree generator."""
    if size < 2:
        raise ValueError(f"texture size must be at least 2 pixels, found {size}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7E47]))
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size
    canvas = np.full((size, size), float(spec.background))
    for depth, lv in enumerate(spec.levels, start=spec.start_level):
        if lv.blend not in BLEND_MODES:
            raise ValueError(f"unknown blend mode {lv.blend!r}; expected one of {', '.join(BLEND_MODES)}")
        n = 2 ** depth
        cell = 1.0 / n
        shape = (n, n)
        r_off = lv.offset * cell * np.sqrt(rng.random(shape))
        theta = 2 * np.pi * rng.random(shape)
        cx = (np.arange(n)[None, :] + 0.5) * cell + r_off * np.cos(theta)
        cy = (np.arange(n)[:, None] + 0.5) * cell + r_off * np.sin(theta)
        radius = 0.5 * cell * (1.0 + lv.size_jitter * (2.0 * rng.random(shape) - 1.0))
        angle = lv.rotation * (2.0 * rng.random(shape) - 1.0)
        opacity = np.clip(lv.opacity * (1.0 + lv.opacity_jitter * (2.0 * rng.random(shape) - 1.0)), 0.0, 1.0)
        value = lv.value[0] + (lv.value[1] - lv.value[0]) * rng.random(shape)
        ci = np.minimum((x * n).astype(int), n - 1)
        cj = np.minimum((y * n).astype(int), n - 1)
        layer = np.zeros_like(canvas)
        cover = np.zeros_like(canvas)
        for dj in (-1, 0, 1):
            for di in (-1, 0, 1):
                jj, ii = (cj + dj) % n, (ci + di) % n  # the texture tiles
                dx = (x - cx[jj, ii] + 0.5) % 1.0 - 0.5
                dy = (y - cy[jj, ii] + 0.5) % 1.0 - 0.5
                c, s = np.cos(angle[jj, ii]), np.sin(angle[jj, ii])
                u = (c * dx + s * dy) / (radius[jj, ii] * np.sqrt(lv.aspect))
                v = (-s * dx + c * dy) * np.sqrt(lv.aspect) / radius[jj, ii]
                d = np.sqrt(u * u + v * v)
                a = opacity[jj, ii] * np.clip((1.0 - d) / max(spec.softness, 1e-6), 0.0, 1.0)
                take = a > cover  # the strongest stamp covering a pixel wins within a level
                layer = np.where(take, value[jj, ii], layer)
                cover = np.where(take, a, cover)
        canvas = blend(canvas, layer, cover, lv.blend)
    return np.clip(canvas, 0.0, 1.0)


def apply_palette(values: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """Map values in [0, 1] through the palette as a piecewise-linear gradient: (..., 3)."""
    stops = np.linspace(0.0, 1.0, palette.shape[0])
    return np.stack([np.interp(values, stops, palette[:, c]) for c in range(3)], axis=-1)


def normal_map(height: np.ndarray, strength: float) -> np.ndarray:
    """Tangent-space unit normals (H, W, 3) of a height field over the unit square (height in units of
    the texture width times ``strength``), by central differences with wrap-around (the texture tiles)."""
    size = height.shape[1]
    dhdx = (np.roll(height, -1, axis=1) - np.roll(height, 1, axis=1)) * size / 2.0 * strength
    dhdy = (np.roll(height, -1, axis=0) - np.roll(height, 1, axis=0)) * size / 2.0 * strength
    n = np.stack([-dhdx, -dhdy, np.ones_like(height)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


VESSELS = Quadtree(levels=tuple(Level(opacity=0.9, aspect=25.0, size_jitter=0.6, rotation=np.pi, value=(0.7, 1.0),
                                      blend="max") for _ in range(4)), start_level=1, background=0.0, softness=0.6)
MOTTLE = Quadtree(levels=tuple(Level(opacity=0.45, value=(0.3, 0.8), blend=b)
                               for b in ("normal", "overlay", "normal", "multiply", "screen", "normal")))


@dataclass
class LayerBake:
    albedo: np.ndarray  # (H, W, 3) linear RGB
    roughness: np.ndarray  # (H, W)
    height: np.ndarray  # (H, W) in [0, 1]
    normal: np.ndarray  # (H, W, 3) tangent space
    vessels: np.ndarray  # (H, W) mask in [0, 1]


def bake_layer(size: int, palette: np.ndarray, roughness: float, seed: int, pattern: Quadtree = MOTTLE,
               vessel_density: float = 0.0, bump: float = 0.002) -> LayerBake:
    """Bake one layer: a pattern mapped through ``palette``, roughness varying ±30 % with it, its
    height and normals, and (when ``vessel_density`` > 0) a vessel mask darkening the albedo."""
    values = quadtree(size, pattern, seed)
    albedo = apply_palette(values, palette)
    vessels = np.zeros_like(values)
    if vessel_density > 0.0:
        vessels = np.clip(quadtree(size, VESSELS, seed + 1) * vessel_density, 0.0, 1.0)
        albedo = albedo * (1.0 - 0.6 * vessels[..., None])  # haemoglobin absorbs: vessels read darker
    rough = np.clip(roughness * (0.7 + 0.6 * values), 0.01, 1.0)
    return LayerBake(albedo=albedo, roughness=rough, height=values, normal=normal_map(values, bump), vessels=vessels)


def sample_bilinear(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup (wrapping: the textures tile) of a (H, W, C) texture at (k, 2) UVs."""
    h, w = texture.shape[:2]
    x = np.mod(uv[:, 0], 1.0) * w - 0.5
    y = np.mod(uv[:, 1], 1.0) * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    tx, ty = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0 % w, y0 % h
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    top = texture[y0, x0] * (1 - tx) + texture[y0, x1] * tx
    bottom = texture[y1, x0] * (1 - tx) + texture[y1, x1] * tx
    return top * (1 - ty) + bottom * ty


def mip_chain(texture: np.ndarray) -> list[np.ndarray]:
    """The texture's mip-map pyramid (Williams 1983): level 0 is ``texture`` (H, W, C), each next level the 2 x 2
    box average of the one before, while both sides are even (a 256-texel bake has 9 levels, down to 1 x 1, the
    texture's mean)."""
    chain = [np.asarray(texture, dtype=np.float64)]
    while chain[-1].shape[0] % 2 == 0 and chain[-1].shape[1] % 2 == 0 and min(chain[-1].shape[:2]) > 1:
        t = chain[-1]
        chain.append(0.25 * (t[0::2, 0::2] + t[1::2, 0::2] + t[0::2, 1::2] + t[1::2, 1::2]))
    return chain


def sample_mipmapped(chain: list[np.ndarray], uv: np.ndarray, texels: np.ndarray) -> np.ndarray:
    """Trilinear lookup (wrapping) at (k, 2) UVs of a :func:`mip_chain` seen with a footprint of ``texels`` (k,)
    level-0 texels per sample: bilinear in the two levels around ``lod = log2(texels)`` (clamped to the chain),
    blended linearly in lod. A footprint of one texel or less is the plain bilinear lookup of level 0; a sample
    covering the whole tile reads the texture's mean, so a pattern finer than the pixels averages out instead
    of aliasing into speckle."""
    lod = np.clip(np.log2(np.maximum(np.asarray(texels, dtype=np.float64), 1.0)), 0.0, len(chain) - 1.0)
    low = np.minimum(np.floor(lod).astype(int), len(chain) - 1)
    blend_up = (lod - low)[:, None]
    out = np.empty((uv.shape[0], chain[0].shape[2]))
    for level in np.unique(low):
        sel = np.flatnonzero(low == level)
        value = sample_bilinear(chain[level], uv[sel])
        if level + 1 < len(chain) and blend_up[sel].any():
            value = value * (1.0 - blend_up[sel]) + sample_bilinear(chain[level + 1], uv[sel]) * blend_up[sel]
        out[sel] = value
    return out
