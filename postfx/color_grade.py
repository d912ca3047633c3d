"""Colour grade on display values (Qian §6.3.3: filmic adjustment and curve editing).

| name | default | unit | range | equation |
|---|---|---|---|---|
| `lift` | [0, 0, 0] | display value | each [-1, 4] | `y = gain (x + lift (1 - x))^(1/gamma)` per channel, clipped to [0, 1] |
| `gamma` | [1, 1, 1] | - | each (0.05, 10] | as above |
| `gain` | [1, 1, 1] | - | each [-1, 4] | as above |
| `contrast` | 1 | - | [0.1, 5] | filmic S-curve `y^c / (y^c + (1 - y)^c)`; 1 is the identity; fixes 0, 1/2, 1 |
| `curve` | [[0, 0], [1, 1]] | display value | points in [0, 1]^2, x increasing | master tone curve, monotone cubic (PCHIP) through the points, flat beyond them |
| `curve_r`, `curve_g`, `curve_b` | none | display value | as `curve` | per-channel curves after the master curve |
| `saturation` | 1 | - | [0, 4] | `l + saturation (y - l)`, l the Rec. 709 luma, clipped to [0, 1] |

The per-channel steps are sampled into a LUT of LUT_SIZE entries per channel (linear interpolation
between them); saturation follows per pixel. Pointwise: fused with its neighbours in a chain.
"""
from __future__ import annotations

import functools
from typing import Annotated

import numpy as np
from numba import njit, prange
from pydantic import Field, field_validator

from postfx.effect import Effect, EffectParams, Pointwise, image_only
from postfx.kernels import LUMA

Unit = Annotated[float, Field(ge=0.0, le=1.0)]
RGB = Annotated[list[Annotated[float, Field(ge=-1.0, le=4.0)]], Field(min_length=3, max_length=3)]


class ColorGrade(EffectParams):
    """Colour grading on display values (Qian §6.3.3: filmic adjustment and curve editing), in order:
    lift/gamma/gain per channel ``y = gain (x + lift (1 - x))^(1/gamma)``, a filmic S-curve
    ``y = x^c / (x^c + (1 - x)^c)`` (``contrast`` c; 1 is the identity; it fixes 0, 1/2 and 1), the
    editable master tone curve, the per-channel curves, then saturation about Rec. 709 luma.

    Curves are control points ``[[x, y], ...]`` with x strictly increasing in [0, 1], interpolated by a
    monotone cubic (Fritsch–Carlson / PCHIP): the curve passes through every point and never
    overshoots; beyond the first and last point it is flat.
    """

    lift: RGB = [0.0, 0.0, 0.0]
    gamma: Annotated[list[Annotated[float, Field(gt=0.05, le=10.0)]], Field(min_length=3, max_length=3)] = [1.0, 1.0, 1.0]
    gain: RGB = [1.0, 1.0, 1.0]
    contrast: Annotated[float, Field(ge=0.1, le=5.0, description="filmic S-curve exponent")] = 1.0
    curve: list[Annotated[list[Unit], Field(min_length=2, max_length=2)]] = [[0.0, 0.0], [1.0, 1.0]]
    curve_r: list[Annotated[list[Unit], Field(min_length=2, max_length=2)]] | None = None
    curve_g: list[Annotated[list[Unit], Field(min_length=2, max_length=2)]] | None = None
    curve_b: list[Annotated[list[Unit], Field(min_length=2, max_length=2)]] | None = None
    saturation: Annotated[float, Field(ge=0.0, le=4.0)] = 1.0

    @field_validator("curve", "curve_r", "curve_g", "curve_b")
    @classmethod
    def _increasing(cls, points):
        if points is None:
            return points
        if len(points) < 2:
            raise ValueError(f"a curve needs at least 2 points [x, y], found {len(points)}")
        xs = [p[0] for p in points]
        if any(b <= a for a, b in zip(xs, xs[1:])):
            raise ValueError(f"curve x values must be strictly increasing, found {xs}")
        return points


LUT_SIZE = 1024


def _monotone_curve(points):
    pts = np.asarray(points, dtype=np.float64)
    from scipy.interpolate import PchipInterpolator  # here, not at import: scipy.interpolate adds ~1 s to start-up

    spline = PchipInterpolator(pts[:, 0], pts[:, 1], extrapolate=False)
    return lambda x: np.where(x <= pts[0, 0], pts[0, 1], np.where(x >= pts[-1, 0], pts[-1, 1], spline(x)))


