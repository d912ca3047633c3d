"""Laparoscope mask: the circular scope aperture with a soft edge and a radial vignette.

| name | default | unit | range | equation |
|---|---|---|---|---|
| `radius` | 0.95 | half image heights | (0, 4] | `rho = length(p - c) / (H / 2)`; inside for `rho <= radius` |
| `softness` | 0.04 | half image heights | [0, 2] | edge `1 - smoothstep(radius - s/2, radius + s/2, rho)` (a step at 0) |
| `vignette` | 0.35 | - | [0, 1] | weight `edge (1 - vignette min(rho / radius, 1)^2)` |
| `offset` | [0, 0] | fractions of W, H | each [-1, 1] | centre `c = (W (1/2 + offset_x), H (1/2 + offset_y))` |

Pointwise: the image times the weight. It comes last in the default order, so the black surround
stays black and the edge has the same profile at every exposure.
"""
from __future__ import annotations

import functools
from typing import Annotated

import numpy as np
from pydantic import Field

from postfx.effect import Effect, EffectParams, Pointwise, image_only


class LaparoscopeMask(EffectParams):
    """Circular scope aperture with a soft edge and a radial vignette.

    Radii are fractions of half the image height; ``offset`` moves the circle's centre by fractions of
    the width and height (an off-centre scope).
    """

    radius: Annotated[float, Field(gt=0.0, le=4.0)] = 0.95
    softness: Annotated[float, Field(ge=0.0, le=2.0)] = 0.04
    vignette: Annotated[float, Field(ge=0.0, le=1.0, description="darkening at the rim")] = 0.35
    offset: Annotated[list[Annotated[float, Field(ge=-1.0, le=1.0)]], Field(min_length=2, max_length=2)] = [0.0, 0.0]


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / np.maximum(e1 - e0, 1e-12), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def mask_weights(h: int, w: int, p: LaparoscopeMask) -> np.ndarray:
    """(H, W) float32 weights: 1 inside the scope circle, 0 outside, a smoothstep edge of width
    ``softness`` centred on ``radius``, times the vignette ``1 - vignette (rho / radius)^2``."""
    return _mask_weights(h, w, p.radius, p.softness, p.vignette, p.offset[0], p.offset[1])


@functools.lru_cache(maxsize=8)
def _mask_weights(h, w, radius, softness, vignette, off_x, off_y) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    cx, cy = w * (0.5 + off_x), h * (0.5 + off_y)
    rho = np.hypot(x - cx, y - cy) / (0.5 * h)
    if softness == 0.0:
        edge = (rho <= radius).astype(np.float64)
    else:
        edge = 1.0 - smoothstep(radius - 0.5 * softness, radius + 0.5 * softness, rho)
    weights = (edge * (1.0 - vignette * np.clip(rho / radius, 0.0, 1.0) ** 2)).astype(np.float32)
    weights.setflags(write=False)
    return weights


def laparoscope_mask(img: np.ndarray, p: LaparoscopeMask) -> np.ndarray:
    return img * mask_weights(img.shape[0], img.shape[1], p)[..., None]  # weights cached per size and params


GLSL = """uniform vec2 mask_centre;
uniform float mask_radius;
uniform float mask_softness;
uniform float mask_vignette;
vec3 fx_laparoscope_mask(vec3 x, ivec2 p, ivec2 size) {
  float rho = length(vec2(float(p.x) + 0.5 - mask_centre.x, float(p.y) + 0.5 - mask_centre.y)) / (0.5 * float(size.y));
  float edge;
  if (mask_softness == 0.0) edge = rho <= mask_radius ? 1.0 : 0.0;
  else {
    float t = clamp((rho - (mask_radius - 0.5 * mask_softness)) / mask_softness, 0.0, 1.0);
    edge = 1.0 - t * t * (3.0 - 2.0 * t);
  }
  float r = clamp(rho / mask_radius, 0.0, 1.0);
  return x * (edge * (1.0 - mask_vignette * r * r));
}
"""


def bind(ctx, p: LaparoscopeMask, width: int, height: int, seed: int) -> tuple[dict, dict]:
    return {}, {"mask_centre": (width * (0.5 + p.offset[0]), height * (0.5 + p.offset[1])),
                "mask_radius": p.radius, "mask_softness": p.softness, "mask_vignette": p.vignette}


EFFECT = Effect("laparoscope_mask", LaparoscopeMask, image_only(laparoscope_mask), pointwise=Pointwise(GLSL, bind))
