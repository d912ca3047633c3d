"""Lens flare: pseudo flare from HDR highlights (after J. Chapman, "Pseudo Lens Flare", 2013), added in
scene-linear light before the tone map.

| name | default | unit | range | equation |
|---|---|---|---|---|
| `threshold` | 2 | scene-linear luminance | [0, 1e6] | bright part `B = x max(l - threshold, 0) / l` at half resolution |
| `intensity` | 0.1 | - | [0, 10] | `y = x + intensity up(G * F)` |
| `ghosts` | four ghosts | `[s, r, g, b]` | at most 16; 0.5 <= abs(s) <= 8, tints [0, 10] | ghost of a highlight at x at `c + s (x - c)`, weight `tint / s^2` |
| `halo_radius` | 0.6 | half image heights | [0, 4] | a highlight at distance d from c shows at d + h on its ray |
| `halo_tint` | [0.25, 0.3, 0.4] | - | each [0, 10] | tint of the halo |
| `falloff` | 2 | - | integer [0, 16] | fade of a source at q: `(1 - min(length(q - c) / rho, 1))^falloff`, rho = half diagonal |
| `blur_px` | 2 | full-res px | [0, 16] | Gaussian G of `blur_px / 2` half-res pixels (none at 0) |
| `centre` | [0.5, 0.5] | fractions of W, H | each [0, 1] | optical centre c |

The NumPy reference (the GLSL passes below mirror it), made geometric: stray reflections between lens
surfaces image the bright sources a second time, scaled about the optical centre (ghosts) or spread
around it (halo). Steps, all in scene-linear light before the tone map:

1. ``B``: the part of each pixel above ``threshold`` in luminance, averaged over 2x2 blocks (half
   resolution: the flare is low-frequency), and ``B4`` its 2x2 average (quarter resolution).
2. Features at half resolution. Ghost ``[s, r, g, b]`` at output position p (full-res pixels) reads the
   source at ``q = c + (p - c) / s``: a highlight at x shows at ``c + s (x - c)``. It is weighted by
   ``tint / s^2`` (the ghost's energy does not depend on its scale) and by the radial fade of its
   source ``f(q) = (1 - min(|q - c| / rho, 1))^falloff``, rho = half the image diagonal. Ghosts with
   |s| >= 1 read ``B`` and smaller ones ``B4``, so that neighbouring outputs never step over a
   source texel. The halo reads ``q = p + h (c - p) / |c - p|`` (h = ``halo_radius`` x half the
   height): a highlight at distance d from the centre shows at distance d + h on the same ray (and,
   for d < h, at h - d on the other side); one at the centre draws a ring of radius h.
   Outside the image the sources are zero (a clamp would smear the border into every ghost).
3. Gaussian blur of ``blur_px / 2`` half-res pixels, bilinear upsampling, ``img + intensity F``.
"""
from __future__ import annotations

import functools
from typing import Annotated

import numpy as np
from numba import njit, prange
from pydantic import Field, field_validator

from postfx.effect import Effect, EffectParams, image_only
from postfx.gaussian import gaussian_blur
from postfx.gl import gaussian as gl_gaussian
from postfx.gl import halfres
from postfx.gl.library import Vec4Array
from postfx.gl.shaders import HEADER, register
from postfx.kernels import add_upsampled, bright_half, threads_for


