"""Every post-effect, in the default order, with its parameters; the camera presets.

Default order (``DEFAULT_ORDER``): depth of field, chromatic aberration, lens flare, bloom and blur act on
scene-linear HDR light, as the lens does; sensor noise is added to the linear signal, as the sensor
does; the tone map then turns light into display values, which the colour grade shapes (curves are
edited on display values, as in a grading tool), then the camera's sharpening; the mask comes last so
its black surround stays black and its soft edge has the same profile at every exposure. Qian's
profiles put CA with the tone map and the mask last; we keep the mask last and move the lens effects
before the tone map, where they are physical.

Adding an effect: a module with its parameters, NumPy reference and GL recipe ending in an ``EFFECT``
record (``postfx.effect.Effect``), and one line below. The scene schema composes its ``[effects.NAME]``
tables from ``EFFECTS``.
"""
from __future__ import annotations

from postfx import (bloom, blur, chromatic_aberration, color_grade, depth_of_field, laparoscope_mask, lens_flare,
                    sensor_noise, sharpen, tonemap)
from postfx.effect import Effect, EffectParams

REGISTRY: dict[str, Effect] = {module.EFFECT.name: module.EFFECT for module in (
    depth_of_field,
    chromatic_aberration,
    lens_flare,
    bloom,
    blur,
    sensor_noise,
    tonemap,
    color_grade,
    sharpen,
    laparoscope_mask,
)}

DEFAULT_ORDER: list[str] = list(REGISTRY)
EFFECTS: dict[str, type[EffectParams]] = {name: effect.params for name, effect in REGISTRY.items()}
POINTWISE: tuple[str, ...] = tuple(name for name, effect in REGISTRY.items() if effect.pointwise is not None)

# Named camera signatures: (effect, parameters) in order.
CAMERA_PRESETS: dict[str, list[tuple[str, dict]]] = {
    "hd_scope": [
        ("chromatic_aberration", {"strength_r": 0.002, "strength_b": -0.002}),
        ("tonemap", {"exposure": 0.0, "curve": "aces"}),
        ("laparoscope_mask", {"radius": 1.15, "softness": 0.05, "vignette": 0.25}),
    ],
    "old_scope": [
        ("chromatic_aberration", {"strength_r": 0.008, "strength_b": -0.008}),
        ("tonemap", {"exposure": 0.3, "curve": "reinhard"}),
        ("sensor_noise", {"shot": 0.004, "read": 0.006}),
        ("color_grade", {"lift": [0.03, 0.02, 0.0], "gain": [1.0, 0.96, 0.88], "contrast": 1.25,
                         "saturation": 0.8}),
        ("laparoscope_mask", {"radius": 0.9, "softness": 0.08, "vignette": 0.55}),
    ],
}


def effect(name: str) -> Effect:
    """The effect ``name``; a KeyError naming the known ones otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown post-effect {name!r}; expected one of {', '.join(REGISTRY)}") from None
