"""Post-effects of the laparoscope camera (Qian §6.3.3): depth of field, chromatic aberration, lens flare,
bloom, blur, sensor noise, tone mapping with sRGB encoding, colour grading, sharpening and the circular
scope mask, each in its own module (parameters, NumPy reference, GL recipe), listed in
``postfx.registry`` in the default order; ``postfx.chain`` runs them with the NumPy or the OSMesa
backend (``postfx.gl``).

Only the effects listed in the scene's ``[effects]`` table run, in order.
"""
from __future__ import annotations

from postfx.chain import ChainResult, apply_chain, apply_effect, osmesa_available, osmesa_problem, to_uint8
from postfx.effect import EffectParams, Lens
from postfx.errors import NonFiniteOutput, OSMesaUnavailable
from postfx.registry import CAMERA_PRESETS, DEFAULT_ORDER, EFFECTS, REGISTRY

__all__ = ["CAMERA_PRESETS", "DEFAULT_ORDER", "EFFECTS", "REGISTRY", "ChainResult", "EffectParams", "Lens",
           "NonFiniteOutput", "OSMesaUnavailable", "apply_chain", "apply_effect", "osmesa_available", "osmesa_problem",
           "to_uint8"]
