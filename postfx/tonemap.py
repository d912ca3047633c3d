"""Tone map: exposure, a filmic tone curve and the sRGB display encoding (linear HDR in, display out).

| name | default | unit | range | equation |
|---|---|---|---|---|
| `exposure` | 0 | stops | [-20, 20] | `x' = 2^exposure max(x, 0)` |
| `curve` | `aces` | - | `aces`, `reinhard`, `clamp` | ACES fit (Narkowicz 2015) `x' (2.51 x' + 0.03) / (x' (2.43 x' + 0.59) + 0.14)` clipped to [0, 1]; Reinhard `x' / (1 + x')`; `min(x', 1)` |
| `srgb` | true | - | bool | `12.92 y` for y <= 0.0031308, else `1.055 y^(1/2.4) - 0.055` (y clipped to [0, 1]) |

Pointwise: in a chain it runs fused with the pointwise effects next to it (``postfx.pointwise``; on the
GL side in the last pass of the effect before it).
"""
from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from numba import njit, prange
from pydantic import Field

from postfx.effect import Effect, EffectParams, Pointwise, image_only


class Tonemap(EffectParams):
    """Exposure, a filmic tone curve and the sRGB display encoding (linear HDR in, display out)."""

    exposure: Annotated[float, Field(ge=-20.0, le=20.0, description="exposure [stops]")] = 0.0
    curve: Literal["aces", "reinhard", "clamp"] = "aces"
    srgb: bool = True


TONE_CURVES = {"aces": 0, "reinhard": 1, "clamp": 2}


@njit(cache=True, inline="always")
def _srgb1(x):
    x = min(max(x, np.float32(0.0)), np.float32(1.0))
    return np.float32(12.92) * x if x <= np.float32(0.0031308) else (np.float32(1.055) * x ** np.float32(1.0 / 2.4)
                                                                      - np.float32(0.055))


@njit(cache=True, inline="always")
def tonemap_value(x, gain, curve, srgb):
    """One float32 value: exposure ``gain``, then the curve (0 ACES fit, 1 Reinhard, 2 clamp), then sRGB."""
    zero, one = np.float32(0.0), np.float32(1.0)
    x = max(x, zero) * gain
    if curve == 0:  # ACES fit (Narkowicz 2015)
        y = min(max((x * (np.float32(2.51) * x + np.float32(0.03)))
                    / (x * (np.float32(2.43) * x + np.float32(0.59)) + np.float32(0.14)), zero), one)
    elif curve == 1:
        y = x / (one + x)
    else:
        y = min(x, one)
    return _srgb1(y) if srgb else y


@njit(cache=True, parallel=True)
def _tonemap_kernel(img, gain, curve, srgb):
    """float32 throughout, as the shader (float64 pow was slower and changed nothing visible)."""
    h, w, nc = img.shape
    out = np.empty_like(img)
    gain = np.float32(gain)
    for j in prange(h):
        for i in range(w):
            for c in range(nc):
                out[j, i, c] = tonemap_value(img[j, i, c], gain, curve, srgb)
    return out


def tonemap(img: np.ndarray, p: Tonemap) -> np.ndarray:
    """Exposure ``2^exposure``, then the ACES fit, Reinhard ``x / (1 + x)`` or a clamp, then sRGB."""
    return _tonemap_kernel(np.ascontiguousarray(img, dtype=np.float32), float(2.0**p.exposure),
                           TONE_CURVES[p.curve], bool(p.srgb))


GLSL = """uniform float tm_gain;
uniform int tm_curve;
uniform int tm_srgb;
float encode(float x) {
  x = clamp(x, 0.0, 1.0);
  return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}
vec3 fx_tonemap(vec3 x, ivec2 p, ivec2 size) {
  x = max(x, vec3(0.0)) * tm_gain;
  vec3 y;
  if (tm_curve == 0) y = clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
  else if (tm_curve == 1) y = x / (1.0 + x);
  else y = clamp(x, 0.0, 1.0);
  if (tm_srgb == 1) y = vec3(encode(y.r), encode(y.g), encode(y.b));
  return y;
}
"""


def bind(ctx, p: Tonemap, width: int, height: int, seed: int) -> tuple[dict, dict]:
    return {}, {"tm_gain": 2.0 ** p.exposure, "tm_curve": TONE_CURVES[p.curve], "tm_srgb": int(p.srgb)}


EFFECT = Effect("tonemap", Tonemap, image_only(tonemap), pointwise=Pointwise(GLSL, bind))
