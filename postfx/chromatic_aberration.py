"""Chromatic aberration: radial per-channel magnification about the optical centre (lateral colour,
Qian §6.3.3).

| name | default | unit | range | equation |
|---|---|---|---|---|
| `strength_r` | 0.004 | - | [-1, 1] | red magnified by `1 + strength_r`: a feature at radius r px moves to `r (1 + strength_r)` |
| `strength_g` | 0 | - | [-1, 1] | as red, for green |
| `strength_b` | -0.004 | - | [-1, 1] | as red, for blue |
| `centre` | [0.5, 0.5] | fractions of W, H | each [0, 1] | optical centre c |

Channel c of pixel p is read bilinearly at ``c + (p - c) / (1 + strength_c)`` (coordinates clamped).
Typical scopes: |strength| 0.001–0.01.
"""
from __future__ import annotations

from typing import Annotated

import numpy as np
from numba import njit, prange
from pydantic import Field

from postfx.effect import Effect, EffectParams, image_only
from postfx.gl.shaders import HEADER, PIXEL, register
from postfx.kernels import bilinear_clamped


class ChromaticAberration(EffectParams):
    """Radial per-channel magnification about the optical centre (lateral colour, Qian §6.3.3).

    Channel ``c`` is magnified by ``1 + strength_c``: a feature at radius r pixels moves to
    ``r (1 + strength_c)``. Typical scopes: |strength| 0.001–0.01.
    """

    strength_r: Annotated[float, Field(ge=-1.0, le=1.0, description="red magnification - 1")] = 0.004
    strength_g: Annotated[float, Field(ge=-1.0, le=1.0, description="green magnification - 1")] = 0.0
    strength_b: Annotated[float, Field(ge=-1.0, le=1.0, description="blue magnification - 1")] = -0.004
    centre: Annotated[list[Annotated[float, Field(ge=0.0, le=1.0)]], Field(min_length=2, max_length=2,
                      description="optical centre as a fraction of width and height")] = [0.5, 0.5]


def _scales(p: ChromaticAberration) -> list[float]:
    """The sampling scale ``1 / (1 + strength_c)`` per channel (a large finite value at strength -1)."""
    return [1.0 / (1.0 + k) if k > -1.0 else 1e6 for k in (p.strength_r, p.strength_g, p.strength_b)]


@njit(cache=True, parallel=True)
def _radial_resample(img, cx, cy, scales):
    """Channel c of pixel (i, j) samples the input at c + (p - c) * scales[c], bilinearly (pixel
    centres at +0.5, coordinates clamped to the image)."""
    h, w, nc = img.shape
    out = np.empty_like(img)
    for j in prange(h):
        y = j + 0.5
        for i in range(w):
            x = i + 0.5
            for c in range(nc):
                sx = np.float32(cx + (x - cx) * scales[c])
                sy = np.float32(cy + (y - cy) * scales[c])
                out[j, i, c] = bilinear_clamped(img, c, sx, sy)
    return out


def chromatic_aberration(img: np.ndarray, p: ChromaticAberration) -> np.ndarray:
    """Magnify channel c by ``1 + strength_c`` about the optical centre (bilinear resampling)."""
    h, w, _ = img.shape
    return _radial_resample(np.ascontiguousarray(img, dtype=np.float32), p.centre[0] * w, p.centre[1] * h,
                            np.array(_scales(p)))


SHADER = register("chromatic_aberration", HEADER + "uniform sampler2D img;\nuniform vec3 scale;\nuniform vec2 centre;\n"
                  "//EPILOGUE::Dec\n" + """
void main() {
""" + PIXEL + """  // channel c bilinear at centre + (pos - centre) scale_c: the sampler's linear filter (clamped)
  vec2 pos = vec2(p) + 0.5, inv = 1.0 / vec2(size);
  vec3 rgb = vec3(texture(img, (centre + (pos - centre) * scale.r) * inv).r,
                  texture(img, (centre + (pos - centre) * scale.g) * inv).g,
                  texture(img, (centre + (pos - centre) * scale.b) * inv).b);
  gl_FragData[0] = vec4(post(rgb, p, size), 1.0);
}
""")


def draw(ctx, tex, p: ChromaticAberration, ep, frame):
    w, h = tex.GetWidth(), tex.GetHeight()
    return ctx.draw(SHADER, {"img": tex, **ep.inputs},
                    {"scale": _scales(p), "centre": (p.centre[0] * w, p.centre[1] * h), **ep.uniforms},
                    w, h, epilogue=ep.passes, linear={"img": False})


EFFECT = Effect("chromatic_aberration", ChromaticAberration, image_only(chromatic_aberration), draw)
