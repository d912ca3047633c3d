"""Run a chain of post-effects on a linear HDR frame with either backend: ``numpy`` (the reference,
``postfx.registry`` effects' ``reference``) or ``osmesa`` (GLSL passes through an off-screen OpenGL
context, ``postfx.gl``); ``auto`` takes osmesa where it can run. Both give the same pixels to float32
rounding (docs/postfx.md, "Backends").

Only the effects listed in the chain run, in its order.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from postfx.effect import EffectParams, Lens
from postfx.errors import OSMesaUnavailable, check_output
from postfx.gl import chain as gl_chain
from postfx.gl.context import Context
from postfx.pointwise import POINTWISE, pointwise_chain
from postfx.registry import effect


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


def apply_effect(name: str, img: np.ndarray, depth: np.ndarray, params: EffectParams, lens: Lens,
                 seed: int = 0) -> np.ndarray:
    """One effect with the NumPy reference backend."""
    return effect(name).reference(img, depth, params, lens, seed)


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
        Context.get()  # raises OSMesaUnavailable naming libosmesa6 when it cannot run
        img, groups, total = gl_chain.run_chain(img, depth, chain, lens, seed, clip=True)  # one upload, one read-back
        check_output(None, img)  # the GL side runs the chain in one go: no effect to name
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
        if rest:  # consecutive pointwise effects: one pass, the same result (pointwise.pointwise_chain)
            img = pointwise_chain(img, run, seed)
            fused[name] = [n for n, _ in rest]
        else:
            img = apply_effect(name, img, depth, params, lens, seed).astype(np.float32, copy=False)
        seconds[name] = time.perf_counter() - start
        check_output("+".join(n for n, _ in run), img)  # a fused run of pointwise effects cannot be split
    return ChainResult(np.clip(img, 0.0, 1.0), seconds, used, time.perf_counter() - begin, fused)


def _pointwise_runs(chain):
    """The chain cut into runs: consecutive pointwise effects (at most one of each) together, every
    other effect alone."""
    runs: list = []
    for name, params in chain:
        last = runs[-1] if runs else None
        if (last is not None and name in POINTWISE and last[0][0] in POINTWISE
                and name not in {n for n, _ in last}):
            last.append((name, params))
        else:
            runs.append([(name, params)])
    return runs


def osmesa_problem() -> str | None:
    """Why the OSMesa backend cannot run here (libOSMesa missing, VTK without its off-screen window, no
    context), or None when it can."""
    try:
        Context.get()
    except OSMesaUnavailable as e:
        return str(e)
    return None


def osmesa_available() -> bool:
    """True when the OSMesa backend can run here (libOSMesa loads and a context can be created)."""
    return osmesa_problem() is None


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Display values in [0, 1] -> 8-bit (round to nearest). Refuses non-finite values
    (:class:`~postfx.errors.NonFiniteOutput`): a cast would write NaN as black."""
    check_output("to_uint8", image)
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
