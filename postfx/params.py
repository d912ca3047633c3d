"""Parameters of every post-effect, validated (unknown keys, wrong types and out-of-range values are
errors). The scene's ``[effects.NAME]`` tables are read into these models."""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator


class EffectParams(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


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


class DepthOfField(EffectParams):
    """Thin-lens depth of field: circle of confusion from depth, gathered with a disc kernel.

    CoC diameter on the sensor ``c = 2 A f |d - d_f| / (d (d_f - f))`` for aperture radius A, focal
    length f, focus distance d_f and depth d; in pixels ``c W / (2 f tan(fov/2))``.
    """

    focus_distance: Annotated[float, Field(gt=0.0, le=1e5, description="in-focus distance [m]")] = 0.1
    aperture: Annotated[float, Field(ge=0.0, le=1.0, description="aperture radius [m]")] = 0.001
    focal_length: Annotated[float, Field(gt=0.0, le=1.0, description="lens focal length [m]")] = 0.004
    max_radius_px: Annotated[float, Field(ge=0.0, le=64.0, description="largest blur radius [px]")] = 12.0


class LaparoscopeMask(EffectParams):
    """Circular scope aperture with a soft edge and a radial vignette.

    Radii are fractions of half the image height; ``offset`` moves the circle's centre by fractions of
    the width and height (an off-centre scope).
    """

    radius: Annotated[float, Field(gt=0.0, le=4.0)] = 0.95
    softness: Annotated[float, Field(ge=0.0, le=2.0)] = 0.04
    vignette: Annotated[float, Field(ge=0.0, le=1.0, description="darkening at the rim")] = 0.35
    offset: Annotated[list[Annotated[float, Field(ge=-1.0, le=1.0)]], Field(min_length=2, max_length=2)] = [0.0, 0.0]


class Tonemap(EffectParams):
    """Exposure, a filmic tone curve and the sRGB display encoding (linear HDR in, display out)."""

    exposure: Annotated[float, Field(ge=-20.0, le=20.0, description="exposure [stops]")] = 0.0
    curve: Literal["aces", "reinhard", "clamp"] = "aces"
    srgb: bool = True


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


class Blur(EffectParams):
    """Gaussian blur of standard deviation ``sigma_px`` pixels (separable, edges clamped)."""

    sigma_px: Annotated[float, Field(gt=0.0, le=16.0)] = 1.0


class Sharpen(EffectParams):
    """Unsharp mask on display values: ``x + amount (x - blur_sigma(x))``, clipped to [0, 1]."""

    amount: Annotated[float, Field(ge=0.0, le=5.0)] = 0.5
    sigma_px: Annotated[float, Field(gt=0.0, le=8.0)] = 1.0


class Bloom(EffectParams):
    """Glow around HDR highlights: the part of each pixel above ``threshold`` (in luminance, scene-linear)
    is blurred by ``sigma_px`` and added back times ``intensity``."""

    threshold: Annotated[float, Field(ge=0.0, le=1e6)] = 1.0
    intensity: Annotated[float, Field(ge=0.0, le=10.0)] = 0.3
    sigma_px: Annotated[float, Field(gt=0.0, le=16.0)] = 6.0


class SensorNoise(EffectParams):
    """Seeded sensor noise on linear values: Gaussian with variance ``shot x + read^2`` (shot noise
    proportional to the signal, read noise constant), deterministic for the frame's seed."""

    shot: Annotated[float, Field(ge=0.0, le=1.0)] = 0.002
    read: Annotated[float, Field(ge=0.0, le=1.0)] = 0.003


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


EFFECTS: dict[str, type[EffectParams]] = {
    "depth_of_field": DepthOfField,
    "chromatic_aberration": ChromaticAberration,
    "tonemap": Tonemap,
    "color_grade": ColorGrade,
    "blur": Blur,
    "sharpen": Sharpen,
    "bloom": Bloom,
    "lens_flare": LensFlare,
    "sensor_noise": SensorNoise,
    "laparoscope_mask": LaparoscopeMask,
}
