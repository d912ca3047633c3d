"""A chain of effects on the GL side: one upload, the passes queued without waiting, one read-back.

A chain stays on the GL side: the HDR frame is uploaded once (or, when the depth of field comes first,
the DoF's padded source built from it on the CPU), each effect draws its passes from texture to
texture (targets come from a pool), and the result is read back once. OSMesa is llvmpipe, software
GL, where a texel fetch costs about as much as a numba tap, so the passes also do less work: bloom
and lens flare run at half resolution, bilinear reads use the sampler's filter, the Gaussian weights
are uniforms, the noise is drawn in the shader from a counter-based generator instead of being
uploaded, the depth of field gathers for blocks of outputs per fetched texel within a per-tile bound
and writes them with imageStore, and a run of pointwise effects (noise, tone map, grade, mask) is
applied in the last pass of the effect before it.
"""
from __future__ import annotations

import time

import numpy as np

from postfx.effect import GLFrame
from postfx.gl.context import Context
from postfx.gl.shaders import Epilogue
from postfx.registry import POINTWISE, effect


def bind_epilogue(ctx: Context, run, width: int, height: int, seed: int) -> Epilogue:
    """The pointwise effects ``run`` (a list of ``(name, params)``) bound for a pass of that size."""
    ep = Epilogue()
    for name, params in run:
        pointwise = effect(name).pointwise
        if pointwise is None:
            raise KeyError(f"{name!r} is not a pointwise effect")
        ep.add(name, pointwise.glsl, *pointwise.bind(ctx, params, width, height, seed))
    return ep


def takes_rows(name: str, params) -> bool:
    """Whether the effect ``name`` reads a row-blocked image in place (a blur or sharpen whose radius is at
    most GAUSS_PLAIN_V; the unsharp mask's own fetch of it too)."""
    reads_rows = effect(name).reads_rows
    return reads_rows is not None and reads_rows(params)


def effect_on_gpu(ctx: Context, name: str, tex, depth: np.ndarray, params, lens, seed: int = 0, epilogue=(),
                  host=None, rows_out=False):
    """One effect from texture to texture (the input stays valid; the caller releases it), followed by
    the pointwise effects ``epilogue`` (a list of ``(name, params)``) drawn in its last pass. ``tex`` may
    be None for the depth of field, which then reads the frame ``host`` from the CPU. ``rows_out``: a
    blur or sharpen may leave its result row-blocked (``gl.gaussian``); only ``takes_rows`` effects and
    ``Context.download`` read such a texture."""
    fx = effect(name)
    if tex is not None and id(tex) in ctx.row_blocked and not takes_rows(name, params):
        raise ValueError(f"{name} cannot read a row-blocked image")
    w, h = host.shape[1::-1] if tex is None else (tex.GetWidth(), tex.GetHeight())
    if fx.pointwise is not None:  # a run of pointwise effects: one pass
        ep = bind_epilogue(ctx, [(name, params), *epilogue], w, h, seed)
        return ctx.draw("pointwise", {"img": tex, **ep.inputs}, ep.uniforms, w, h, epilogue=ep.passes)
    ep = bind_epilogue(ctx, epilogue, w, h, seed)
    return fx.draw(ctx, tex, params, ep, GLFrame(depth, lens, seed, host, rows_out))


def fused_groups(chain, fuse: bool = True):
    """The chain cut into passes: each effect with the run of pointwise effects that follows it (they
    are drawn in its last pass, each at most once: their uniforms have one name per effect); one
    effect per group without ``fuse``."""
    groups = []
    for name, params in chain:
        if fuse and groups and name in POINTWISE and name not in {n for n, _ in groups[-1]}:
            groups[-1].append((name, params))
        else:
            groups.append([(name, params)])
    return groups


def run_chain(hdr: np.ndarray, depth: np.ndarray, chain, lens, seed: int = 0, fuse: bool = True, clip: bool = False):
    """The whole chain on the GL side: one upload, one read-back. Returns the image (clipped to [0, 1]
    with ``clip``, as ``postfx.apply_chain`` returns it), the seconds of each group of fused effects
    (keyed by the effect's name, or by the names joined with "+" when pointwise effects were drawn in
    its last pass) and the total seconds including the transfers.

    The passes are queued without waiting for each other: llvmpipe's threads go from one pass to the
    next while this thread prepares the ones after, instead of sleeping after every effect. An
    effect's seconds come from GL timestamps: from the end of the effect before it (for the first, from
    the chain's start on the CPU, after the frame's upload, when llvmpipe's clock is the monotonic one;
    a DoF that comes first builds and uploads its own source, which counts) to the end of its own last
    pass."""
    ctx = Context.get()
    start = time.perf_counter()
    groups = fused_groups(chain, fuse)
    # a depth of field first builds its source from the frame on the CPU: no upload of the frame itself
    tex = None if groups and groups[0][0][0] == "depth_of_field" else ctx.upload_into("frame", hdr)
    uploaded = tex
    effects_ns = time.monotonic_ns()  # the first effect's time starts after the frame's upload
    if not ctx.shared_clock:
        ctx.timestamp(len(groups))
    keys = []
    for i, group in enumerate(groups):
        (name, params), rest = group[0], group[1:]
        # row-blocked output for the read-back or for the next Gaussian (its passes read it in place)
        rows_out = i == len(groups) - 1 or takes_rows(*groups[i + 1][0])
        out = effect_on_gpu(ctx, name, tex, depth, params, lens, seed, epilogue=rest, host=hdr, rows_out=rows_out)
        ctx.timestamp(i)
        keys.append("+".join(n for n, _ in group))
        if tex is not uploaded:
            ctx.release(tex)
        tex = out
    image = ctx.download(tex, clip)
    if tex is not uploaded:
        ctx.release(tex)
    stamps = ctx.timestamps(len(groups) + (not ctx.shared_clock))
    previous = effects_ns if ctx.shared_clock else stamps[-1]
    seconds = {}
    for key, stamp in zip(keys, stamps):
        seconds[key] = max(stamp - previous, 0) * 1e-9
        previous = stamp
    return image, seconds, time.perf_counter() - start


def apply_effect(name: str, img: np.ndarray, depth: np.ndarray, params, lens, seed: int = 0) -> np.ndarray:
    """One effect with upload and read-back; same signature and meaning as :func:`postfx.apply_effect`."""
    return run_chain(img, depth, [(name, params)], lens, seed)[0]
