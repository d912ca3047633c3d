"""The OSMesa backend: every post-effect as GLSL fragment passes (``postfx.shaders``), rendered
off-screen through VTK's ``vtkOSOpenGLRenderWindow`` (the VTK wheel plus Debian ``libosmesa6``) into
float textures. No window and no X server. See ``../shared/notes/osmesa.md`` for the path used.

A chain stays on the GL side: the HDR frame is uploaded once, each effect draws its passes from
texture to texture (targets come from a pool), and the result is read back once. OSMesa is llvmpipe,
software GL, where a texel fetch costs about as much as a numba tap, so the passes also do less
work: bloom and lens flare run at half resolution, the Gaussian weights are uniforms, the noise is
drawn in the shader from a counter-based generator instead of being uploaded.
"""
from __future__ import annotations

import ctypes
import math
import time

import numpy as np

from postfx.shaders import MAX_TAPS, SHADERS

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
        self.pooled: set[int] = set()  # ids of the targets this context allocated

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

    def target(self, width: int, height: int, border=None):
        """An RGBA32F texture from the pool (contents undefined until drawn)."""
        from vtkmodules.vtkCommonCore import VTK_FLOAT
        from vtkmodules.vtkRenderingOpenGL2 import vtkTextureObject

        free = self.free.get((width, height))
        if free:
            tex = free.pop()
        else:
            tex = vtkTextureObject()
            tex.SetContext(self.window)
            tex.Allocate2D(width, height, 4, VTK_FLOAT)
            self.pooled.add(id(tex))
        return self._filtering(tex, border)

    def release(self, *textures):
        """Give drawn targets back to the pool."""
        for tex in textures:
            if tex is not None and id(tex) in self.pooled:
                self.free.setdefault((tex.GetWidth(), tex.GetHeight()), []).append(tex)

    def draw(self, name: str, inputs: dict, uniforms: dict, width: int, height: int, border=None):
        """Draw the full-screen pass ``name`` reading the textures ``inputs`` into a new target."""
        fs = SHADERS[name]
        if name not in self.quads:
            from vtkmodules.vtkRenderingOpenGL2 import vtkOpenGLQuadHelper

            self.quads[name] = vtkOpenGLQuadHelper(self.window, self.vertex_shader, fs, "")
        target = self.target(width, height, border)
        fbo = self.fbo
        fbo.SaveCurrentBindingsAndBuffers()
        try:
            fbo.Bind()
            fbo.AddColorAttachment(0, target)
            fbo.ActivateDrawBuffer(0)
            fbo.Start(width, height)
            program = self.window.GetShaderCache().ReadyShaderProgram(self.vertex_shader, fs, "")
            for key, tex in inputs.items():
                tex.Activate()
                program.SetUniformi(key, tex.GetTextureUnit())
            for key, value in uniforms.items():
                _set_uniform(program, key, value)
            self.quads[name].Render()
            for tex in inputs.values():
                tex.Deactivate()
        finally:
            fbo.RestorePreviousBindingsAndBuffers()
        return target

    def download(self, tex) -> np.ndarray:
        """Read a target back as (H, W, 3) float32 through the one reused pixel buffer."""
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkCommonCore import VTK_FLOAT, vtkFloatArray
        from vtkmodules.vtkRenderingOpenGL2 import vtkOpenGLFramebufferObject

        width, height = tex.GetWidth(), tex.GetHeight()
        fbo = self.fbo
        fbo.SaveCurrentBindingsAndBuffers()
        try:
            fbo.Bind()
            fbo.AddColorAttachment(0, tex)
            fbo.ActivateReadBuffer(0)
            vtkOpenGLFramebufferObject.Download([0, width - 1, 0, height - 1], VTK_FLOAT, 4, GL_FLOAT, GL_RGBA,
                                                self.pbo)
            out = vtkFloatArray()
            out.SetNumberOfComponents(4)
            out.SetNumberOfTuples(width * height)
            self.pbo.Download2D(VTK_FLOAT, out.GetVoidPointer(0), [width, height], 4, [0, 0])
        finally:
            fbo.RestorePreviousBindingsAndBuffers()
        return vtk_to_numpy(out).reshape(height, width, 4)[..., :3].copy()

    def finish(self):
        """Wait until every pass drawn so far has run (llvmpipe renders at flush time)."""
        self.window.WaitForCompletion()


