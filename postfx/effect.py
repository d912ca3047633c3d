"""What every post-effect module provides: its validated parameters (``EffectParams``: unknown keys,
wrong types and out-of-range values are errors; the scene's ``[effects.NAME]`` tables are read into
them), and its ``Effect`` record, which the registry lists: the NumPy reference and the GL recipe."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from pydantic import BaseModel, ConfigDict


class EffectParams(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


@dataclass(frozen=True)
class Lens:
    """What the lens effects need to turn metres into pixels: horizontal field of view and size."""

    fov_deg: float
    width: int
    height: int


@dataclass(frozen=True)
class GLFrame:
    """What an effect's GL recipe gets besides its input texture and parameters: the depth map, the lens,
    the frame's seed, the frame on the CPU (``host``, read by a depth of field that comes first: its
    input texture is then None) and ``rows_out`` (a Gaussian may leave its result row-blocked, see
    ``postfx.gl.gaussian``)."""

    depth: np.ndarray | None
    lens: Lens
    seed: int
    host: np.ndarray | None
    rows_out: bool


@dataclass(frozen=True)
class Pointwise:
    """The GL side of a pointwise effect (each output pixel depends only on the same input pixel): a GLSL
    function ``vec3 fx_<name>(vec3 x, ivec2 p, ivec2 size)`` with its uniform declarations, drawn inside
    the last pass of the effect before it, and ``bind(ctx, params, width, height, seed)`` -> (textures,
    uniforms) of that function."""

    glsl: str
    bind: Callable[..., tuple[dict, dict]]


@dataclass(frozen=True)
class Effect:
    """One post-effect as the registry lists it.

    ``reference(img, depth, params, lens, seed)``: the NumPy backend. ``draw(ctx, tex, params, ep,
    frame)``: the GL recipe, from the texture ``tex`` into a new target, the pointwise epilogue ``ep``
    (``postfx.gl.shaders.Epilogue``) drawn in its last pass; None for pointwise effects, which are drawn
    as ``pointwise``. ``reads_rows(params)``: whether its passes read a row-blocked image in place."""

    name: str
    params: type[EffectParams]
    reference: Callable[..., np.ndarray]
    draw: Callable[..., Any] | None = None
    pointwise: Pointwise | None = None
    reads_rows: Callable[[Any], bool] | None = None


def image_only(function: Callable[[np.ndarray, Any], np.ndarray]) -> Callable[..., np.ndarray]:
    """``reference`` of an effect that needs only the image and its parameters."""

    def reference(img, depth, params, lens, seed):
        return function(img, params)

    return reference
