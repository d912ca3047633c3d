"""The OSMesa backend: every post-effect as a GLSL fragment pass, rendered off-screen through VTK's
``vtkOSOpenGLRenderWindow`` (the VTK wheel plus Debian ``libosmesa6``), float textures in, float
results read back. No window and no X server. See ``../shared/notes/osmesa.md`` for the path used.

The shaders mirror ``postfx.effects`` line by line (manual bilinear through ``texelFetch``, the same
clamping), so the two backends agree to float32 rounding.
"""
from __future__ import annotations

import ctypes
import math

import numpy as np

GL_FLOAT = 0x1406
GL_RGBA = 0x1908
LIBRARIES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")

_HEADER = """//VTK::System::Dec
in vec2 texCoord;
//VTK::Output::Dec
"""

_BILINEAR = """
float bilinear(sampler2D tex, int channel, float x, float y) {
  ivec2 size = textureSize(tex, 0);
  float w = float(size.x), h = float(size.y);
  float fx = clamp(x - 0.5, 0.0, w - 1.0);
  float fy = clamp(y - 0.5, 0.0, h - 1.0);
  int x0 = size.x > 1 ? min(int(fx), size.x - 2) : 0;
  int y0 = size.y > 1 ? min(int(fy), size.y - 2) : 0;
  float tx = fx - float(x0), ty = fy - float(y0);
  int x1 = min(x0 + 1, size.x - 1), y1 = min(y0 + 1, size.y - 1);
  float top = texelFetch(tex, ivec2(x0, y0), 0)[channel] * (1.0 - tx) + texelFetch(tex, ivec2(x1, y0), 0)[channel] * tx;
  float bottom = texelFetch(tex, ivec2(x0, y1), 0)[channel] * (1.0 - tx) + texelFetch(tex, ivec2(x1, y1), 0)[channel] * tx;
  return top * (1.0 - ty) + bottom * ty;
}
"""

# Row 0 uploaded is row 0 read back (osmesa.md), so texel (i, j) is image pixel (column i, row j).
_PIXEL = "  ivec2 size = textureSize(img, 0);\n  ivec2 p = ivec2(texCoord * vec2(size));\n"

