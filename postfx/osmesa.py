"""The OSMesa backend: every post-effect as GLSL fragment passes (``postfx.shaders``), rendered
off-screen through VTK's ``vtkOSOpenGLRenderWindow`` (the VTK wheel plus Debian ``libosmesa6``) into
float textures. No window and no X server. See ``../shared/notes/osmesa.md`` for the path used.

A chain stays on the GL side: the HDR frame is uploaded once (or, when the depth of field comes first,
the DoF's padded source built from it on the CPU), each effect draws its passes from texture to
texture (targets come from a pool), and the result is read back once. OSMesa is llvmpipe, software
GL, where a texel fetch costs about as much as a numba tap, so the passes also do less work: bloom
and lens flare run at half resolution, bilinear reads use the sampler's filter, the Gaussian weights
are uniforms, the noise is drawn in the shader from a counter-based generator instead of being
uploaded, the depth of field gathers for blocks of 4 x 4 outputs per fetched texel within a per-tile
bound and writes them with imageStore, and a run of pointwise effects (noise, tone map, grade, mask)
is applied in the last pass of the effect before it.
"""
from __future__ import annotations

import contextlib
import ctypes
import math
import time

import numpy as np
from numba import njit

from postfx import shaders
from postfx.shaders import DOF_BLOCK, DOF_TILE, GAUSS_BLOCK, MAX_TAPS, POINTWISE

GL_FLOAT = 0x1406
GL_RGB = 0x1907
GL_RGBA = 0x1908
_GL_FORMATS = {1: 0x1903, 2: 0x8227, 3: GL_RGB, 4: GL_RGBA}  # GL_RED, GL_RG, GL_RGB, GL_RGBA
GL_PIXEL_PACK_BUFFER = 0x88EB
GL_PIXEL_UNPACK_BUFFER = 0x88EC
GL_UNPACK_ALIGNMENT = 0x0CF5
GL_TEXTURE_2D = 0x0DE1
GL_PACK_ALIGNMENT = 0x0D05
GL_PACK_ROW_LENGTH = 0x0D02
GL_RGBA32F = 0x8814
GL_WRITE_ONLY = 0x88B9
GL_ALL_BARRIER_BITS = 0xFFFFFFFF
GL_TIMESTAMP = 0x8E28
GL_RENDERER = 0x1F01
GL_QUERY_RESULT = 0x8866
LIBRARIES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")


def _gl_library():
    for name in LIBRARIES:
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    raise OSError("libOSMesa not found")


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


def _canonical(value):
    """A value of ``_set_uniform`` in a form that compares equal exactly when the program would receive
    the same values (uniform names keep one type)."""
    if isinstance(value, tuple):  # FloatArray, Vec4Array, IVec2, pairs
        return value
    if isinstance(value, list):
        return tuple(value)
    if isinstance(value, np.ndarray):
        return value.tobytes()
    return value


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


