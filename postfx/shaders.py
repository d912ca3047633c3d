"""GLSL fragment passes of the OSMesa backend (``postfx.osmesa`` draws them). Each mirrors a kernel of
``postfx.effects`` / ``postfx.lens_flare`` line by line: the same taps, clamping and bilinear weights
(manual, through ``texelFetch``), so the two backends agree to float32 rounding.

Conventions: texel (i, j) is image pixel (column i, row j) (row 0 uploaded is row 0 read back);
``texture()`` is used only with nearest filtering at texel centres, where it is ``texelFetch`` with the
texture's wrap mode (clamp to edge = clamped indices, clamp to border = a constant outside).
"""
from __future__ import annotations

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

# the same bilinear weights on all three channels at once, zero outside the texture
_BILINEAR_ZERO = """
vec3 texel0(sampler2D tex, ivec2 q) {
  ivec2 size = textureSize(tex, 0);
  return (q.x < 0 || q.y < 0 || q.x >= size.x || q.y >= size.y) ? vec3(0.0) : texelFetch(tex, q, 0).rgb;
}
vec3 bilinear_zero(sampler2D tex, float x, float y) {
  float fx = x - 0.5, fy = y - 0.5;
  float x0f = floor(fx), y0f = floor(fy);
  float tx = fx - x0f, ty = fy - y0f;
  ivec2 q = ivec2(int(x0f), int(y0f));
  vec3 top = texel0(tex, q) * (1.0 - tx) + texel0(tex, q + ivec2(1, 0)) * tx;
  vec3 bottom = texel0(tex, q + ivec2(0, 1)) * (1.0 - tx) + texel0(tex, q + ivec2(1, 1)) * tx;
  return top * (1.0 - ty) + bottom * ty;
}
"""

_PIXEL = "  ivec2 size = textureSize(img, 0);\n  ivec2 p = ivec2(texCoord * vec2(size));\n"

# the output's own pixel when the output size differs from the input's
_OUT_PIXEL = "  ivec2 p = ivec2(texCoord * vec2(out_size));\n"

MAX_TAPS = 129  # Gaussian taps per pass: 2 ceil(3 sigma) + 1 for sigma up to 16 px (params allow 16)

