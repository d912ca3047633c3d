"""The OpenGL library under VTK's OSMesa window (Debian ``libosmesa6``), the GL enums the backend calls
it with, and the uniform values a pass sets."""
from __future__ import annotations

import ctypes

import numpy as np

from postfx.errors import OSMesaUnavailable

GL_FLOAT = 0x1406
GL_RGB = 0x1907
GL_RGBA = 0x1908
GL_FORMATS = {1: 0x1903, 2: 0x8227, 3: GL_RGB, 4: GL_RGBA}  # GL_RED, GL_RG, GL_RGB, GL_RGBA
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


def gl_library():
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


class GLCalls:
    """The libOSMesa calls VTK does not wrap (image stores, memory barriers, reads and sub-uploads into
    client memory), with their argument types, and the GL 3.3 query calls that libOSMesa does not export
    by name, through its ``OSMesaGetProcAddress``. Valid while an OSMesa context is current."""

    def __init__(self):
        lib = self.lib = gl_library()
        lib.glBindImageTexture.argtypes = [ctypes.c_uint, ctypes.c_uint, ctypes.c_int, ctypes.c_ubyte,
                                           ctypes.c_int, ctypes.c_uint, ctypes.c_uint]
        lib.glMemoryBarrier.argtypes = [ctypes.c_uint]
        lib.glBindBuffer.argtypes = [ctypes.c_uint, ctypes.c_uint]
        lib.glPixelStorei.argtypes = [ctypes.c_uint, ctypes.c_int]
        lib.glReadPixels.argtypes = [ctypes.c_int] * 4 + [ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p]
        lib.glTexSubImage2D.argtypes = [ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                        ctypes.c_int, ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p]
        lib.glGetString.restype, lib.glGetString.argtypes = ctypes.c_char_p, [ctypes.c_uint]
        self.address = lib.OSMesaGetProcAddress
        self.address.restype, self.address.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
        self.query_counter = self.proc("glQueryCounter", ctypes.c_uint, ctypes.c_uint)
        self.query_result = self.proc("glGetQueryObjectui64v", ctypes.c_uint, ctypes.c_uint,
                                      ctypes.POINTER(ctypes.c_uint64))
        self.gen_queries = self.proc("glGenQueries", ctypes.c_int, ctypes.POINTER(ctypes.c_uint))
        self.get_int64 = self.proc("glGetInteger64v", ctypes.c_uint, ctypes.POINTER(ctypes.c_int64))

    def proc(self, name, *argtypes):
        pointer = self.address(name.encode())
        if not pointer:
            raise OSMesaUnavailable(f"libOSMesa has no {name} (OpenGL 3.3 is needed)")
        return ctypes.CFUNCTYPE(None, *argtypes)(pointer)


class FloatArray(tuple):
    """A ``uniform float name[n]`` value."""


class Vec4Array(tuple):
    """A ``uniform vec4 name[n]`` value (flat, 4 floats per element)."""


class IVec2(tuple):
    """A ``uniform ivec2`` value."""


def canonical(value):
    """A value of ``set_uniform`` in a form that compares equal exactly when the program would receive
    the same values (uniform names keep one type)."""
    if isinstance(value, tuple):  # FloatArray, Vec4Array, IVec2, pairs
        return value
    if isinstance(value, list):
        return tuple(value)
    if isinstance(value, np.ndarray):
        return value.tobytes()
    return value


def set_uniform(program, key, value):
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
