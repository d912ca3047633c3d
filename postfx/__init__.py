"""Post-effects of the laparoscope camera (Qian §6.3.3): depth of field, chromatic aberration, tone
mapping with sRGB encoding, and the circular scope mask.

Default order (``DEFAULT_ORDER``): depth of field, chromatic aberration, lens flare, bloom and blur
act on scene-linear HDR light, as the lens does; sensor noise is added to the linear signal, as the sensor
does; the tone map then turns light into display values, which the colour grade
shapes (curves are edited on display values, as in a grading tool), then the camera's sharpening; the
mask comes last so
its black surround stays black and its soft edge has the same profile at every exposure. Qian's
profiles put CA with the tone map and the mask last; we keep the mask last and move the lens
effects before the tone map, where they are physical.

Only the effects listed in the scene's ``[effects]`` table run, in order.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from postfx import effects
from postfx import lens_flare as _flare
from postfx.params import EFFECTS, EffectParams

DEFAULT_ORDER = ["depth_of_field", "chromatic_aberration", "lens_flare", "bloom", "blur", "sensor_noise", "tonemap", "color_grade",
                 "sharpen", "laparoscope_mask"]

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


class OSMesaUnavailable(RuntimeError):
    """The off-screen OpenGL backend cannot run here (message names what to install)."""


@dataclass(frozen=True)
class Lens:
    """What the lens effects need to turn metres into pixels: horizontal field of view and size."""

    fov_deg: float
    width: int
    height: int


@dataclass
class ChainResult:
    image: np.ndarray
    seconds: dict = field(default_factory=dict)  # per effect (see fused)
    backend_used: str = "numpy"
    total_seconds: float = 0.0  # the whole chain, with the osmesa upload and read-back
    # pointwise effects (noise, tone map, grade, mask) run fused: osmesa draws a run of them in the last
    # pass of the effect before them, numpy applies consecutive ones in one pass. fused[name] lists
    # the effects run with ``name``: seconds[name] includes their time, they have no entry of their own
    fused: dict = field(default_factory=dict)


# effects that need only the image and their parameters
_IMAGE_ONLY = {name: getattr(effects, name) for name in ("chromatic_aberration", "tonemap", "laparoscope_mask",
                                                         "color_grade", "blur", "sharpen", "bloom")}
_IMAGE_ONLY["lens_flare"] = _flare.lens_flare


def apply_effect(name: str, img: np.ndarray, depth: np.ndarray, params: EffectParams, lens: Lens,
                 seed: int = 0) -> np.ndarray:
    """One effect with the NumPy reference backend (``postfx.effects``, ``postfx.lens_flare``)."""
    if name in _IMAGE_ONLY:
        return _IMAGE_ONLY[name](img, params)
    if name == "depth_of_field":
        return effects.depth_of_field(img, depth, params, lens.fov_deg)
    if name == "sensor_noise":
        return effects.sensor_noise(img, params, seed)
    raise KeyError(f"unknown post-effect {name!r}; expected one of {', '.join(EFFECTS)}")


def apply_chain(hdr: np.ndarray, depth: np.ndarray, chain, lens: Lens, backend: str = "auto",
                seed: int = 0) -> ChainResult:
    """Run ``chain`` (a list of ``(name, params)``) on a linear HDR image; returns display values.

    Without a tone map in the chain the result is the linear image clipped to [0, 1].
    """
    if backend not in ("auto", "numpy", "osmesa"):
        raise ValueError(f"unknown backend {backend!r}; expected auto, numpy or osmesa")
    used = backend
    if backend == "auto":
        used = "osmesa" if osmesa_available() else "numpy"
    img = np.ascontiguousarray(hdr, dtype=np.float32)
    if used == "osmesa":
        from postfx import osmesa

        osmesa.Context.get()  # raises OSMesaUnavailable naming libosmesa6 when it cannot run
        img, groups, total = osmesa.run_chain(img, depth, chain, lens, seed, clip=True)  # one upload, one read-back
        seconds, fused = {}, {}
        for key, value in groups.items():
            first, *rest = key.split("+")
            seconds[first] = value
            if rest:
                fused[first] = rest
        return ChainResult(img, seconds, used, total, fused)
    seconds, fused = {}, {}
    begin = time.perf_counter()
    for run in _pointwise_runs(chain):
        (name, params), rest = run[0], run[1:]
        start = time.perf_counter()
        if rest:  # consecutive pointwise effects: one pass, the same result (effects.pointwise_chain)
            img = effects.pointwise_chain(img, run, seed)
            fused[name] = [n for n, _ in rest]
        else:
            img = apply_effect(name, img, depth, params, lens, seed).astype(np.float32, copy=False)
        seconds[name] = time.perf_counter() - start
    return ChainResult(np.clip(img, 0.0, 1.0), seconds, used, time.perf_counter() - begin, fused)


def _pointwise_runs(chain):
    """The chain cut into runs: consecutive pointwise effects (at most one of each) together, every
    other effect alone."""
    runs: list = []
    for name, params in chain:
        last = runs[-1] if runs else None
        if (last is not None and name in effects.POINTWISE and last[0][0] in effects.POINTWISE
                and name not in {n for n, _ in last}):
            last.append((name, params))
        else:
            runs.append([(name, params)])
    return runs


def osmesa_available() -> bool:
    """True when the OSMesa backend can run here (libOSMesa loads and a context can be created)."""
    from postfx import osmesa

    if not osmesa.library_available():
        return False
    try:
        osmesa.Context.get()
    except OSMesaUnavailable:
        return False
    return True


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Display values in [0, 1] -> 8-bit (round to nearest)."""
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


__all__ = ["EFFECTS", "DEFAULT_ORDER", "CAMERA_PRESETS", "Lens", "apply_chain", "to_uint8", "OSMesaUnavailable"]
