"""The OpenGL library under VTK's OSMesa window (Debian ``libosmesa6``), the GL enums the backend calls
it with, and the uniform values a pass sets."""
from __future__ import annotations

import ctypes

import numpy as np

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