def _gaussian(ctx, tex, sigma, orig=None, amount=0.0):
    """Separable Gaussian (effects.gaussian_blur); with ``orig``, the vertical pass is the unsharp
    mask's ``orig + amount (orig - blur)`` clipped."""
    from postfx import effects

    w, h = tex.GetWidth(), tex.GetHeight()
    weights = effects.gaussian_weights(sigma)
    if weights.size > MAX_TAPS:
        raise ValueError(f"sigma_px = {sigma} needs {weights.size} taps, the shader holds {MAX_TAPS}")
    common = {"R": (weights.size - 1) // 2, "wts": FloatArray(weights), "amount": float(amount)}
    horizontal = ctx.draw("gauss_1d", {"img": tex, "orig": tex}, {**common, "dir": (1.0, 0.0), "mode": 0}, w, h)
    out = ctx.draw("gauss_1d", {"img": horizontal, "orig": orig if orig is not None else horizontal},
                   {**common, "dir": (0.0, 1.0), "mode": int(orig is not None)}, w, h)
    ctx.release(horizontal)
    return out


def _half(ctx, tex, threshold=None):
    """2x2 block mean at half resolution, of the part above ``threshold`` when given (effects._bright_half)."""
    from postfx import effects

    w, h = (tex.GetWidth() + 1) // 2, (tex.GetHeight() + 1) // 2
    uniforms = {"out_size": IVec2((w, h)), "use_threshold": int(threshold is not None),
                "threshold": float(threshold or 0.0), "luma": effects.LUMA}
    return ctx.draw("bright_half", {"img": tex}, uniforms, w, h)


def _add_upsampled(ctx, tex, low, k):
    out = ctx.draw("add_upsampled", {"img": tex, "low": low}, {"k": float(k)}, tex.GetWidth(), tex.GetHeight())
    ctx.release(low)
    return out


def effect_on_gpu(ctx: Context, name: str, tex, depth: np.ndarray, params, lens, seed: int = 0):
    """One effect from texture to texture (the input stays valid; the caller releases it)."""
    from postfx import effects, lens_flare

    w, h = tex.GetWidth(), tex.GetHeight()
    if name == "blur":
        return _gaussian(ctx, tex, params.sigma_px)
    if name == "sharpen":
        return _gaussian(ctx, tex, params.sigma_px, orig=tex, amount=params.amount)
    if name == "bloom":
        half = _half(ctx, tex, params.threshold)
        low = _gaussian(ctx, half, 0.5 * params.sigma_px)
        ctx.release(half)
        return _add_upsampled(ctx, tex, low, params.intensity)
    if name == "lens_flare":
        half = _half(ctx, tex, params.threshold)
        quarter = _half(ctx, half)
        cx, cy, rho, halo = lens_flare.geometry((h, w), params)
        ghosts = lens_flare.ghost_table(params)
        uniforms = {"centre": (cx, cy), "rho": rho, "halo": halo, "halo_tint": params.halo_tint,
                    "falloff": params.falloff, "n_ghosts": len(ghosts),
                    "ghosts": Vec4Array(np.vstack([ghosts, np.zeros((16 - len(ghosts), 4))]).ravel())}
        low = ctx.draw("flare_features", {"half_res": half, "quarter": quarter}, uniforms, half.GetWidth(),
                       half.GetHeight())
        ctx.release(half, quarter)
        if params.blur_px > 0.0:
            blurred = _gaussian(ctx, low, 0.5 * params.blur_px)
            ctx.release(low)
            low = blurred
        return _add_upsampled(ctx, tex, low, params.intensity)
    if name == "sensor_noise":
        key = effects.noise_key(seed)
        return ctx.draw("noise", {"img": tex}, {"shot": float(params.shot), "rd": float(params.read),
                                                "key_bits": key - (1 << 32) if key >= 1 << 31 else key}, w, h)
    if name == "chromatic_aberration":
        scale = [1.0 / (1.0 + k) if k > -1.0 else 1e6 for k in (params.strength_r, params.strength_g, params.strength_b)]
        return ctx.draw(name, {"img": tex}, {"scale": scale, "centre": (params.centre[0] * w, params.centre[1] * h)},
                        w, h)
    if name == "tonemap":
        curve = effects.TONE_CURVES[params.curve]
        return ctx.draw(name, {"img": tex}, {"gain": 2.0 ** params.exposure, "curve": curve,
                                             "srgb": int(params.srgb)}, w, h)
    if name == "laparoscope_mask":
        centre = (w * (0.5 + params.offset[0]), h * (0.5 + params.offset[1]))
        return ctx.draw(name, {"img": tex}, {"centre": centre, "radius": params.radius, "softness": params.softness,
                                             "vignette": params.vignette}, w, h)
    if name == "color_grade":
        lut = ctx.upload(effects.grade_lut(params)[None, :, :])  # a LUT_SIZE x 1 float texture
        return ctx.draw(name, {"img": tex, "lut": lut}, {"saturation": params.saturation, "luma": effects.LUMA}, w, h)
    if name == "depth_of_field":
        coc = effects.coc_radius_px(depth, params, lens.fov_deg, w)
        rmax = float(coc.max())
        if rmax < 0.5:
            return ctx.draw("copy", {"img": tex}, {}, w, h)
        reach2 = ctx.upload(effects.dof_reach2(coc))
        src = ctx.draw("dof_source", {"img": tex, "reach2": reach2}, {}, w, h, border=(0.0, 0.0, 0.0, -1.0))
        out = ctx.draw(name, {"src": src}, {"R": int(math.ceil(rmax)), "r2max": rmax * rmax + 0.25}, w, h)
        ctx.release(src)
        return out
    raise KeyError(f"unknown post-effect {name!r}")


def run_chain(hdr: np.ndarray, depth: np.ndarray, chain, lens, seed: int = 0):
    """The whole chain on the GL side: one upload, one read-back. Returns the image, the seconds of
    each effect (measured with a finish after it) and the total seconds including the transfers."""
    ctx = Context.get()
    start = time.perf_counter()
    tex = ctx.upload(hdr)
    uploaded = tex
    seconds = {}
    for name, params in chain:
        t0 = time.perf_counter()
        out = effect_on_gpu(ctx, name, tex, depth, params, lens, seed)
        ctx.finish()
        seconds[name] = time.perf_counter() - t0
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