SHADERS = {
    "chromatic_aberration": _HEADER + "uniform sampler2D img;\nuniform vec3 scale;\nuniform vec2 centre;\n" + _BILINEAR + """
void main() {
""" + _PIXEL + """  float x = float(p.x) + 0.5, y = float(p.y) + 0.5;
  vec3 rgb;
  for (int c = 0; c < 3; ++c) {
    rgb[c] = bilinear(img, c, centre.x + (x - centre.x) * scale[c], centre.y + (y - centre.y) * scale[c]);
  }
  gl_FragData[0] = vec4(rgb, 1.0);
}
""",
    "tonemap": _HEADER + "uniform sampler2D img;\nuniform float gain;\nuniform int curve;\nuniform int srgb;\n" + """
float encode(float x) {
  x = clamp(x, 0.0, 1.0);
  return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}
void main() {
""" + _PIXEL + """  vec3 x = max(texelFetch(img, p, 0).rgb, vec3(0.0)) * gain;
  vec3 y;
  if (curve == 0) y = clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
  else if (curve == 1) y = x / (1.0 + x);
  else y = clamp(x, 0.0, 1.0);
  if (srgb == 1) y = vec3(encode(y.r), encode(y.g), encode(y.b));
  gl_FragData[0] = vec4(y, 1.0);
}
""",
    "laparoscope_mask": _HEADER + "uniform sampler2D img;\nuniform vec2 centre;\nuniform float radius;\n"
    "uniform float softness;\nuniform float vignette;\n" + """
void main() {
""" + _PIXEL + """  float x = float(p.x) + 0.5, y = float(p.y) + 0.5;
  float rho = length(vec2(x - centre.x, y - centre.y)) / (0.5 * float(size.y));
  float edge;
  if (softness == 0.0) edge = rho <= radius ? 1.0 : 0.0;
  else {
    float t = clamp((rho - (radius - 0.5 * softness)) / softness, 0.0, 1.0);
    edge = 1.0 - t * t * (3.0 - 2.0 * t);
  }
  float r = clamp(rho / radius, 0.0, 1.0);
  float weight = edge * (1.0 - vignette * r * r);
  gl_FragData[0] = vec4(texelFetch(img, p, 0).rgb * weight, 1.0);
}
""",
    "color_grade": _HEADER + "uniform sampler2D img;\nuniform sampler2D lut;\nuniform float saturation;\n"
    "uniform vec3 luma;\n" + """
float lookup(float x, int c) {
  int n = textureSize(lut, 0).x;
  float f = clamp(x, 0.0, 1.0) * float(n - 1);
  int k = min(int(f), n - 2);
  float a = texelFetch(lut, ivec2(k, 0), 0)[c];
  return a + (f - float(k)) * (texelFetch(lut, ivec2(k + 1, 0), 0)[c] - a);
}
void main() {
""" + _PIXEL + """  vec3 x = texelFetch(img, p, 0).rgb;
  vec3 y = vec3(lookup(x.r, 0), lookup(x.g, 1), lookup(x.b, 2));
  float l = dot(luma, y);
  gl_FragData[0] = vec4(clamp(vec3(l) + saturation * (y - vec3(l)), 0.0, 1.0), 1.0);
}
""",
    # one direction of the separable Gaussian (weights exp(-x^2 / 2 sigma^2) normalised, edges clamped)
    "gauss_1d": _HEADER + "uniform sampler2D img;\nuniform int R;\nuniform float sigma;\nuniform vec2 dir;\n" + """
void main() {
""" + _PIXEL + """  vec3 acc = vec3(0.0);
  float wsum = 0.0;
  for (int k = -R; k <= R; ++k) {
    float w = exp(-0.5 * (float(k) / sigma) * (float(k) / sigma));
    ivec2 q = clamp(p + ivec2(dir) * k, ivec2(0), size - 1);
    acc += w * texelFetch(img, q, 0).rgb;
    wsum += w;
  }
  gl_FragData[0] = vec4(acc / wsum, 1.0);
}
""",
    "bright": _HEADER + "uniform sampler2D img;\nuniform float threshold;\nuniform vec3 luma;\n" + """
void main() {
""" + _PIXEL + """  vec3 x = texelFetch(img, p, 0).rgb;
  float l = dot(luma, x);
  gl_FragData[0] = vec4(x * max(l - threshold, 0.0) / max(l, 1e-12), 1.0);
}
""",
    # a + k (a - b) clipped (sharpen, k = amount) or a + k b (bloom, mode 1)
    "combine": _HEADER + "uniform sampler2D a;\nuniform sampler2D b;\nuniform float k;\nuniform int mode;\n" + """
void main() {
  ivec2 size = textureSize(a, 0);
  ivec2 p = ivec2(texCoord * vec2(size));
  vec3 x = texelFetch(a, p, 0).rgb, y = texelFetch(b, p, 0).rgb;
  vec3 r = mode == 0 ? clamp(x + k * (x - y), 0.0, 1.0) : x + k * y;
  gl_FragData[0] = vec4(r, 1.0);
}
""",
    "noise": _HEADER + "uniform sampler2D img;\nuniform sampler2D z;\nuniform float shot;\nuniform float rd;\n" + """
void main() {
""" + _PIXEL + """  vec3 x = texelFetch(img, p, 0).rgb;
  vec3 sd = sqrt(max(x, 0.0) * shot + rd * rd);
  gl_FragData[0] = vec4(max(x + sd * texelFetch(z, p, 0).rgb, 0.0), 1.0);
}
""",
    "depth_of_field": _HEADER + "uniform sampler2D src;\nuniform int R;\nuniform float r2max;\n" + """
// src = (r w, g w, b w, reach^2) with w = 1 / (pi max(reach^2 - 1/4, 1/4)): one fetch per tap. It is
// padded by R texels of reach -1 on every side (never inside a disc), so taps need no bounds test.
void main() {
  ivec2 p = ivec2(texCoord * vec2(textureSize(src, 0) - 2 * R)) + ivec2(R);
  vec4 acc = vec4(0.0);
  for (int dj = -R; dj <= R; ++dj) {
    int span = int(floor(sqrt(max(r2max - float(dj * dj), 0.0))));
    for (int di = -span; di <= span; ++di) {
      vec4 s = texelFetch(src, p + ivec2(di, dj), 0);
      if (float(di * di + dj * dj) <= s.a) {
        acc += vec4(s.rgb, 1.0 / (3.14159265358979 * max(s.a - 0.25, 0.25)));
      }
    }
  }
  gl_FragData[0] = vec4(acc.rgb / acc.a, 1.0);
}
""",
}