class LensFlare(EffectParams):
    """Pseudo lens flare from HDR highlights (after J. Chapman, "Pseudo Lens Flare", 2013): the part of
    the image above ``threshold`` (luminance, scene-linear) at half resolution, imaged again by each
    ghost and by a halo, blurred, and added times ``intensity`` before the tone map.

    Ghost ``[s, r, g, b]``: a copy of the highlights scaled by ``s`` about the optical centre ``c``
    (a highlight at x appears at ``c + s (x - c)``; s < 0 mirrors it through the centre), tinted
    (r, g, b) and dimmed by ``1 / s^2`` so that its energy does not depend on its size. Halo: a
    highlight at x appears ``halo_radius`` further out along the ray from the centre through x (a
    highlight at the centre draws a ring). Both fade with the source's distance from the centre,
    ``(1 - |x - c| / half diagonal)^falloff``.
    """

    threshold: Annotated[float, Field(ge=0.0, le=1e6, description="luminance where highlights start")] = 2.0
    intensity: Annotated[float, Field(ge=0.0, le=10.0)] = 0.1
    ghosts: Annotated[list[Annotated[list[float], Field(min_length=4, max_length=4)]], Field(max_length=16)] = [
        [-0.5, 1.0, 0.65, 0.35], [-1.0, 0.35, 0.6, 1.0], [-1.6, 0.45, 1.0, 0.55], [1.4, 1.0, 0.5, 0.8]]
    halo_radius: Annotated[float, Field(ge=0.0, le=4.0, description="fraction of half the image height")] = 0.6
    halo_tint: Annotated[list[Annotated[float, Field(ge=0.0, le=10.0)]], Field(min_length=3, max_length=3)] = [
        0.25, 0.3, 0.4]
    falloff: Annotated[int, Field(ge=0, le=16, description="integer exponent of the radial fade")] = 2
    blur_px: Annotated[float, Field(ge=0.0, le=16.0, description="softening of ghosts and halo [px]")] = 2.0
    centre: Annotated[list[Annotated[float, Field(ge=0.0, le=1.0)]], Field(min_length=2, max_length=2,
                      description="optical centre as a fraction of width and height")] = [0.5, 0.5]

    @field_validator("ghosts")
    @classmethod
    def _ghost_scale_and_tint(cls, ghosts):
        for k, (scale, *tint) in enumerate(ghosts):
            if not 0.5 <= abs(scale) <= 8.0:
                raise ValueError(f"ghost {k}: scale must satisfy 0.5 <= |scale| <= 8 (smaller ghosts would skip "
                                 f"highlights at half resolution), found {scale}")
            if any(not 0.0 <= t <= 10.0 for t in tint):
                raise ValueError(f"ghost {k}: tint values must be in [0, 10], found {tint}")
        return ghosts


@njit(cache=True)  # a small kernel: a parallel region would cost more to wake than it saves
def downsample2(img):
    """2x2 block mean (indices clamped at an odd edge)."""
    h, w, nc = img.shape
    hh, wh = (h + 1) // 2, (w + 1) // 2
    out = np.empty((hh, wh, nc), np.float32)
    for jh in range(hh):
        j0, j1 = 2 * jh, min(2 * jh + 1, h - 1)
        for ih in range(wh):
            i0, i1 = 2 * ih, min(2 * ih + 1, w - 1)
            for c in range(nc):
                out[jh, ih, c] = (img[j0, i0, c] + img[j0, i1, c] + img[j1, i0, c] + img[j1, i1, c]) * np.float32(0.25)
    return out


@njit(cache=True, inline="always")
def bilinear_zero(img, x, y):
    """Bilinear sample (r, g, b) at (x, y) in texels (centres at +0.5), zero outside the image."""
    h, w = img.shape[0], img.shape[1]
    fx = x - np.float32(0.5)
    fy = y - np.float32(0.5)
    x0f = np.floor(fx)
    y0f = np.floor(fy)
    tx = fx - x0f
    ty = fy - y0f
    x0 = int(x0f)
    y0 = int(y0f)
    r = np.float32(0.0)
    g = np.float32(0.0)
    b = np.float32(0.0)
    if x0 < -1 or y0 < -1 or x0 >= w or y0 >= h:
        return r, g, b
    for dy in range(2):
        yy = y0 + dy
        if yy < 0 or yy >= h:
            continue
        wy = ty if dy == 1 else np.float32(1.0) - ty
        for dx in range(2):
            xx = x0 + dx
            if xx < 0 or xx >= w:
                continue
            wxy = wy * (tx if dx == 1 else np.float32(1.0) - tx)
            r += wxy * img[yy, xx, 0]
            g += wxy * img[yy, xx, 1]
            b += wxy * img[yy, xx, 2]
    return r, g, b


