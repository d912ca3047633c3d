"""The OSMesa backend: every post-effect as GLSL fragment passes (``postfx.shaders``), rendered
off-screen through VTK's ``vtkOSOpenGLRenderWindow`` (the VTK wheel plus Debian ``libosmesa6``) into
float textures. No window and no X server. See ``../shared/notes/osmesa.md`` for the path used.

A chain stays on the GL side: the HDR frame is uploaded once, each effect draws its passes from
texture to texture (targets come from a pool), and the result is read back once. OSMesa is llvmpipe,
software GL, where a texel fetch costs about as much as a numba tap, so the passes also do less
work: bloom and lens flare run at half resolution, the Gaussian weights are uniforms, the noise is
drawn in the shader from a counter-based generator instead of being uploaded, the depth of field
gathers for blocks of 4 x 2 outputs per fetched texel within a per-tile bound, and a run of pointwise
effects (noise, tone map, grade, mask) is applied in the last pass of the effect before it.
"""
from __future__ import annotations

import ctypes
import math
import time

import numpy as np

from postfx import shaders
from postfx.shaders import DOF_BLOCK, DOF_TILE, GAUSS_BLOCK, MAX_TAPS, POINTWISE

GL_FLOAT = 0x1406
GL_RGBA = 0x1908
LIBRARIES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")


def library_available() -> bool:
    for name in LIBRARIES:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


class FloatArray(tuple):
    """A ``uniform float name[n]`` value."""


class Vec4Array(tuple):
    """A ``uniform vec4 name[n]`` value (flat, 4 floats per element)."""


class IVec2(tuple):
    """A ``uniform ivec2`` value."""