def library_available() -> bool:
    for name in LIBRARIES:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


class Context:
    """One off-screen OpenGL context per process, created on first use and reused."""

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
        from vtkmodules.vtkRenderingOpenGL2 import (vtkOpenGLRenderUtilities, vtkOSOpenGLRenderWindow,
                                                    vtkPixelBufferObject)

        self.window = vtkOSOpenGLRenderWindow()
        self.window.SetOffScreenRendering(1)
        self.window.SetSize(16, 16)
        self.window.Initialize()
        if self.window.GetGenericContext() is None:
            raise OSMesaUnavailable("VTK could not create an OSMesa context (check libosmesa6)")
        self.vertex_shader = vtkOpenGLRenderUtilities.GetFullScreenQuadVertexShader()
        self.pbo = vtkPixelBufferObject()
        self.pbo.SetContext(self.window)
        self.quads = {}

    def _texture(self, array: np.ndarray):
        from vtkmodules.util.numpy_support import numpy_to_vtk
        from vtkmodules.vtkCommonCore import VTK_FLOAT
        from vtkmodules.vtkRenderingOpenGL2 import vtkTextureObject

        h, w = array.shape[:2]
        channels = 1 if array.ndim == 2 else array.shape[2]
        data = numpy_to_vtk(np.ascontiguousarray(array, dtype=np.float32).reshape(-1, channels), deep=True)
        tex = vtkTextureObject()
        tex.SetContext(self.window)
        tex.Create2DFromRaw(w, h, channels, VTK_FLOAT, data)
        tex.SetMinificationFilter(vtkTextureObject.Nearest)
        tex.SetMagnificationFilter(vtkTextureObject.Nearest)
        tex.SetWrapS(vtkTextureObject.ClampToEdge)
        tex.SetWrapT(vtkTextureObject.ClampToEdge)
        return tex, data

    def run(self, name: str, inputs: dict[str, np.ndarray], uniforms: dict, width: int, height: int) -> np.ndarray:
        """Draw the full-screen pass ``name`` into a float target and read back (H, W, 3) float32."""
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkCommonCore import VTK_FLOAT, vtkFloatArray
        from vtkmodules.vtkRenderingOpenGL2 import (vtkOpenGLFramebufferObject, vtkOpenGLQuadHelper,
                                                    vtkTextureObject)

        fs = SHADERS[name]
        if name not in self.quads:
            self.quads[name] = vtkOpenGLQuadHelper(self.window, self.vertex_shader, fs, "")
        quad = self.quads[name]
        textures = {key: self._texture(arr) for key, arr in inputs.items()}
        target = vtkTextureObject()
        target.SetContext(self.window)
        target.Allocate2D(width, height, 4, VTK_FLOAT)
        fbo = vtkOpenGLFramebufferObject()
        fbo.SetContext(self.window)
        fbo.SaveCurrentBindingsAndBuffers()
        try:
            fbo.Bind()
            fbo.AddColorAttachment(0, target)
            fbo.ActivateDrawBuffer(0)
            fbo.Start(width, height)
            program = self.window.GetShaderCache().ReadyShaderProgram(self.vertex_shader, fs, "")
            for key, (tex, _) in textures.items():
                tex.Activate()
                program.SetUniformi(key, tex.GetTextureUnit())
            for key, value in uniforms.items():
                if isinstance(value, int):
                    program.SetUniformi(key, value)
                elif np.ndim(value) == 0:
                    program.SetUniformf(key, float(value))
                elif len(value) == 2:
                    program.SetUniform2f(key, [float(v) for v in value])
                else:
                    program.SetUniform3f(key, [float(v) for v in value])
            quad.Render()
            for tex, _ in textures.values():
                tex.Deactivate()
            vtkOpenGLFramebufferObject.Download([0, width - 1, 0, height - 1], VTK_FLOAT, 4, GL_FLOAT, GL_RGBA,
                                                self.pbo)
            out = vtkFloatArray()
            out.SetNumberOfComponents(4)
            out.SetNumberOfTuples(width * height)
            self.pbo.Download2D(VTK_FLOAT, out.GetVoidPointer(0), [width, height], 4, [0, 0])
        finally:
            fbo.RestorePreviousBindingsAndBuffers()
        return vtk_to_numpy(out).reshape(height, width, 4)[..., :3].copy()


