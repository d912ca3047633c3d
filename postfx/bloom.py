"""Bloom: glow around HDR highlights, at half resolution (a low-frequency effect).

| name | default | unit | range | equation |
|---|---|---|---|---|
| `threshold` | 1 | scene-linear luminance | [0, 1e6] | bright part `b = x max(l - threshold, 0) / l`, l the Rec. 709 luma |
| `intensity` | 0.3 | - | [0, 10] | `y = x + intensity up(G * half(b))` |
| `sigma_px` | 6 | full-res px | (0, 16] | Gaussian G of `sigma_px / 2` half-res pixels |

``half``: the 2x2 block mean; ``up``: bilinear upsampling.
"""
from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from postfx.effect import Effect, EffectParams, image_only
from postfx.gaussian import gaussian_blur
from postfx.gl import gaussian as gl_gaussian
from postfx.gl import halfres
from postfx.kernels import add_upsampled, bright_half


class Bloom(EffectParams):
    """Glow around HDR highlights: the part of each pixel above ``threshold`` (in luminance, scene-linear)
    is blurred by ``sigma_px`` and added back times ``intensity``."""

    threshold: Annotated[float, Field(ge=0.0, le=1e6)] = 1.0
    intensity: Annotated[float, Field(ge=0.0, le=10.0)] = 0.3
    sigma_px: Annotated[float, Field(gt=0.0, le=16.0)] = 6.0


def bloom(img: np.ndarray, p: Bloom) -> np.ndarray:
    """Glow at half resolution (a low-frequency effect): the bright part averaged over 2x2 blocks,
    blurred by ``sigma_px / 2`` half-res pixels, upsampled bilinearly and added times ``intensity``."""
    low = gaussian_blur(bright_half(img, p.threshold), 0.5 * p.sigma_px)
    return add_upsampled(img, low, p.intensity)


def draw(ctx, tex, p: Bloom, ep, frame):
    half = halfres.half(ctx, tex, p.threshold)
    low = gl_gaussian.gaussian(ctx, half, 0.5 * p.sigma_px)
    ctx.release(half)
    return halfres.add_upsampled(ctx, tex, low, p.intensity, ep)


EFFECT = Effect("bloom", Bloom, image_only(bloom), draw)