@njit(cache=True)
def _rgb_of(rgba, clip, out):
    """``out = rgba[..., :3]``, clipped to [0, 1] with ``clip`` as np.clip does (NaN stays NaN)."""
    h, w, _ = rgba.shape
    zero, one = np.float32(0.0), np.float32(1.0)
    for j in range(h):
        for i in range(w):
            for c in range(3):
                v = rgba[j, i, c]
                if clip:
                    if v < zero:
                        v = zero
                    elif v > one:
                        v = one
                out[j, i, c] = v


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
                                                    vtkOSOpenGLRenderWindow)

        self.window = vtkOSOpenGLRenderWindow()
        self.window.SetOffScreenRendering(1)
        self.window.SetSize(16, 16)
        self.window.Initialize()
        if self.window.GetGenericContext() is None:
            raise OSMesaUnavailable("VTK could not create an OSMesa context (check libosmesa6)")
        self.vertex_shader = vtkOpenGLRenderUtilities.GetFullScreenQuadVertexShader()
        self.fbo = vtkOpenGLFramebufferObject()
        self.fbo.SetContext(self.window)
        self.quads = {}
        # VTK wraps no image-store calls and reads back through a pixel buffer: these calls come straight
        # from the library VTK uses (its context is current on this thread)
        self.gl = _gl_library()
        self.gl.glBindImageTexture.argtypes = [ctypes.c_uint, ctypes.c_uint, ctypes.c_int, ctypes.c_ubyte,
                                               ctypes.c_int, ctypes.c_uint, ctypes.c_uint]
        self.gl.glMemoryBarrier.argtypes = [ctypes.c_uint]
        self.gl.glBindBuffer.argtypes = [ctypes.c_uint, ctypes.c_uint]
        self.gl.glPixelStorei.argtypes = [ctypes.c_uint, ctypes.c_int]
        self.gl.glReadPixels.argtypes = [ctypes.c_int] * 4 + [ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p]
        self.gl.glTexSubImage2D.argtypes = [ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                            ctypes.c_int, ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p]
        # GL 3.3 calls that libOSMesa does not export by name: through its OSMesaGetProcAddress
        address = self.gl.OSMesaGetProcAddress
        address.restype, address.argtypes = ctypes.c_void_p, [ctypes.c_char_p]

        def proc(name, *argtypes):
            pointer = address(name.encode())
            if not pointer:
                raise OSMesaUnavailable(f"libOSMesa has no {name} (OpenGL 3.3 is needed)")
            return ctypes.CFUNCTYPE(None, *argtypes)(pointer)

        self._query_counter = proc("glQueryCounter", ctypes.c_uint, ctypes.c_uint)
        self._query_result = proc("glGetQueryObjectui64v", ctypes.c_uint, ctypes.c_uint, ctypes.POINTER(ctypes.c_uint64))
        self._gen_queries = proc("glGenQueries", ctypes.c_int, ctypes.POINTER(ctypes.c_uint))
        get_int64 = proc("glGetInteger64v", ctypes.c_uint, ctypes.POINTER(ctypes.c_int64))
        self.queries: list[int] = []
        # llvmpipe stamps with CLOCK_MONOTONIC, Python's monotonic clock: then an effect's seconds can start
        # at the chain's start on the CPU (the DoF's CPU steps count); checked, not assumed
        now, gl_now = time.monotonic_ns(), ctypes.c_int64()
        get_int64(GL_TIMESTAMP, ctypes.byref(gl_now))
        self.shared_clock = abs(gl_now.value - now) < 5_000_000
        self.gl.glGetString.restype, self.gl.glGetString.argtypes = ctypes.c_char_p, [ctypes.c_uint]
        self.renderer = (self.gl.glGetString(GL_RENDERER) or b"").decode(errors="replace")
        # imageStore results reach later passes' texture fetches after a glMemoryBarrier, which llvmpipe
        # (Mesa 22.3) implements as a full finish: this thread sleeps until the gather has run, and the
        # rasterizer threads until it has queued the next pass (rendered benchmark frame 43.3 vs 37.4 ms
        # in one process, alternating). llvmpipe runs each pass (scene) after the one before it has
        # finished on every thread, and its stores go straight to the texture's memory, so there the
        # later passes read the stored values without it (tested: the same bits); other drivers get it.
        self.barrier_after_stores = "llvmpipe" not in self.renderer
        # per-frame inputs of a fixed shape (the DoF's padded source): a host array and a texture kept
        # from chain to chain, refilled in place (no fresh pages to fault in, no texture allocation)
        self.staging: dict = {}
        self.persistent: dict = {}
        self.free: dict[tuple[int, int], list] = {}
        self.pooled: dict[int, int] = {}  # id -> layers of the targets this context allocated
        self.programs: dict = {}  # shader source -> its vtkShaderProgram
        self.uniform_values: dict[str, dict] = {}  # shader source -> uniform -> what its program holds
        self.row_blocked: dict[int, int] = {}  # id -> image height of a target drawn row-blocked, until read back
        # when a dict: every draw waits for the passes before it, and for itself, and adds its seconds
        # under "<pass>[+epilogue] <width>x<height>" (a profile for the benchmark; off by default)
        self.profile: dict | None = None

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

    @staticmethod
    def _linear(tex, zero_outside: bool):
        """Bilinear filtering: llvmpipe interpolates float textures with float32 weights, the
        arithmetic of effects.bilinear_clamped / lens_flare.bilinear_zero up to float rounding of the
        coordinate (measured at 640x480: 7e-6 for the bloom's upsampling), for one fetch instead of four."""
        from vtkmodules.vtkRenderingOpenGL2 import vtkTextureObject

        tex.SetMinificationFilter(vtkTextureObject.Linear)
        tex.SetMagnificationFilter(vtkTextureObject.Linear)
        wrap = vtkTextureObject.ClampToBorder if zero_outside else vtkTextureObject.ClampToEdge
        tex.SetWrapS(wrap)
        tex.SetWrapT(wrap)
        if zero_outside:
            tex.SetBorderColor(0.0, 0.0, 0.0, 0.0)

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

    def staging_array(self, key, shape, tag=None) -> tuple[np.ndarray, bool]:
        """A float32 host array of ``shape`` kept under ``key`` for the next upload, with the contents of
        its last use when ``shape`` and ``tag`` repeat; the flag is True when it is new."""
        arr, last = self.staging.get(key, (None, None))
        if arr is None or arr.shape != tuple(shape) or last != tag:
            arr = np.empty(shape, np.float32)
            self.staging[key] = (arr, tag)
            return arr, True
        return arr, False

    def upload_into(self, key, array: np.ndarray):
        """``upload(array)`` into a texture kept under ``key``: refilled with glTexSubImage2D when the shape
        repeats (the DoF source at 664 x 504: 0.44 vs 0.65 ms for a new texture; a 40 x 30 one: 0.008
        vs 0.021 ms). The texture holds ``array`` until the next upload under the same key (GL orders
        that upload after every pass drawn before it)."""
        h, w = array.shape[:2]
        channels = 1 if array.ndim == 2 else array.shape[2]
        tex, shape = self.persistent.get(key, (None, None))
        if tex is None or shape != (h, w, channels):
            tex = self.upload(array)
            self.persistent[key] = (tex, (h, w, channels))
            return tex
        tex.Activate()  # binds it to GL_TEXTURE_2D of its unit
        self.gl.glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0)  # from client memory
        self.gl.glPixelStorei(GL_UNPACK_ALIGNMENT, 4)
        self.gl.glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, w, h, _GL_FORMATS[channels], GL_FLOAT,
                                np.ascontiguousarray(array, dtype=np.float32).ctypes.data)
        tex.Deactivate()
        return tex

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
            if tex is not None:
                self.row_blocked.pop(id(tex), None)
            if tex is not None and id(tex) in self.pooled:
                self.free.setdefault((tex.GetWidth(), tex.GetHeight(), self.pooled[id(tex)]), []).append(tex)

    def draw(self, name: str, inputs: dict, uniforms: dict, width: int, height: int, border=None,
             epilogue: tuple = (), layers: int = 0, images: dict | None = None, linear: dict | None = None):
        """Draw the full-screen pass ``name`` (with the pointwise ``epilogue``, ``shaders.source``) reading
        the textures ``inputs`` into a new target; with ``layers``, into the layers of a 3D target, one
        draw buffer each. ``images``: RGBA32F textures the pass writes with imageStore (uniform name ->
        texture), visible to every later pass (a memory barrier follows the draw, except on llvmpipe: see
        ``barrier_after_stores``). ``linear``: inputs this
        pass samples with llvmpipe's bilinear filter (input name -> True for zero outside the texture,
        False for clamped coordinates); they return to nearest filtering afterwards."""
        if self.profile is not None:
            self.finish()
            t0 = time.perf_counter()
        fs = shaders.source(name, tuple(epilogue))
        if fs not in self.quads:
            from vtkmodules.vtkRenderingOpenGL2 import vtkOpenGLQuadHelper

            self.quads[fs] = vtkOpenGLQuadHelper(self.window, self.vertex_shader, fs, "")
        target = self.target(width, height, border, layers)
        self.row_blocked.pop(id(target), None)
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
            # by source the cache hashes the shader texts on every call; the program object binds directly
            program = self.programs.get(fs)
            if program is None:
                program = self.programs[fs] = self.window.GetShaderCache().ReadyShaderProgram(self.vertex_shader, fs, "")
            else:
                self.window.GetShaderCache().ReadyShaderProgram(program)
            for key, zero in (linear or {}).items():
                self._linear(inputs[key], zero)
            # a program keeps its uniforms: set only those that changed since its last draw (about 56 per
            # chain, 18 us each through VTK's wrapping, most of them the same every frame)
            known = self.uniform_values.setdefault(fs, {})
            for key, tex in inputs.items():
                tex.Activate()
                unit = tex.GetTextureUnit()
                if known.get(key) != unit:
                    program.SetUniformi(key, unit)
                    known[key] = unit
            for key, value in uniforms.items():
                canonical = _canonical(value)
                if known.get(key) != canonical:
                    _set_uniform(program, key, value)
                    known[key] = canonical
            for unit, (key, tex) in enumerate((images or {}).items()):
                self.gl.glBindImageTexture(unit, tex.GetHandle(), 0, 0, 0, GL_WRITE_ONLY, GL_RGBA32F)
                if known.get(key) != unit:
                    program.SetUniformi(key, unit)
                    known[key] = unit
            self.quads[fs].Render()
            if images and self.barrier_after_stores:
                self.gl.glMemoryBarrier(GL_ALL_BARRIER_BITS)
            for tex in inputs.values():
                tex.Deactivate()
            for key in linear or {}:
                self._filtering(inputs[key])
            for layer in range(1, layers):
                fbo.RemoveColorAttachment(layer)
        finally:
            fbo.RestorePreviousBindingsAndBuffers()
        if self.profile is not None:
            self.finish()
            key = f"{'+'.join((name, *epilogue))} {width}x{height}"
            self.profile[key] = self.profile.get(key, 0.0) + time.perf_counter() - t0
        return target

    def note(self, key: str, t0: float):
        """Add the seconds since ``t0`` to the profile (when one is kept) under ``key``."""
        if self.profile is not None:
            self.profile[key] = self.profile.get(key, 0.0) + time.perf_counter() - t0

    def download(self, tex, clip: bool = False) -> np.ndarray:
        """Read a target back as a new (H, W, 3) float32 array, clipped to [0, 1] with ``clip``.

        glReadPixels of RGBA into a host array kept from call to call (RGBA32F to RGBA is a copy in Mesa,
        0.29 ms at 640x480, where RGB converts, 0.48 ms, and a new array faults its pages in on every
        call, about 1 ms), then the RGB channels into the result in one loop (0.3 ms; NumPy's clip of the
        strided view took 1.6 ms). A row-blocked target (``row_blocked``: layer k holds rows k, k + L,
        ...) is read layer by layer, each row landing in its place (GL_PACK_ROW_LENGTH of L rows)."""
        t0 = time.perf_counter()
        width = tex.GetWidth()
        height = self.row_blocked.pop(id(tex), None)
        layers = tex.GetDepth() if height is not None else 1
        if height is None:
            height = tex.GetHeight()
        staged, _ = self.staging_array("read-back", (height, width, 4))
        fbo = self.fbo
        fbo.SaveCurrentBindingsAndBuffers()
        try:
            fbo.Bind()
            self.gl.glBindBuffer(GL_PIXEL_PACK_BUFFER, 0)  # into client memory, not a pixel buffer
            self.gl.glPixelStorei(GL_PACK_ALIGNMENT, 4)
            self.gl.glPixelStorei(GL_PACK_ROW_LENGTH, width * layers)
            for layer in range(min(layers, height)):
                fbo.RemoveColorAttachment(0)  # VTK keeps an attachment of the same texture, whatever its layer
                fbo.AddColorAttachment(0, tex, layer)
                fbo.ActivateReadBuffer(0)
                rows = (height - layer + layers - 1) // layers
                self.gl.glReadPixels(0, 0, width, rows, GL_RGBA, GL_FLOAT, staged[layer].ctypes.data)
            self.gl.glPixelStorei(GL_PACK_ROW_LENGTH, 0)
            if layers > 1:  # a later draw into this target's layer 0 must attach it again
                fbo.RemoveColorAttachment(0)
        finally:
            fbo.RestorePreviousBindingsAndBuffers()
        out = np.empty((height, width, 3), np.float32)
        _rgb_of(staged, clip, out)
        self.note(f"read-back {width}x{height}", t0)
        return out

    def finish(self):
        """Wait until every pass drawn so far has run (llvmpipe renders at flush time)."""
        self.window.WaitForCompletion()

    def timestamp(self, index: int) -> None:
        """Record in query ``index`` the time at which the passes drawn so far have run (GL_TIMESTAMP, read
        with ``timestamps`` once they have): timing without waiting for them here."""
        while len(self.queries) <= index:
            ids = (ctypes.c_uint * 16)()
            self._gen_queries(16, ids)
            self.queries.extend(ids)
        self._query_counter(self.queries[index], GL_TIMESTAMP)

    def timestamps(self, count: int) -> list[int]:
        """The nanoseconds of queries 0 .. count - 1 (waits for them)."""
        value, out = ctypes.c_uint64(), []
        for query in self.queries[:count]:
            self._query_result(query, GL_QUERY_RESULT, ctypes.byref(value))
            out.append(value.value)
        return out


