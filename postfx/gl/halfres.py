"""Half-resolution passes of bloom and lens flare, mirroring ``postfx.kernels``: the 2x2 mean of the part
above a luminance threshold, and the bilinear upsampling added back to the image."""
from __future__ import annotations

from postfx.gl.library import IVec2
from postfx.gl.shaders import HEADER, OUT_PIXEL, PIXEL, register
from postfx.kernels import LUMA

# half resolution: the 2x2 mean of the part above threshold in luminance (kernels._bright_half)
BRIGHT_HALF = register("bright_half", HEADER + "uniform sampler2D img;\nuniform float threshold;\nuniform vec3 luma;\n"
                       "uniform ivec2 out_size;\nuniform int use_threshold;\n" + """
vec3 part(vec3 x) {
  if (use_threshold == 1) {
    float l = dot(luma, x);
    x *= max(l - threshold, 0.0) / max(l, 1e-12);
  }
  return x;
}
void main() {
  ivec2 size = textureSize(img, 0);
  vec2 inv = 1.0 / vec2(size);
""" + OUT_PIXEL + """  ivec2 q0 = 2 * p, q1 = min(2 * p + 1, size - 1);
  vec3 acc = part(texture(img, (vec2(q0.x, q0.y) + 0.5) * inv).rgb);
  acc += part(texture(img, (vec2(q1.x, q0.y) + 0.5) * inv).rgb);
  acc += part(texture(img, (vec2(q0.x, q1.y) + 0.5) * inv).rgb);
  acc += part(texture(img, (vec2(q1.x, q1.y) + 0.5) * inv).rgb);
  gl_FragData[0] = vec4(acc * 0.25, 1.0);
}
""")

# img + k up(low), low at half resolution read bilinearly at ((i + 1/2) / 2, (j + 1/2) / 2)
ADD_UPSAMPLED = register("add_upsampled", HEADER + "uniform sampler2D img;\nuniform sampler2D low;\nuniform float k;\n"
                         "//EPILOGUE::Dec\n" + """
void main() {
""" + PIXEL + """  // bilinear at ((i + 1/2) / 2, (j + 1/2) / 2) half-res texels: the sampler's linear filter (clamped)
  vec3 up = texture(low, (vec2(p) + 0.5) * 0.5 / vec2(textureSize(low, 0))).rgb;
  gl_FragData[0] = vec4(post(texture(img, texCoord).rgb + k * up, p, size), 1.0);
}
""")


def half(ctx, tex, threshold=None):
    """2x2 block mean at half resolution, of the part above ``threshold`` when given (kernels._bright_half)."""
    w, h = (tex.GetWidth() + 1) // 2, (tex.GetHeight() + 1) // 2
    uniforms = {"out_size": IVec2((w, h)), "use_threshold": int(threshold is not None),
                "threshold": float(threshold or 0.0), "luma": LUMA}
    return ctx.draw(BRIGHT_HALF, {"img": tex}, uniforms, w, h)


def add_upsampled(ctx, tex, low, k, ep):
    """``tex + k up(low)`` (kernels.add_upsampled) with the pointwise epilogue ``ep``; releases ``low``."""
    out = ctx.draw(ADD_UPSAMPLED, {"img": tex, "low": low, **ep.inputs}, {"k": float(k), **ep.uniforms},
                   tex.GetWidth(), tex.GetHeight(), epilogue=ep.passes, linear={"low": False})
    ctx.release(low)
    return out
