"""Shader text every GL pass shares: the fragment shader header, the pixel of a fragment, the
registry of passes by name, and the pointwise epilogue appended to a pass.

Each effect's passes mirror its NumPy kernel: the same taps, clamping and weights, so the two backends
agree to float32 rounding (bilinear reads: to the rounding of the texture coordinate).

Conventions: texel (i, j) is image pixel (column i, row j) (row 0 uploaded is row 0 read back);
``texture()`` with nearest filtering at texel centres is ``texelFetch`` with the texture's wrap mode
(clamp to edge = clamped indices, clamp to border = a constant outside), and llvmpipe runs it faster
than ``texelFetch``; a pass that reads bilinearly has the sampler's linear filter switched on for that
input (``Context.draw(linear=...)``): llvmpipe interpolates float textures with float32 weights, clamped
or with a zero border as the NumPy kernels, one fetch instead of four.

Pointwise effects (sensor noise, tone map, colour grade, mask: each output pixel depends only on the
same input pixel) are GLSL functions ``fx_<effect>`` with their own uniform names. ``source(name,
epilogue)`` appends a run of them to the last pass of another effect (``post()`` in that pass), so
a chain such as blur -> noise -> tone map -> grade draws one full-resolution pass where it would draw four.
"""
from __future__ import annotations

import functools

HEADER = """//VTK::System::Dec
in vec2 texCoord;
//VTK::Output::Dec
"""

# a pass that also writes images (imageStore): GLSL 1.50 plus the extension (core in GL 4.2)
IMAGE_HEADER = HEADER.replace("//VTK::System::Dec",
                              "//VTK::System::Dec\n#extension GL_ARB_shader_image_load_store : require")

# the fragment's pixel when the output has the input's size
PIXEL = "  ivec2 size = textureSize(img, 0);\n  ivec2 p = ivec2(texCoord * vec2(size));\n"

# the output's own pixel when the output size differs from the input's
OUT_PIXEL = "  ivec2 p = ivec2(texCoord * vec2(out_size));\n"

SHADERS = {
    # texture() at texCoord (the fragment's own texel centre, the viewport being the image's size) reads
    # the same texel as texelFetch(img, p, 0), faster on llvmpipe
    "copy": HEADER + "uniform sampler2D img;\n//EPILOGUE::Dec\nvoid main() {\n" + PIXEL
    + "  gl_FragData[0] = vec4(post(texture(img, texCoord).rgb, p, size), 1.0);\n}\n",
    # a run of pointwise effects on their own (the first effect of a chain, or fusion switched off)
    "pointwise": HEADER + "uniform sampler2D img;\n//EPILOGUE::Dec\nvoid main() {\n" + PIXEL
    + "  gl_FragData[0] = vec4(post(texture(img, texCoord).rgb, p, size), 1.0);\n}\n",
}


def register(name: str, text: str) -> str:
    """Add the fragment shader ``text`` under ``name`` (a pass that takes a pointwise epilogue marks where
    its declarations go with ``//EPILOGUE::Dec`` and writes ``post(rgb, p, size)``); returns ``name``."""
    SHADERS[name] = text
    return name


@functools.lru_cache(maxsize=None)
def source(name: str, epilogue: tuple[tuple[str, str], ...] = ()) -> str:
    """The fragment shader ``name`` with the pointwise effects ``epilogue`` (``(effect, GLSL)`` pairs)
    applied, in order, to what it writes (``post()``; the identity for an empty epilogue)."""
    fs = SHADERS[name]
    if "//EPILOGUE::Dec" not in fs:
        if epilogue:
            raise ValueError(f"pass {name!r} takes no pointwise epilogue")
        return fs
    calls = "".join(f"  x = fx_{effect}(x, p, size);\n" for effect, _ in epilogue)
    dec = "".join(glsl for glsl in dict.fromkeys(glsl for _, glsl in epilogue))
    return fs.replace("//EPILOGUE::Dec", dec + "vec3 post(vec3 x, ivec2 p, ivec2 size) {\n" + calls + "  return x;\n}\n")


class Epilogue:
    """Pointwise effects drawn inside another pass: ``passes`` (``(effect, GLSL)`` pairs, in order, for
    ``source``), and the textures and uniforms their functions read."""

    def __init__(self):
        self.passes: tuple[tuple[str, str], ...] = ()
        self.inputs: dict = {}
        self.uniforms: dict = {}

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(effect for effect, _ in self.passes)

    def add(self, effect: str, glsl: str, inputs: dict, uniforms: dict) -> None:
        if any(key in self.inputs for key in inputs):
            raise ValueError(f"one {effect} per fused pass")
        self.passes += ((effect, glsl),)
        self.inputs.update(inputs)
        self.uniforms.update(uniforms)