def _gaussian(ctx, tex, sigma, orig=None, amount=0.0, epilogue=None, rows_out=False):
    """Separable Gaussian (effects.gaussian_blur) in blocks of GAUSS_BLOCK outputs per fragment; with
    ``orig``, the unsharp mask's ``orig + amount (orig - blur)`` clipped. ``epilogue``: pointwise effects
    fused into the last pass (``_Epilogue``).

    Row-blocked images (``Context.row_blocked``: a 3D target whose layer k holds the rows k, k + L, ...):
    with ``rows_out`` a radius up to GAUSS_PLAIN_V writes its result so, GAUSS_BLOCK rows per fragment
    from GAUSS_BLOCK + 2R fetches instead of 2R + 1 per row (``shaders._gauss_rows_out``; the caller asks
    for it when the result goes to the read-back or to another such Gaussian); ``tex`` (and ``orig``)
    may be row-blocked, and are read in place."""
    from postfx import effects

    w = tex.GetWidth()
    h = ctx.row_blocked.get(id(tex), tex.GetHeight())
    weights = effects.gaussian_weights(sigma)
    if weights.size > MAX_TAPS:
        raise ValueError(f"sigma_px = {sigma} needs {weights.size} taps, the shader holds {MAX_TAPS}")
    R = (weights.size - 1) // 2
    horizontal, vertical = shaders.gauss_passes(R)
    wts = FloatArray(weights)
    bx, by = -(-w // GAUSS_BLOCK), -(-h // GAUSS_BLOCK)
    rows = ctx.draw(horizontal + ("r" if id(tex) in ctx.row_blocked else ""), {"img": tex},
                    {"wts": wts, "blocks": IVec2((bx, h))}, bx, h, layers=GAUSS_BLOCK)
    ep = epilogue or _Epilogue.none()
    # the unsharp mask's variant: "u" for an image, "U" for a row-blocked one
    unsharp = "" if orig is None else ("U" if id(orig) in ctx.row_blocked else "u")
    if rows_out and R <= shaders.GAUSS_PLAIN_V:
        inputs = {"rows": rows, **({} if orig is None else {"orig": orig}), **ep.inputs}
        uniforms = {"wts": wts, "size": IVec2((w, h)), "blocks": IVec2((w, by)), **ep.uniforms}
        if orig is not None:
            uniforms["amount"] = float(amount)
        out = ctx.draw(f"gauss_vb{R}{unsharp}", inputs, uniforms, w, by, epilogue=ep.names, layers=GAUSS_BLOCK)
        ctx.row_blocked[id(out)] = h
        ctx.release(rows)
        return out
    if unsharp == "U" and R > shaders.GAUSS_PLAIN_V:
        raise ValueError("a row-blocked image goes only to Gaussians of radius <= GAUSS_PLAIN_V")
    if R <= shaders.GAUSS_PLAIN_V:  # one output per fragment, straight into the image
        inputs = {"rows": rows, **({} if orig is None else {"orig": orig}), **ep.inputs}
        uniforms = {"wts": wts, "size": IVec2((w, h)), **ep.uniforms}
        if orig is not None:
            uniforms["amount"] = float(amount)
        out = ctx.draw(vertical + unsharp, inputs, uniforms, w, h, epilogue=ep.names)
        ctx.release(rows)
        return out
    cols = ctx.draw(vertical, {"rows": rows}, {"wts": wts, "blocks": IVec2((w, by))}, w, by, layers=GAUSS_BLOCK)
    ctx.release(rows)
    inputs = {"blocks": cols, **({} if orig is None else {"orig": orig}), **ep.inputs}
    uniforms = {"size": IVec2((w, h)), **ep.uniforms}
    if orig is not None:
        uniforms["amount"] = float(amount)
    out = ctx.draw("gauss_unpack" if orig is None else "gauss_unpack_sharpen", inputs, uniforms, w, h,
                   epilogue=ep.names)
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
                   tex.GetWidth(), tex.GetHeight(), epilogue=ep.names, linear={"low": False})
    ctx.release(low)
    return out