def _set_uniform(program, key, value):
    if isinstance(value, FloatArray):
        program.SetUniform1fv(key, len(value), [float(v) for v in value])
    elif isinstance(value, Vec4Array):
        program.SetUniform4fv(key, len(value) // 4, [float(v) for v in value])
    elif isinstance(value, IVec2):
        program.SetUniform2i(key, [int(v) for v in value])
    elif isinstance(value, (bool, int, np.integer)):
        program.SetUniformi(key, int(value))
    elif np.ndim(value) == 0:
        program.SetUniformf(key, float(value))
    elif len(value) == 2:
        program.SetUniform2f(key, [float(v) for v in value])
    else:
        program.SetUniform3f(key, [float(v) for v in value])


class Context:
    """One off-screen OpenGL context per process, created on first use and reused; draws full-screen
    passes between float textures."""

    _instance = None

    @classmethod
    def get(cls) -> "Context":
        if cls._instance is None:
            cls._instance = cls()
        return cls._instance

    def __init__(self):
        from postfx import OSMesaUnavailable

        # Without libOSMesa VTK only warns and the next GL call segfaults: check first.
        if not library_available():
            raise OSMesaUnavailable("libOSMesa is not installed; install the Debian package libosmesa6 "
                                    "(apt-get install libosmesa6) or use backend = \"numpy\"")
        from vtkmodules.vtkRenderingOpenGL2 import (vtkOpenGLFramebufferObject, vtkOpenGLRenderUtilities,
                                                    vtkOSOpenGLRenderWindow, vtkPixelBufferObject)

        self.window = vtkOSOpenGLRenderWindow()
        self.window.SetOffScreenRendering(1)
        self.window.SetSize(16, 16)
        self.window.Initialize()
        if self.window.GetGenericContext() is None:
            raise OSMesaUnavailable("VTK could not create an OSMesa context (check libosmesa6)")
        self.vertex_shader = vtkOpenGLRenderUtilities.GetFullScreenQuadVertexShader()
        self.pbo = vtkPixelBufferObject()
        self.pbo.SetContext(self.window)
        self.fbo = vtkOpenGLFramebufferObject()
        self.fbo.SetContext(self.window)
        self.quads = {}
        self.free: dict[tuple[int, int], list] = {}
        self.pooled: dict[int, int] = {}  # id -> layers of the targets this context allocated

    # -- textures -------------------------------------------------------------------------------
    def _filtering(self, tex, border=None):
        from vtkmodules.vtkRenderingOpenGL2 import vtkTextureObject

        tex.SetMinificationFilter(vtkTextureObject.Nearest)
        tex.SetMagnificationFilter(vtkTextureObject.Nearest)
        wrap = vtkTextureObject.ClampToEdge if border is None else vtkTextureObject.ClampToBorder
        tex.SetWrapS(wrap)
        tex.SetWrapT(wrap)
        if border is not None:
            tex.SetBorderColor(*border)
        return tex

    def upload(self, array: np.ndarray):
        """A float texture holding ``array`` ((H, W) or (H, W, C), C <= 4)."""
        from vtkmodules.util.numpy_support import numpy_to_vtk
        from vtkmodules.vtkCommonCore import VTK_FLOAT
        from vtkmodules.vtkRenderingOpenGL2 import vtkTextureObject

        h, w = array.shape[:2]
        channels = 1 if array.ndim == 2 else array.shape[2]
        data = numpy_to_vtk(np.ascontiguousarray(array, dtype=np.float32).reshape(-1, channels), deep=False)
        tex = vtkTextureObject()
        tex.SetContext(self.window)
        tex.Create2DFromRaw(w, h, channels, VTK_FLOAT, data)  # copied into GL here
        return self._filtering(tex)

    def target(self, width: int, height: int, border=None, layers: int = 0):
        """An RGBA32F texture from the pool (contents undefined until drawn); with ``layers``, a 3D
        texture of that depth (one draw buffer per layer)."""
        from vtkmodules.vtkCommonCore import VTK_FLOAT
        from vtkmodules.vtkRenderingOpenGL2 import vtkTextureObject

        free = self.free.get((width, height, layers))
        if free:
            tex = free.pop()
        else:
            tex = vtkTextureObject()
            tex.SetContext(self.window)
            if layers:
                tex.Allocate3D(width, height, layers, 4, VTK_FLOAT)
            else:
                tex.Allocate2D(width, height, 4, VTK_FLOAT)
            self.pooled[id(tex)] = layers
        return self._filtering(tex, border)

    def release(self, *textures):
        """Give drawn targets back to the pool."""
        for tex in textures:
            if tex is not None and id(tex) in self.pooled:
                self.free.setdefault((tex.GetWidth(), tex.GetHeight(), self.pooled[id(tex)]), []).append(tex)

    def draw(self, name: str, inputs: dict, uniforms: dict, width: int, height: int, border=None,
             epilogue: tuple = (), layers: int = 0):
        """Draw the full-screen pass ``name`` (with the pointwise ``epilogue``, ``shaders.source``) reading
        the textures ``inputs`` into a new target; with ``layers``, into the layers of a 3D target, one
        draw buffer each."""
        fs = shaders.source(name, tuple(epilogue))
        if fs not in self.quads:
            from vtkmodules.vtkRenderingOpenGL2 import vtkOpenGLQuadHelper

            self.quads[fs] = vtkOpenGLQuadHelper(self.window, self.vertex_shader, fs, "")
        target = self.target(width, height, border, layers)
        fbo = self.fbo
        fbo.SaveCurrentBindingsAndBuffers()
        try:
            fbo.Bind()
            if layers:
                for layer in range(layers):
                    fbo.AddColorAttachment(layer, target, layer)
                fbo.ActivateDrawBuffers(layers)
            else:
                fbo.AddColorAttachment(0, target)
                fbo.ActivateDrawBuffer(0)
            fbo.Start(width, height)
            program = self.window.GetShaderCache().ReadyShaderProgram(self.vertex_shader, fs, "")
            for key, tex in inputs.items():
                tex.Activate()
                program.SetUniformi(key, tex.GetTextureUnit())
            for key, value in uniforms.items():
                _set_uniform(program, key, value)
            self.quads[fs].Render()
            for tex in inputs.values():
                tex.Deactivate()
            for layer in range(1, layers):
                fbo.RemoveColorAttachment(layer)
        finally:
            fbo.RestorePreviousBindingsAndBuffers()
        return target

    def download(self, tex) -> np.ndarray:
        """Read a target back as (H, W, 3) float32 (a view of the RGBA read-back) through the one reused
        pixel buffer, straight into a NumPy array (1.1 ms at 640x480, 4.5 ms through a vtkFloatArray)."""
        from vtkmodules.vtkCommonCore import VTK_FLOAT
        from vtkmodules.vtkRenderingOpenGL2 import vtkOpenGLFramebufferObject

        width, height = tex.GetWidth(), tex.GetHeight()
        out = np.empty((height, width, 4), np.float32)
        fbo = self.fbo
        fbo.SaveCurrentBindingsAndBuffers()
        try:
            fbo.Bind()
            fbo.AddColorAttachment(0, tex)
            fbo.ActivateReadBuffer(0)
            vtkOpenGLFramebufferObject.Download([0, width - 1, 0, height - 1], VTK_FLOAT, 4, GL_FLOAT, GL_RGBA,
                                                self.pbo)
            self.pbo.Download2D(VTK_FLOAT, out, [width, height], 4, [0, 0])
        finally:
            fbo.RestorePreviousBindingsAndBuffers()
        return out[..., :3]

    def finish(self):
        """Wait until every pass drawn so far has run (llvmpipe renders at flush time)."""
        self.window.WaitForCompletion()


def _gaussian(ctx, tex, sigma, orig=None, amount=0.0, epilogue=None):
    """Separable Gaussian (effects.gaussian_blur) in blocks of GAUSS_BLOCK outputs per fragment; with
    ``orig``, the unsharp mask's ``orig + amount (orig - blur)`` clipped. ``epilogue``: pointwise effects
    fused into the last pass (``_Epilogue``)."""
    from postfx import effects

    w, h = tex.GetWidth(), tex.GetHeight()
    weights = effects.gaussian_weights(sigma)
    if weights.size > MAX_TAPS:
        raise ValueError(f"sigma_px = {sigma} needs {weights.size} taps, the shader holds {MAX_TAPS}")
    horizontal, vertical = shaders.gauss_passes((weights.size - 1) // 2)
    wts = FloatArray(weights)
    bx, by = -(-w // GAUSS_BLOCK), -(-h // GAUSS_BLOCK)
    rows = ctx.draw(horizontal, {"img": tex}, {"wts": wts, "blocks": IVec2((bx, h))}, bx, h, layers=GAUSS_BLOCK)
    cols = ctx.draw(vertical, {"rows": rows}, {"wts": wts, "blocks": IVec2((w, by))}, w, by, layers=GAUSS_BLOCK)
    ctx.release(rows)
    ep = epilogue or _Epilogue.none()
    out = ctx.draw("gauss_unpack", {"blocks": cols, "orig": orig if orig is not None else tex, **ep.inputs},
                   {"mode": int(orig is not None), "amount": float(amount), **ep.uniforms}, w, h, epilogue=ep.names)
    ctx.release(cols)
    return out


def _half(ctx, tex, threshold=None):
    """2x2 block mean at half resolution, of the part above ``threshold`` when given (effects._bright_half)."""
    from postfx import effects

    w, h = (tex.GetWidth() + 1) // 2, (tex.GetHeight() + 1) // 2
    uniforms = {"out_size": IVec2((w, h)), "use_threshold": int(threshold is not None),
                "threshold": float(threshold or 0.0), "luma": effects.LUMA}
    return ctx.draw("bright_half", {"img": tex}, uniforms, w, h)


def _add_upsampled(ctx, tex, low, k, ep):
    out = ctx.draw("add_upsampled", {"img": tex, "low": low, **ep.inputs}, {"k": float(k), **ep.uniforms},
                   tex.GetWidth(), tex.GetHeight(), epilogue=ep.names)
    ctx.release(low)
    return out


class _Epilogue:
    """Pointwise effects drawn inside another pass: their names (in order), uniforms and textures."""

    def __init__(self, ctx, effects_, width, height, seed):
        from postfx import effects

        self.names = tuple(name for name, _ in effects_)
        self.inputs: dict = {}
        self.uniforms: dict = {}
        for name, params in effects_:
            if name == "sensor_noise":
                key = effects.noise_key(seed)
                self.uniforms.update(noise_shot=float(params.shot), noise_rd=float(params.read),
                                     noise_key=key - (1 << 32) if key >= 1 << 31 else key)
            elif name == "tonemap":
                self.uniforms.update(tm_gain=2.0 ** params.exposure, tm_curve=effects.TONE_CURVES[params.curve],
                                     tm_srgb=int(params.srgb))
            elif name == "color_grade":
                if "cg_lut" in self.inputs:
                    raise ValueError("one colour grade per fused pass")
                self.inputs["cg_lut"] = ctx.upload(effects.grade_lut(params)[None, :, :])  # LUT_SIZE x 1
                self.uniforms.update(cg_saturation=float(params.saturation), cg_luma=effects.LUMA)
            elif name == "laparoscope_mask":
                self.uniforms.update(mask_centre=(width * (0.5 + params.offset[0]), height * (0.5 + params.offset[1])),
                                     mask_radius=params.radius, mask_softness=params.softness,
                                     mask_vignette=params.vignette)
            else:
                raise KeyError(f"{name!r} is not a pointwise effect")

    @classmethod
    def none(cls):
        return cls(None, (), 0, 0, 0)


def dof_tiles(reach2: np.ndarray) -> np.ndarray:
    """(ceil(H / DOF_TILE), ceil(W / DOF_TILE)) float32: for each output tile, the largest ``reach2`` of
    every source that can reach one of its pixels. A source q reaches p only if |p - q| <= sqrt(reach2_q)
    <= Rg = floor(sqrt(max reach2)) along each axis, so the sources of a tile lie in the tiles within
    ceil(Rg / DOF_TILE) of it: the tile maxima dilated by that many tiles bound every disc that
    covers the tile, and a gather over that bound sums exactly the terms of the full one."""
    h, w = reach2.shape
    th, tw = -(-h // DOF_TILE), -(-w // DOF_TILE)
    padded = np.full((th * DOF_TILE, tw * DOF_TILE), -1.0, np.float32)
    padded[:h, :w] = reach2
    tiles = padded.reshape(th, DOF_TILE, tw, DOF_TILE).max(axis=(1, 3))
    k = -(-int(math.floor(math.sqrt(max(float(reach2.max()), 0.0)))) // DOF_TILE)
    for axis in (0, 1):  # separable running maximum over 2k + 1 tiles
        grown = tiles.copy()
        n = tiles.shape[axis]
        for shift in range(1, min(k, n - 1) + 1):
            lo, hi = [slice(None)] * 2, [slice(None)] * 2
            lo[axis], hi[axis] = slice(0, n - shift), slice(shift, n)
            grown[tuple(lo)] = np.maximum(grown[tuple(lo)], tiles[tuple(hi)])
            grown[tuple(hi)] = np.maximum(grown[tuple(hi)], tiles[tuple(lo)])
        tiles = grown
    return tiles


def _depth_of_field(ctx, tex, depth, params, lens, ep):
    from postfx import effects

    w, h = tex.GetWidth(), tex.GetHeight()
    coc = effects.coc_radius_px(depth, params, lens.fov_deg, w)
    if float(coc.max()) < 0.5:
        return ctx.draw("copy", {"img": tex, **ep.inputs}, ep.uniforms, w, h, epilogue=ep.names)
    reach2 = effects.dof_reach2(coc)
    kx, ky = DOF_BLOCK
    pad = int(math.floor(math.sqrt(float(reach2.max())))) + max(kx, ky)
    reach_tex = ctx.upload(reach2)
    src = ctx.draw("dof_source", {"img": tex, "reach2": reach_tex}, {"pad": pad}, w + 2 * pad, h + 2 * pad)
    tiles = ctx.upload(dof_tiles(reach2))
    blocks = (-(-w // kx), -(-h // ky))
    gathered = ctx.draw("dof_gather", {"src": src, "tiles": tiles}, {"blocks": IVec2(blocks), "pad": pad},
                        blocks[0], blocks[1], layers=kx * ky)
    ctx.release(src)
    out = ctx.draw("dof_unpack", {"blocks": gathered, **ep.inputs}, {"out_size": IVec2((w, h)), **ep.uniforms},
                   w, h, epilogue=ep.names)
    ctx.release(gathered)
    return out


def effect_on_gpu(ctx: Context, name: str, tex, depth: np.ndarray, params, lens, seed: int = 0, epilogue=()):
    """One effect from texture to texture (the input stays valid; the caller releases it), followed by
    the pointwise effects ``epilogue`` (a list of ``(name, params)``) drawn in its last pass."""
    from postfx import lens_flare

    w, h = tex.GetWidth(), tex.GetHeight()
    if name in POINTWISE:  # a run of pointwise effects: one pass
        ep = _Epilogue(ctx, [(name, params), *epilogue], w, h, seed)
        return ctx.draw("pointwise", {"img": tex, **ep.inputs}, ep.uniforms, w, h, epilogue=ep.names)
    ep = _Epilogue(ctx, epilogue, w, h, seed)
    if name == "blur":
        return _gaussian(ctx, tex, params.sigma_px, epilogue=ep)
    if name == "sharpen":
        return _gaussian(ctx, tex, params.sigma_px, orig=tex, amount=params.amount, epilogue=ep)
    if name == "bloom":
        half = _half(ctx, tex, params.threshold)
        low = _gaussian(ctx, half, 0.5 * params.sigma_px)
        ctx.release(half)
        return _add_upsampled(ctx, tex, low, params.intensity, ep)
    if name == "lens_flare":
        half = _half(ctx, tex, params.threshold)
        quarter = _half(ctx, half)
        cx, cy, rho, halo = lens_flare.geometry((h, w), params)
        ghosts = lens_flare.ghost_table(params)
        uniforms = {"centre": (cx, cy), "rho": rho, "halo": halo, "halo_tint": params.halo_tint}
        if len(ghosts):
            uniforms["ghosts"] = Vec4Array(ghosts.ravel())
        features = shaders.flare_features(len(ghosts), int(params.falloff),
                                          tuple(bool(abs(s) >= 1.0) for s in ghosts[:, 0]))
        low = ctx.draw(features, {"half_res": half, "quarter": quarter}, uniforms, half.GetWidth(), half.GetHeight())
        ctx.release(half, quarter)
        if params.blur_px > 0.0:
            blurred = _gaussian(ctx, low, 0.5 * params.blur_px)
            ctx.release(low)
            low = blurred
        return _add_upsampled(ctx, tex, low, params.intensity, ep)
    if name == "chromatic_aberration":
        scale = [1.0 / (1.0 + k) if k > -1.0 else 1e6 for k in (params.strength_r, params.strength_g, params.strength_b)]
        return ctx.draw(name, {"img": tex, **ep.inputs},
                        {"scale": scale, "centre": (params.centre[0] * w, params.centre[1] * h), **ep.uniforms},
                        w, h, epilogue=ep.names)
    if name == "depth_of_field":
        return _depth_of_field(ctx, tex, depth, params, lens, ep)
    raise KeyError(f"unknown post-effect {name!r}")


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


def run_chain(hdr: np.ndarray, depth: np.ndarray, chain, lens, seed: int = 0, fuse: bool = True):
    """The whole chain on the GL side: one upload, one read-back. Returns the image, the seconds of
    each group of fused effects (measured with a finish after it; keyed by the effect's name, or by
    the names joined with "+" when pointwise effects were drawn in its last pass) and the total
    seconds including the transfers."""
    ctx = Context.get()
    start = time.perf_counter()
    tex = ctx.upload(hdr)
    uploaded = tex
    seconds = {}
    for group in fused_groups(chain, fuse):
        (name, params), rest = group[0], group[1:]
        t0 = time.perf_counter()
        out = effect_on_gpu(ctx, name, tex, depth, params, lens, seed, epilogue=rest)
        ctx.finish()
        seconds["+".join(n for n, _ in group)] = time.perf_counter() - t0
        if tex is not uploaded:
            ctx.release(tex)
        tex = out
    image = ctx.download(tex)
    if tex is not uploaded:
        ctx.release(tex)
    return image, seconds, time.perf_counter() - start


def apply_effect(name: str, img: np.ndarray, depth: np.ndarray, params, lens, seed: int = 0) -> np.ndarray:
    """One effect with upload and read-back; same signature and meaning as :func:`postfx.apply_effect`."""
    return run_chain(img, depth, [(name, params)], lens, seed)[0]