@functools.lru_cache(maxsize=16)
def _grade_lut(key: str) -> np.ndarray:
    p = ColorGrade.model_validate_json(key)
    x = np.linspace(0.0, 1.0, LUT_SIZE)
    master = _monotone_curve(p.curve)
    lut = np.empty((LUT_SIZE, 3), np.float32)
    for c, own in enumerate((p.curve_r, p.curve_g, p.curve_b)):
        y = np.clip(x + p.lift[c] * (1.0 - x), 0.0, None) ** (1.0 / p.gamma[c]) * p.gain[c]
        y = np.clip(y, 0.0, 1.0)
        with np.errstate(divide="ignore"):
            a, b = y**p.contrast, (1.0 - y) ** p.contrast
        y = np.where(a + b > 0, a / np.maximum(a + b, 1e-300), 0.0)
        y = master(y)
        if own is not None:
            y = _monotone_curve(own)(y)
        lut[:, c] = np.clip(y, 0.0, 1.0)
    lut.setflags(write=False)
    return lut


def grade_lut(p: ColorGrade) -> np.ndarray:
    """(LUT_SIZE, 3) float32: the per-channel part of the grade sampled on [0, 1]."""
    return _grade_lut(p.model_dump_json())  # lists make the model unhashable: cache on its JSON


@njit(cache=True, inline="always")
def grade_pixel(r0, g0, b0, lut, saturation, l0, l1, l2):
    """One pixel: the per-channel LUT (linear interpolation), then saturation about luma, in float64."""
    n = lut.shape[0]
    f0 = min(max(np.float64(r0), 0.0), 1.0) * (n - 1)
    f1 = min(max(np.float64(g0), 0.0), 1.0) * (n - 1)
    f2 = min(max(np.float64(b0), 0.0), 1.0) * (n - 1)
    k0, k1, k2 = min(int(f0), n - 2), min(int(f1), n - 2), min(int(f2), n - 2)
    r = lut[k0, 0] + (f0 - k0) * (lut[k0 + 1, 0] - lut[k0, 0])
    g = lut[k1, 1] + (f1 - k1) * (lut[k1 + 1, 1] - lut[k1, 1])
    b = lut[k2, 2] + (f2 - k2) * (lut[k2 + 1, 2] - lut[k2, 2])
    luma = l0 * r + l1 * g + l2 * b
    return (min(max(luma + saturation * (r - luma), 0.0), 1.0), min(max(luma + saturation * (g - luma), 0.0), 1.0),
            min(max(luma + saturation * (b - luma), 0.0), 1.0))


@njit(cache=True, parallel=True)
def _grade_kernel(img, lut, saturation, l0, l1, l2):
    h, w, _ = img.shape
    out = np.empty_like(img)
    for j in prange(h):
        for i in range(w):
            r, g, b = grade_pixel(img[j, i, 0], img[j, i, 1], img[j, i, 2], lut, saturation, l0, l1, l2)
            out[j, i, 0] = r
            out[j, i, 1] = g
            out[j, i, 2] = b
    return out


def color_grade(img: np.ndarray, p: ColorGrade) -> np.ndarray:
    """Grade display values in [0, 1]: the per-channel LUT (linear interpolation), then saturation."""
    return _grade_kernel(np.ascontiguousarray(img, dtype=np.float32), grade_lut(p), float(p.saturation), *LUMA)


GLSL = """uniform sampler2D cg_lut;
uniform float cg_saturation;
uniform vec3 cg_luma;
// cg_lut: row c holds channel c, texel k the entries k and k + 1 (one fetch per channel, not two)
float lookup(float x, int c) {
  int n = textureSize(cg_lut, 0).x;
  float f = clamp(x, 0.0, 1.0) * float(n - 1);
  int k = min(int(f), n - 2);
  vec2 ab = texture(cg_lut, vec2((float(k) + 0.5) / float(n), (float(c) + 0.5) / 3.0)).rg;  // texel (k, c) at its centre
  return ab.x + (f - float(k)) * (ab.y - ab.x);
}
vec3 fx_color_grade(vec3 x, ivec2 p, ivec2 size) {
  vec3 y = vec3(lookup(x.r, 0), lookup(x.g, 1), lookup(x.b, 2));
  float l = dot(cg_luma, y);
  return clamp(vec3(l) + cg_saturation * (y - vec3(l)), 0.0, 1.0);
}
"""


def lut_pairs(lut: np.ndarray) -> np.ndarray:
    """(3, n, 2) float32: row c, texel k = (lut[k, c], lut[k + 1, c]) (the last texel repeats its entry), so
    that the shader's linear interpolation reads one texel per channel."""
    pairs = np.empty((3, lut.shape[0], 2), np.float32)
    pairs[:, :, 0] = lut.T
    pairs[:, :-1, 1] = lut[1:].T
    pairs[:, -1, 1] = lut[-1]
    return pairs


def bind(ctx, p: ColorGrade, width: int, height: int, seed: int) -> tuple[dict, dict]:
    return ({"cg_lut": ctx.upload_into("cg_lut", lut_pairs(grade_lut(p)))},
            {"cg_saturation": float(p.saturation), "cg_luma": LUMA})


EFFECT = Effect("color_grade", ColorGrade, image_only(color_grade), pointwise=Pointwise(GLSL, bind))
