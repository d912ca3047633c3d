"""Sharpen: the camera's unsharp mask on display values.

| name | default | unit | range | equation |
|---|---|---|---|---|
| `amount` | 0.5 | - | [0, 5] | `y = x + amount (x - G_sigma * x)`, clipped to [0, 1] |
| `sigma_px` | 1 | px | (0, 8] | standard deviation of the Gaussian `G_sigma` (as `blur`) |
"""
from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from postfx.effect import Effect, EffectParams, image_only
from postfx.gaussian import unsharp_mask
from postfx.gl import gaussian as gl_gaussian


class Sharpen(EffectParams):
    """Unsharp mask on display values: ``x + amount (x - blur_sigma(x))``, clipped to [0, 1]."""

    amount: Annotated[float, Field(ge=0.0, le=5.0)] = 0.5
    sigma_px: Annotated[float, Field(gt=0.0, le=8.0)] = 1.0


def sharpen(img: np.ndarray, p: Sharpen) -> np.ndarray:
    """Unsharp mask ``x + amount (x - blur_sigma(x))`` clipped to [0, 1]."""
    return unsharp_mask(img, p.sigma_px, p.amount)


def draw(ctx, tex, p: Sharpen, ep, frame):
    return gl_gaussian.gaussian(ctx, tex, p.sigma_px, orig=tex, amount=p.amount, epilogue=ep,
                                rows_out=frame.rows_out)


EFFECT = Effect("sharpen", Sharpen, image_only(sharpen), draw, reads_rows=lambda p: gl_gaussian.reads_rows(p.sigma_px))