def _lut_pairs(lut: np.ndarray) -> np.ndarray:
    """(3, n, 2) float32: row c, texel k = (lut[k, c], lut[k + 1, c]) (the last texel repeats its entry), so
    that the shader's linear interpolation reads one texel per channel."""
    pairs = np.empty((3, lut.shape[0], 2), np.float32)
    pairs[:, :, 0] = lut.T
    pairs[:, :-1, 1] = lut[1:].T
    pairs[:, -1, 1] = lut[-1]
    return pairs


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
                self.inputs["cg_lut"] = ctx.upload_into("cg_lut", _lut_pairs(effects.grade_lut(params)))
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


# error_model="numpy": IEEE division without numba's zero-division check, which kept the loops from
# vectorising (1.3 -> 0.3 ms at 640x480); no operation changes, the results are the same bits
@njit(cache=True, error_model="numpy")
def _coc_reach2(depth, eps, df, k, denom, half, width, sensor_width, max_r, tile, reach2, tiles):
    """``reach2 = effects.dof_reach2(effects.coc_radius_px(depth, ...))`` to the bit, in one loop over the
    pixels instead of NumPy's dozen whole-array passes, and the largest
    reach2 of each ``tile`` x ``tile`` tile (``tiles``, filled with -1 by the caller). The scalars come
    in the precision NumPy computes with: ``eps``, ``df``, ``k``, ``denom``, ``half``, ``width`` in the
    depth's dtype (NumPy 2 casts Python scalars to the array's float32), ``sensor_width`` and ``max_r``
    in float64 (``np.tan`` returns a float64 scalar, so NumPy divides in float64 there), and each
    operation in NumPy's order."""
    h, w = depth.shape
    one = depth.dtype.type(1.0)
    for j in range(h):
        row = reach2[j]
        for i in range(w):  # branch-free, so that it vectorises
            z = depth[j, i]
            finite = np.isfinite(z)
            d = max(z, eps) if finite else one
            rel = abs(d - df) / d if finite else one  # NaN, +-inf: the far limit |d - df| / d -> 1
            radius = np.float64(half * (k * rel / denom) * width) / sensor_width
            c = np.float64(np.float32(min(radius, max_r)))
            row[i] = np.float32(c * c + 0.25)
        tj = j // tile
        for ti in range(tiles.shape[1]):
            m = tiles[tj, ti]
            for i in range(ti * tile, min((ti + 1) * tile, w)):
                m = max(m, row[i])
            tiles[tj, ti] = m