@njit(cache=True, inline="always")
def _fade(qx, qy, cx, cy, rho, falloff):
    """``(1 - min(length(q - c) / rho, 1))^falloff``, an integer power by repeated products (as the shader)."""
    d = np.sqrt((qx - cx) * (qx - cx) + (qy - cy) * (qy - cy)) / rho
    base = max(np.float32(1.0) - d, np.float32(0.0))
    f = np.float32(1.0)
    for _ in range(falloff):
        f *= base
    return f


@njit(cache=True, parallel=True)
def _features(half, quarter, cx, cy, rho, ghosts, halo, halo_tint, falloff):
    """Ghosts and halo at half resolution; positions in full-res pixels (half texel k is centred at
    2k + 1). ``ghosts`` (n, 4) float32 rows [s, r, g, b]."""
    hh, wh, _ = half.shape
    out = np.zeros((hh, wh, 3), np.float32)
    two = np.float32(2.0)
    for jh in prange(hh):
        py = two * (np.float32(jh) + np.float32(0.5))
        for ih in range(wh):
            px = two * (np.float32(ih) + np.float32(0.5))
            a0 = np.float32(0.0)
            a1 = np.float32(0.0)
            a2 = np.float32(0.0)
            for k in range(ghosts.shape[0]):
                s = ghosts[k, 0]
                qx = cx + (px - cx) / s
                qy = cy + (py - cy) / s
                wk = _fade(qx, qy, cx, cy, rho, falloff) / (s * s)
                if wk <= np.float32(0.0):
                    continue
                if abs(s) >= np.float32(1.0):
                    r, g, b = bilinear_zero(half, qx / two, qy / two)
                else:
                    r, g, b = bilinear_zero(quarter, qx / np.float32(4.0), qy / np.float32(4.0))
                a0 += ghosts[k, 1] * wk * r
                a1 += ghosts[k, 2] * wk * g
                a2 += ghosts[k, 3] * wk * b
            dx = cx - px
            dy = cy - py
            d = np.sqrt(dx * dx + dy * dy)
            if halo > np.float32(0.0) and d > np.float32(0.0):
                qx = px + dx * (halo / d)
                qy = py + dy * (halo / d)
                wh_ = _fade(qx, qy, cx, cy, rho, falloff)
                if wh_ > np.float32(0.0):
                    r, g, b = bilinear_zero(half, qx / two, qy / two)
                    a0 += halo_tint[0] * wh_ * r
                    a1 += halo_tint[1] * wh_ * g
                    a2 += halo_tint[2] * wh_ * b
            out[jh, ih, 0] = a0
            out[jh, ih, 1] = a1
            out[jh, ih, 2] = a2
    return out


def geometry(shape, p: LensFlare):
    """Optical centre (full-res pixels), fade radius rho (half diagonal) and halo radius h [px]."""
    h, w = shape[:2]
    return (np.float32(p.centre[0] * w), np.float32(p.centre[1] * h), np.float32(0.5 * np.hypot(w, h)),
            np.float32(p.halo_radius * 0.5 * h))


def ghost_table(p: LensFlare) -> np.ndarray:
    return np.array(p.ghosts, np.float32).reshape(-1, 4)


def features(img: np.ndarray, p: LensFlare) -> np.ndarray:
    """The flare's light at half resolution, before the blur and ``intensity``."""
    half = bright_half(img, p.threshold)
    cx, cy, rho, halo = geometry(img.shape, p)
    with threads_for(half.size):
        return _features(half, downsample2(half), cx, cy, rho, ghost_table(p), halo,
                         np.array(p.halo_tint, np.float32), int(p.falloff))


def lens_flare(img: np.ndarray, p: LensFlare) -> np.ndarray:
    low = features(img, p)
    if p.blur_px > 0.0:
        low = gaussian_blur(low, 0.5 * p.blur_px)
    return add_upsampled(img, low, p.intensity)


