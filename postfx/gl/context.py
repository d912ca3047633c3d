"""The off-screen OpenGL context of the GL backend: VTK's ``vtkOSOpenGLRenderWindow`` (the VTK wheel plus
Debian ``libosmesa6``), no window and no X server (the path used: ``../shared/notes/osmesa.md``). It
uploads float images, keeps a pool of float render targets, draws full-screen passes from texture to
texture, reads results back, and stamps the GL timeline so that a queued chain can be timed without
waiting for each pass.
"""
from __future__ import annotations

import ctypes
import time

import numpy as np
from numba import njit

from postfx.errors import OSMesaUnavailable
from postfx.gl import shaders
from postfx.gl.library import (GL_ALL_BARRIER_BITS, GL_FLOAT, GL_FORMATS, GL_PACK_ALIGNMENT, GL_PACK_ROW_LENGTH,
                               GL_PIXEL_PACK_BUFFER, GL_PIXEL_UNPACK_BUFFER, GL_QUERY_RESULT, GL_RENDERER, GL_RGBA,
                               GL_RGBA32F, GL_TEXTURE_2D, GL_TIMESTAMP, GL_UNPACK_ALIGNMENT, GL_WRITE_ONLY, GLCalls,
                               canonical, library_available, set_uniform)


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
        # Without libOSMesa VTK only warns and the next GL call segfaults: check first.
        if not library_available():
            raise OSMesaUnavailable("libOSMesa is not installed; install the Debian package libosmesa6 "
                                    "(apt-get install libosmesa6) or use backend = \"numpy\"")
        try:
            self._open_window()
        except (ImportError, OSError) as e:
            # a VTK without the off-screen window class (the PyPI wheel before 9.4), or a library it or the
            # GL calls need that does not load: the backend cannot run here, which "auto" falls back from
            cause = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise OSMesaUnavailable(f"VTK's off-screen window (vtkOSOpenGLRenderWindow) cannot be created: {cause}; "
                                    f"install vtk>=9.4 and libosmesa6, or use backend = \"numpy\"") from e
        self.quads = {}
        calls = self._gl_calls
        self.gl = calls.lib
        self._query_counter, self._query_result, self._gen_queries = calls.query_counter, calls.query_result, calls.gen_queries
        self.queries: list[int] = []
        # llvmpipe stamps with CLOCK_MONOTONIC, Python's monotonic clock: then an effect's seconds can start
        # at the chain's start on the CPU (the DoF's CPU steps count); checked, not assumed
        now, gl_now = time.monotonic_ns(), ctypes.c_int64()
        calls.get_int64(GL_TIMESTAMP, ctypes.byref(gl_now))
        self.shared_clock = abs(gl_now.value - now) < 5_000_000
        self.renderer = (self.gl.glGetString(GL_RENDERER) or b"").decode(errors="replace")
        # imageStore results reach later passes' texture fetches after a glMemoryBarrier, which llvmpipe
        # (Mesa 22.3) implements as a full finish: this thread sleeps until the gather has run, and the
        # rasterizer threads until it has queued the next pass. llvmpipe runs each pass (scene) after the
        # one before it has finished on every thread, and its stores go straight to the texture's memory,
        # so there the later passes read the stored values without it (tested: the same bits); other
        # drivers get it.
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

    def _open_window(self) -> None:
        """VTK's OSMesa window with a current context, the full-screen pass helpers and the GL calls VTK
        does not wrap; ImportError or OSError where VTK or a library cannot load."""
        # VTK is imported here, not at the top: it is heavy, and the NumPy backend and the scene schema
        # import postfx without needing it
        from vtkmodules.util.numpy_support import numpy_to_vtk
        from vtkmodules.vtkCommonCore import VTK_FLOAT
        from vtkmodules.vtkRenderingOpenGL2 import (vtkOpenGLFramebufferObject, vtkOpenGLQuadHelper,
                                                    vtkOpenGLRenderUtilities, vtkOSOpenGLRenderWindow,
                                                    vtkTextureObject)

        self._numpy_to_vtk, self._vtk_float, self._texture_object = numpy_to_vtk, VTK_FLOAT, vtkTextureObject
        self._quad_helper = vtkOpenGLQuadHelper
        self.window = vtkOSOpenGLRenderWindow()
        self.window.SetOffScreenRendering(1)
        self.window.SetSize(16, 16)
        self.window.Initialize()
        if self.window.GetGenericContext() is None:
            raise OSMesaUnavailable("VTK could not create an OSMesa context (check libosmesa6)")
        self.vertex_shader = vtkOpenGLRenderUtilities.GetFullScreenQuadVertexShader()
        self.fbo = vtkOpenGLFramebufferObject()
        self.fbo.SetContext(self.window)
        # VTK wraps no image-store calls and reads back through a pixel buffer: these calls come straight
        # from the library VTK uses (its context is current on this thread)
        self._gl_calls = GLCalls()

    # -- textures -------------------------------------------------------------------------------
    def _filtering(self, tex, border=None):
        vtkTextureObject = self._texture_object
        tex.SetMinificationFilter(vtkTextureObject.Nearest)
        tex.SetMagnificationFilter(vtkTextureObject.Nearest)
        wrap = vtkTextureObject.ClampToEdge if border is None else vtkTextureObject.ClampToBorder
        tex.SetWrapS(wrap)
        tex.SetWrapT(wrap)
        if border is not None:
            tex.SetBorderColor(*border)
        return tex

    def _linear(self, tex, zero_outside: bool):
        """Bilinear filtering: llvmpipe interpolates float textures with float32 weights, the
        arithmetic of kernels.bilinear_clamped / lens_flare.bilinear_zero up to float rounding of the
        coordinate (measured at 640x480: 7e-6 for the bloom's upsampling), for one fetch instead of four."""
        vtkTextureObject = self._texture_object
        tex.SetMinificationFilter(vtkTextureObject.Linear)
        tex.SetMagnificationFilter(vtkTextureObject.Linear)
        wrap = vtkTextureObject.ClampToBorder if zero_outside else vtkTextureObject.ClampToEdge
        tex.SetWrapS(wrap)
        tex.SetWrapT(wrap)
        if zero_outside:
            tex.SetBorderColor(0.0, 0.0, 0.0, 0.0)

    def upload(self, array: np.ndarray):
        """A float texture holding ``array`` ((H, W) or (H, W, C), C <= 4)."""
        h, w = array.shape[:2]
        channels = 1 if array.ndim == 2 else array.shape[2]
        data = self._numpy_to_vtk(np.ascontiguousarray(array, dtype=np.float32).reshape(-1, channels), deep=False)
        tex = self._texture_object()
        tex.SetContext(self.window)
        tex.Create2DFromRaw(w, h, channels, self._vtk_float, data)  # copied into GL here
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
        repeats (faster than a new texture, see docs/postfx.md, "How fast, and why"). The texture holds
        ``array`` until the next upload under the same key (GL orders that upload after every pass drawn
        before it)."""
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
        self.gl.glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, w, h, GL_FORMATS[channels], GL_FLOAT,
                                np.ascontiguousarray(array, dtype=np.float32).ctypes.data)
        tex.Deactivate()
        return tex

    def target(self, width: int, height: int, border=None, layers: int = 0):
        """An RGBA32F texture from the pool (contents undefined until drawn); with ``layers``, a 3D
        texture of that depth (one draw buffer per layer)."""
        free = self.free.get((width, height, layers))
        if free:
            tex = free.pop()
        else:
            tex = self._texture_object()
            tex.SetContext(self.window)
            if layers:
                tex.Allocate3D(width, height, layers, 4, self._vtk_float)
            else:
                tex.Allocate2D(width, height, 4, self._vtk_float)
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
        """Draw the full-screen pass ``name`` (with the pointwise ``epilogue``, ``(effect, GLSL)`` pairs:
        ``Epilogue.passes``, see ``shaders.source``) reading
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
            self.quads[fs] = self._quad_helper(self.window, self.vertex_shader, fs, "")
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
            # a program keeps its uniforms: set only those that changed since its last draw (each call
            # through VTK's wrapping costs, and most of them are the same every frame)
            known = self.uniform_values.setdefault(fs, {})
            for key, tex in inputs.items():
                tex.Activate()
                unit = tex.GetTextureUnit()
                if known.get(key) != unit:
                    program.SetUniformi(key, unit)
                    known[key] = unit
            for key, value in uniforms.items():
                held = canonical(value)
                if known.get(key) != held:
                    set_uniform(program, key, value)
                    known[key] = held
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
            key = f"{'+'.join((name, *(effect for effect, _ in epilogue)))} {width}x{height}"
            self.profile[key] = self.profile.get(key, 0.0) + time.perf_counter() - t0
        return target

    def note(self, key: str, t0: float):
        """Add the seconds since ``t0`` to the profile (when one is kept) under ``key``."""
        if self.profile is not None:
            self.profile[key] = self.profile.get(key, 0.0) + time.perf_counter() - t0

    def download(self, tex, clip: bool = False) -> np.ndarray:
        """Read a target back as a new (H, W, 3) float32 array, clipped to [0, 1] with ``clip``.

        glReadPixels of RGBA into a host array kept from call to call (RGBA32F to RGBA is a copy in Mesa,
        where RGB converts, and a new array would fault its pages in on every call), then the RGB
        channels into the result in one loop (faster than NumPy's clip of the strided view). A row-blocked
        target (``row_blocked``: layer k holds rows k, k + L, ...) is read layer by layer, each row landing
        in its place (GL_PACK_ROW_LENGTH of L rows)."""
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