def coc_reach2(depth: np.ndarray, p, fov_deg: float, width: int):
    """(reach2, tile maxima): ``effects.dof_reach2(effects.coc_radius_px(depth, p, fov_deg, width))`` (the
    same float32 values) and, per DOF_TILE x DOF_TILE tile, its largest reach2 (-1 where a partial tile
    has no pixel)."""
    from postfx import effects

    depth = np.asarray(depth)
    h, w = depth.shape
    tiles = np.full((-(-h // DOF_TILE), -(-w // DOF_TILE)), -1.0, np.float32)
    if depth.dtype not in (np.float32, np.float64):  # the kernel mirrors NumPy for these two only
        reach2 = effects.dof_reach2(effects.coc_radius_px(depth, p, fov_deg, width))
        padded = np.full((tiles.shape[0] * DOF_TILE, tiles.shape[1] * DOF_TILE), -1.0, np.float32)
        padded[:h, :w] = reach2
        return reach2, padded.reshape(tiles.shape[0], DOF_TILE, tiles.shape[1], DOF_TILE).max(axis=(1, 3))
    f, A, df = p.focal_length, p.aperture, p.focus_distance
    t = depth.dtype.type
    sensor_width = 2.0 * f * np.tan(np.radians(fov_deg) / 2.0)
    reach2 = np.empty((h, w), np.float32)
    _coc_reach2(np.ascontiguousarray(depth), t(1e-9), t(df), t(2.0 * A * f), t(max(df - f, 1e-9)), t(0.5), t(width),
                np.float64(sensor_width), np.float64(p.max_radius_px), DOF_TILE, reach2, tiles)
    return reach2, tiles


def dilate_tiles(tiles: np.ndarray, max_reach2: float) -> np.ndarray:
    """For each output tile, a bound on the ``reach2`` of every source that can reach one of its pixels,
    from the tile maxima ``tiles``. A source q reaches p only if |p - q| <= sqrt(reach2_q) <= Rg =
    floor(sqrt(max reach2)) along each axis, so the sources of a tile lie in the tiles within
    ceil(Rg / DOF_TILE) of it: the tile maxima dilated by that many tiles bound every disc that
    covers the tile, and a gather over that bound sums exactly the terms of the full one."""
    k = -(-int(math.floor(math.sqrt(max(float(max_reach2), 0.0)))) // DOF_TILE)
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


def dof_tiles(reach2: np.ndarray) -> np.ndarray:
    """(ceil(H / DOF_TILE), ceil(W / DOF_TILE)) float32: for each output tile, the largest ``reach2`` of
    every source that can reach one of its pixels (``dilate_tiles`` of the tile maxima)."""
    h, w = reach2.shape
    th, tw = -(-h // DOF_TILE), -(-w // DOF_TILE)
    padded = np.full((th * DOF_TILE, tw * DOF_TILE), -1.0, np.float32)
    padded[:h, :w] = reach2
    return dilate_tiles(padded.reshape(th, DOF_TILE, tw, DOF_TILE).max(axis=(1, 3)), float(reach2.max()))


@njit(cache=True, error_model="numpy")
def _dof_source_host(img, reach2, pad, out, fill_pad):
    """The gather's source on the CPU, as the ``dof_source`` pass draws it, into ``out`` ((h + 2 pad,
    w + 2 pad, 4) float32): padded by ``pad`` texels of reach -1 (written only when ``fill_pad``: a
    reused array keeps them), ``(r w, g w, b w, reach2)`` with w = 1 / (pi max(reach2 - 1/4, 1/4)) in
    float32."""
    h, w, _ = img.shape
    if fill_pad:
        for j in range(h + 2 * pad):
            for i in range(w + 2 * pad):
                out[j, i, 0] = 0.0
                out[j, i, 1] = 0.0
                out[j, i, 2] = 0.0
                out[j, i, 3] = -1.0
    pi = np.float32(3.14159265358979)
    for j in range(h):
        for i in range(w):
            r2 = reach2[j, i]
            wq = np.float32(1.0) / (pi * max(r2 - np.float32(0.25), np.float32(0.25)))
            out[j + pad, i + pad, 0] = img[j, i, 0] * wq
            out[j + pad, i + pad, 1] = img[j, i, 1] * wq
            out[j + pad, i + pad, 2] = img[j, i, 2] * wq
            out[j + pad, i + pad, 3] = r2


def _depth_of_field(ctx, tex, depth, params, lens, ep, host=None):
    """The DoF from the texture ``tex``, or, when the DoF is the chain's first effect, from the frame
    ``host`` still on the CPU: then its padded source is built there (one numba loop) and uploaded in
    place of the frame, which saves the ``dof_source`` pass and the frame's own upload."""
    h, w = host.shape[:2] if host is not None else (tex.GetHeight(), tex.GetWidth())
    t0 = time.perf_counter()
    reach2, tile_max = coc_reach2(depth, params, lens.fov_deg, w)
    ctx.note("dof reach2 + tile maxima (CPU)", t0)
    max_reach2 = float(tile_max.max())
    if max_reach2 < 0.5:  # every CoC radius below 1/2 (reach2 = r^2 + 1/4): nothing moves
        if tex is None:
            tex = ctx.upload(host)
        return ctx.draw("copy", {"img": tex, **ep.inputs}, ep.uniforms, w, h, epilogue=ep.names)
    kx, ky = DOF_BLOCK
    pad = int(math.floor(math.sqrt(max_reach2))) + max(kx, ky)
    if host is not None:
        t0 = time.perf_counter()
        staged, new = ctx.staging_array("dof_source", (h + 2 * pad, w + 2 * pad, 4), tag=pad)
        _dof_source_host(np.ascontiguousarray(host, dtype=np.float32), reach2, pad, staged, new)
        src = ctx.upload_into("dof_source", staged)
        ctx.note("dof source (CPU) + upload", t0)
    else:
        reach_tex = ctx.upload_into("dof_reach2", reach2)
        src = ctx.draw("dof_source", {"img": tex, "reach2": reach_tex}, {"pad": pad}, w + 2 * pad, h + 2 * pad)
    tiles = ctx.upload_into("dof_tiles", dilate_tiles(tile_max, max_reach2))
    blocks = (-(-w // kx), -(-h // ky))
    out = ctx.target(w, h)
    dummy = ctx.draw("dof_gather", {"src": src, "tiles": tiles, **ep.inputs},
                     {"blocks": IVec2(blocks), "size": IVec2((w, h)), "pad": pad, **ep.uniforms},
                     blocks[0], blocks[1], epilogue=ep.names, images={"dof_out": out})
    ctx.release(src, dummy)
    return out


def effect_on_gpu(ctx: Context, name: str, tex, depth: np.ndarray, params, lens, seed: int = 0, epilogue=(),
                  host=None, rows_out=False):
    """One effect from texture to texture (the input stays valid; the caller releases it), followed by
    the pointwise effects ``epilogue`` (a list of ``(name, params)``) drawn in its last pass. ``tex`` may
    be None for the depth of field, which then reads the frame ``host`` from the CPU. ``rows_out``: a
    blur or sharpen may leave its result row-blocked (``_gaussian``); only ``takes_rows`` effects and
    ``Context.download`` read such a texture."""
    from postfx import lens_flare

    if tex is not None and id(tex) in ctx.row_blocked and not takes_rows(name, params):
        raise ValueError(f"{name} cannot read a row-blocked image")

    if name == "depth_of_field":
        return _depth_of_field(ctx, tex, depth, params, lens, _Epilogue(ctx, epilogue, *(
            host.shape[1::-1] if tex is None else (tex.GetWidth(), tex.GetHeight())), seed), host if tex is None else None)
    w, h = tex.GetWidth(), tex.GetHeight()
    if name in POINTWISE:  # a run of pointwise effects: one pass
        ep = _Epilogue(ctx, [(name, params), *epilogue], w, h, seed)
        return ctx.draw("pointwise", {"img": tex, **ep.inputs}, ep.uniforms, w, h, epilogue=ep.names)
    ep = _Epilogue(ctx, epilogue, w, h, seed)
    if name == "blur":
        return _gaussian(ctx, tex, params.sigma_px, epilogue=ep, rows_out=rows_out)
    if name == "sharpen":
        return _gaussian(ctx, tex, params.sigma_px, orig=tex, amount=params.amount, epilogue=ep, rows_out=rows_out)
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
        low = ctx.draw(features, {"half_res": half, "quarter": quarter}, uniforms, half.GetWidth(), half.GetHeight(),
                       linear={"half_res": True, "quarter": True})
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
                        w, h, epilogue=ep.names, linear={"img": False})
    raise KeyError(f"unknown post-effect {name!r}")


def takes_rows(name: str, params) -> bool:
    """Whether the effect ``name`` reads a row-blocked image in place (a blur or sharpen whose radius is at
    most GAUSS_PLAIN_V; the unsharp mask's own fetch of it too)."""
    from postfx import effects

    return name in ("blur", "sharpen") and (effects.gaussian_weights(params.sigma_px).size - 1) // 2 <= shaders.GAUSS_PLAIN_V


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
    its last pass) and the total seconds including the transfers. ``keep_awake`` threads spin while it
    runs unless TISSUERENDER_GL_KEEP_AWAKE=0.

    The passes are queued without waiting for each other: llvmpipe's threads go from one pass to the
    next while this thread prepares the ones after, instead of sleeping after every effect (on this
    2-vCPU VM each such wake-up cost up to ~0.5 ms: the rendered benchmark frame 44.2 ms with a wait
    after each effect, 34.9 ms without, same process, alternating). An effect's seconds come from GL
    timestamps: from the end of the effect before it (for the first, from the chain's start on the CPU,
    after the frame's upload, when llvmpipe's clock is the monotonic one; a DoF that comes first builds
    and uploads its own source, which counts) to the end of its own last pass."""
    from postfx import keep_awake

    ctx = Context.get()
    awake = keep_awake.KeepAwake.get() if keep_awake.enabled() else contextlib.nullcontext()
    start = time.perf_counter()
    with awake:  # idle-priority threads keep the CPUs from halting while llvmpipe's threads sleep and wake
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