SHADERS = {
    "copy": _HEADER + "uniform sampler2D img;\nvoid main() {\n" + _PIXEL + "  gl_FragData[0] = vec4(texelFetch(img, p, 0).rgb, 1.0);\n}\n",
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
    # one direction of the separable Gaussian; the weights come from effects.gaussian_weights (the same
    # float32 numbers as the numba pass); clamp-to-edge wrap = clamped indices. mode 1: the vertical
    # pass of the unsharp mask, fused with x + amount (x - blur) clipped (x from `orig`).
    "gauss_1d": _HEADER + f"uniform sampler2D img;\nuniform sampler2D orig;\nuniform int R;\n"
    f"uniform float wts[{MAX_TAPS}];\nuniform vec2 dir;\nuniform int mode;\nuniform float amount;\n" + """
void main() {
  vec2 size = vec2(textureSize(img, 0));
  vec2 inv = 1.0 / size;
  vec2 uv = (floor(texCoord * size) + 0.5) * inv;
  vec2 step_uv = dir * inv;
  vec3 acc = vec3(0.0);
  for (int k = 0; k <= 2 * R; ++k) {
    acc += wts[k] * texture(img, uv + float(k - R) * step_uv).rgb;
  }
  if (mode == 1) {
    vec3 x = texture(orig, uv).rgb;
    acc = clamp(x + amount * (x - acc), 0.0, 1.0);
  }
  gl_FragData[0] = vec4(acc, 1.0);
}
""",
    # half resolution: the 2x2 mean of the part above threshold in luminance (effects._bright_half)
    "bright_half": _HEADER + "uniform sampler2D img;\nuniform float threshold;\nuniform vec3 luma;\n"
    "uniform ivec2 out_size;\nuniform int use_threshold;\n" + """
void main() {
  ivec2 size = textureSize(img, 0);
""" + _OUT_PIXEL + """  vec3 acc = vec3(0.0);
  for (int dy = 0; dy < 2; ++dy) {
    for (int dx = 0; dx < 2; ++dx) {
      vec3 x = texelFetch(img, min(2 * p + ivec2(dx, dy), size - 1), 0).rgb;
      if (use_threshold == 1) {
        float l = dot(luma, x);
        x *= max(l - threshold, 0.0) / max(l, 1e-12);
      }
      acc += x;
    }
  }
  gl_FragData[0] = vec4(acc * 0.25, 1.0);
}
""",
    # img + k up(low), low at half resolution read bilinearly at ((i + 1/2) / 2, (j + 1/2) / 2)
    "add_upsampled": _HEADER + "uniform sampler2D img;\nuniform sampler2D low;\nuniform float k;\n" + _BILINEAR + """
void main() {
""" + _PIXEL + """  float x = (float(p.x) + 0.5) * 0.5, y = (float(p.y) + 0.5) * 0.5;
  vec3 up = vec3(bilinear(low, 0, x, y), bilinear(low, 1, x, y), bilinear(low, 2, x, y));
  gl_FragData[0] = vec4(texelFetch(img, p, 0).rgb + k * up, 1.0);
}
""",
    # counter-based Gaussian noise, the same field as effects.noise_field (hash32 = lowbias32)
    "noise": _HEADER + "uniform sampler2D img;\nuniform float shot;\nuniform float rd;\nuniform int key_bits;\n" + """
uint hash32(uint x) {
  x ^= x >> 16; x *= 0x7feb352du; x ^= x >> 15; x *= 0x846ca68bu; x ^= x >> 16;
  return x;
}
float unit24(uint x) { return (float(x >> 8) + 0.5) * (1.0 / 16777216.0); }
float normal(uint n, uint key) {
  uint m2 = n & ~1u;
  float r = sqrt(-2.0 * log(unit24(hash32(hash32(m2) ^ key))));
  float angle = 6.2831853071795865 * unit24(hash32(hash32(m2 + 1u) ^ key));
  return (n & 1u) == 0u ? r * cos(angle) : r * sin(angle);
}
void main() {
""" + _PIXEL + """  vec3 x = texelFetch(img, p, 0).rgb;
  uint key = uint(key_bits);  // the uint32 key passed through a signed uniform, same bits
  uint n = uint(p.y * size.x + p.x) * 3u;
  vec3 z = vec3(normal(n, key), normal(n + 1u, key), normal(n + 2u, key));
  vec3 sd = sqrt(max(x, 0.0) * shot + rd * rd);
  gl_FragData[0] = vec4(max(x + sd * z, 0.0), 1.0);
}
""",
    # (r w, g w, b w, reach^2), w = 1 / (pi max(reach^2 - 1/4, 1/4)) as effects._dof_weight
    "dof_source": _HEADER + "uniform sampler2D img;\nuniform sampler2D reach2;\n" + """
void main() {
""" + _PIXEL + """  float r2 = texelFetch(reach2, p, 0).r;
  float w = 1.0 / (3.14159265358979 * max(r2 - 0.25, 0.25));
  gl_FragData[0] = vec4(texelFetch(img, p, 0).rgb * w, r2);
}
""",
    # scatter-as-gather: sum of the sources whose disc covers p; the source texture is clamped to a
    # border of reach -1 (never inside a disc), so taps need no bounds test
    "depth_of_field": _HEADER + "uniform sampler2D src;\nuniform int R;\nuniform float r2max;\n" + """
void main() {
  vec2 size = vec2(textureSize(src, 0));
  vec2 inv = 1.0 / size;
  vec2 uv = (floor(texCoord * size) + 0.5) * inv;
  vec4 acc = vec4(0.0);
  for (int dj = -R; dj <= R; ++dj) {
    float dj2 = float(dj * dj);
    int span = int(floor(sqrt(max(r2max - dj2, 0.0))));
    for (int di = -span; di <= span; ++di) {
      vec4 s = texture(src, uv + vec2(float(di), float(dj)) * inv);
      float w = 1.0 / (3.14159265358979 * max(s.a - 0.25, 0.25));
      acc += (float(di * di) + dj2 <= s.a) ? vec4(s.rgb, w) : vec4(0.0);
    }
  }
  gl_FragData[0] = vec4(acc.rgb / acc.a, 1.0);
}
""",
    # lens flare ghosts and halo at half resolution (lens_flare._features); ghosts (s, r, g, b)
    "flare_features": _HEADER + "uniform sampler2D half_res;\nuniform sampler2D quarter;\nuniform vec2 centre;\n"
    "uniform float rho;\nuniform float halo;\nuniform vec3 halo_tint;\nuniform int falloff;\n"
    "uniform int n_ghosts;\nuniform vec4 ghosts[16];\n" + _BILINEAR_ZERO + """
float fade(vec2 q) {
  float base = max(1.0 - length(q - centre) / rho, 0.0), f = 1.0;
  for (int k = 0; k < falloff; ++k) f *= base;
  return f;
}
void main() {
  vec2 size = vec2(textureSize(half_res, 0));
  ivec2 p = ivec2(texCoord * size);
  vec2 pos = 2.0 * (vec2(p) + 0.5);
  vec3 acc = vec3(0.0);
  for (int k = 0; k < n_ghosts; ++k) {
    float s = ghosts[k].x;
    vec2 q = centre + (pos - centre) / s;
    float wk = fade(q) / (s * s);
    if (wk <= 0.0) continue;
    vec3 v = abs(s) >= 1.0 ? bilinear_zero(half_res, q.x / 2.0, q.y / 2.0) : bilinear_zero(quarter, q.x / 4.0, q.y / 4.0);
    acc += ghosts[k].yzw * wk * v;
  }
  vec2 d = centre - pos;
  float dist = length(d);
  if (halo > 0.0 && dist > 0.0) {
    vec2 q = pos + d * (halo / dist);
    float wh = fade(q);
    if (wh > 0.0) acc += halo_tint * wh * bilinear_zero(half_res, q.x / 2.0, q.y / 2.0);
  }
  gl_FragData[0] = vec4(acc, 1.0);
}
""",
}