def _gaussian(ctx, img, sigma):
    h, w, _ = img.shape
    R = int(math.ceil(3.0 * sigma))
    horizontal = ctx.run("gauss_1d", {"img": img}, {"R": R, "sigma": float(sigma), "dir": (1.0, 0.0)}, w, h)
    return ctx.run("gauss_1d", {"img": horizontal}, {"R": R, "sigma": float(sigma), "dir": (0.0, 1.0)}, w, h)


def apply_effect(name: str, img: np.ndarray, depth: np.ndarray, params, lens, seed: int = 0) -> np.ndarray:
    """One effect on the GPU path; same signature and meaning as :func:`postfx.apply_effect`."""
    from postfx import effects

    ctx = Context.get()
    h, w, _ = img.shape
    if name == "blur":
        return _gaussian(ctx, img, params.sigma_px)
    if name == "sharpen":
        return ctx.run("combine", {"a": img, "b": _gaussian(ctx, img, params.sigma_px)},
                       {"k": float(params.amount), "mode": 0}, w, h)
    if name == "bloom":
        bright = ctx.run("bright", {"img": img}, {"threshold": float(params.threshold), "luma": effects.LUMA}, w, h)
        return ctx.run("combine", {"a": img, "b": _gaussian(ctx, bright, params.sigma_px)},
                       {"k": float(params.intensity), "mode": 1}, w, h)
    if name == "sensor_noise":
        return ctx.run("noise", {"img": img, "z": effects.noise_field(img.shape, seed)},
                       {"shot": float(params.shot), "rd": float(params.read)}, w, h)
    if name == "chromatic_aberration":
        scale = [1.0 / (1.0 + k) if k > -1.0 else 1e6 for k in (params.strength_r, params.strength_g, params.strength_b)]
        return ctx.run(name, {"img": img}, {"scale": scale, "centre": (params.centre[0] * w, params.centre[1] * h)}, w, h)
    if name == "tonemap":
        curve = {"aces": 0, "reinhard": 1, "clamp": 2}[params.curve]
        return ctx.run(name, {"img": img}, {"gain": 2.0 ** params.exposure, "curve": curve,
                                            "srgb": int(params.srgb)}, w, h)
    if name == "laparoscope_mask":
        centre = (w * (0.5 + params.offset[0]), h * (0.5 + params.offset[1]))
        return ctx.run(name, {"img": img}, {"centre": centre, "radius": params.radius, "softness": params.softness,
                                            "vignette": params.vignette}, w, h)
    if name == "color_grade":
        lut = effects.grade_lut(params)[None, :, :]  # a LUT_SIZE x 1 float texture
        return ctx.run(name, {"img": img, "lut": lut}, {"saturation": params.saturation, "luma": effects.LUMA}, w, h)
    if name == "depth_of_field":
        coc = effects.coc_radius_px(depth, params, lens.fov_deg, w)
        if float(coc.max()) < 0.5:
            return img.copy()
        src = effects.dof_source(img, coc)  # premultiplied colour, weight, reach r^2 + 1/4
        rmax = float(coc.max())
        R = int(math.ceil(rmax))
        padded = np.zeros((h + 2 * R, w + 2 * R, 4), np.float32)
        padded[..., 3] = -1.0
        padded[R:R + h, R:R + w] = src[..., [0, 1, 2, 4]]
        return ctx.run(name, {"src": padded}, {"R": R, "r2max": rmax * rmax + 0.25}, w, h)
    raise KeyError(f"unknown post-effect {name!r}")