@functools.lru_cache(maxsize=None)
def flare_features(n_ghosts: int, falloff: int, reads_half: tuple[bool, ...]) -> str:
    """Lens flare ghosts and halo at half resolution (``_features``), unrolled for the number of
    ghosts, the integer fade exponent and the image each ghost reads (half resolution when |s| >= 1, else
    quarter): constants let the shader compiler drop the loops and uniform-array indexing. Ghost k is
    ``ghosts[k] = (s, r, g, b)``. Registered in SHADERS under the returned name."""
    name = f"flare_features_{n_ghosts}_{falloff}_{''.join('h' if h else 'q' for h in reads_half)}"
    fade = "".join("  f *= base;\n" for _ in range(falloff))
    ghosts = "".join(f"""  {{
    float s = ghosts[{k}].x;
    vec2 q = centre + (pos - centre) / s;
    float wk = fade(q) / (s * s);
    if (wk > 0.0) acc += ghosts[{k}].yzw * wk * {"texture(half_res, q * inv_half).rgb" if half
                                                   else "texture(quarter, q * inv_quarter).rgb"};
  }}
""" for k, half in enumerate(reads_half))
    return register(name, HEADER + f"""uniform sampler2D half_res;
uniform sampler2D quarter;
uniform vec2 centre;
uniform float rho;
uniform float halo;
uniform vec3 halo_tint;
uniform vec4 ghosts[{max(n_ghosts, 1)}];
float fade(vec2 q) {{
  float base = max(1.0 - length(q - centre) / rho, 0.0), f = 1.0;
{fade}  return f;
}}
void main() {{
  vec2 size = vec2(textureSize(half_res, 0));
  ivec2 p = ivec2(texCoord * size);
  // bilinear reads, zero outside (lens_flare.bilinear_zero): the samplers' linear filter with a zero border;
  // full-res position q is q / 2 half-res and q / 4 quarter-res texels
  vec2 inv_half = 0.5 / size, inv_quarter = 0.25 / vec2(textureSize(quarter, 0));
  vec2 pos = 2.0 * (vec2(p) + 0.5);
  vec3 acc = vec3(0.0);
{ghosts}  vec2 d = centre - pos;
  float dist = length(d);
  if (halo > 0.0 && dist > 0.0) {{
    vec2 q = pos + d * (halo / dist);
    float wh = fade(q);
    if (wh > 0.0) acc += halo_tint * wh * texture(half_res, q * inv_half).rgb;
  }}
  gl_FragData[0] = vec4(acc, 1.0);
}}
""")


def draw(ctx, tex, p: LensFlare, ep, frame):
    """Half- and quarter-resolution bright parts, the features pass, its blur, added back upsampled."""
    w, h = tex.GetWidth(), tex.GetHeight()
    half = halfres.half(ctx, tex, p.threshold)
    quarter = halfres.half(ctx, half)
    cx, cy, rho, halo = geometry((h, w), p)
    ghosts = ghost_table(p)
    uniforms = {"centre": (cx, cy), "rho": rho, "halo": halo, "halo_tint": p.halo_tint}
    if len(ghosts):
        uniforms["ghosts"] = Vec4Array(ghosts.ravel())
    shader = flare_features(len(ghosts), int(p.falloff), tuple(bool(abs(s) >= 1.0) for s in ghosts[:, 0]))
    low = ctx.draw(shader, {"half_res": half, "quarter": quarter}, uniforms, half.GetWidth(), half.GetHeight(),
                   linear={"half_res": True, "quarter": True})
    ctx.release(half, quarter)
    if p.blur_px > 0.0:
        blurred = gl_gaussian.gaussian(ctx, low, 0.5 * p.blur_px)
        ctx.release(low)
        low = blurred
    return halfres.add_upsampled(ctx, tex, low, p.intensity, ep)


EFFECT = Effect("lens_flare", LensFlare, image_only(lens_flare), draw)
