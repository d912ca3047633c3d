"""Blur: a Gaussian of standard deviation ``sigma_px`` (separable, edges clamped).

| name | default | unit | range | equation |
|---|---|---|---|---|
| `sigma_px` | 1 | px | (0, 16] | `y(p) = sum_k w_k x(p + k)`, `w_k ∝ exp(-k^2 / (2 sigma^2))` for abs(k) <= ceil(3 sigma), normalised; per axis |
"""
from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from postfx.effect import Effect, EffectParams, image_only
from postfx.gaussian import gaussian_blur
from postfx.gl import gaussian as gl_gaussian


class Blur(EffectParams):
    """Gaussian blur of standard deviation ``sigma_px`` pixels (separable, edges clamped)."""

    sigma_px: Annotated[float, Field(gt=0.0, le=16.0)] = 1.0


def blur(img: np.ndarray, p: Blur) -> np.ndarray:
    return gaussian_blur(img, p.sigma_px)


def draw(ctx, tex, p: Blur, ep, frame):
    return gl_gaussian.gaussian(ctx, tex, p.sigma_px, epilogue=ep, rows_out=frame.rows_out)


EFFECT = Effect("blur", Blur, image_only(blur), draw, reads_rows=lambda p: gl_gaussian.reads_rows(p.sigma_px))
