"""GLSL fragment passes of the OSMesa backend (``postfx.osmesa`` draws them). Each mirrors a kernel of
``postfx.effects`` / ``postfx.lens_flare``: the same taps, clamping and weights, so the two backends
agree to float32 rounding (bilinear reads: to the rounding of the texture coordinate, below). Passes
that gather many taps (DoF, Gaussian) compute several outputs per fragment from each fetched texel:
the DoF writes them straight into the image with imageStore, the Gaussian's horizontal pass into the
layers of a 3D target that the vertical pass reads.

Conventions: texel (i, j) is image pixel (column i, row j) (row 0 uploaded is row 0 read back);
``texture()`` with nearest filtering at texel centres is ``texelFetch`` with the texture's wrap mode
(clamp to edge = clamped indices, clamp to border = a constant outside), and llvmpipe runs it about a
third faster than ``texelFetch``; a pass that reads bilinearly has the sampler's linear filter switched
on for that input (``Context.draw(linear=...)``).

Pointwise effects (sensor noise, tone map, colour grade, mask: each output pixel depends only on the
same input pixel) are GLSL functions ``fx_<effect>`` with their own uniform names. ``source(name,
epilogue)`` appends a run of them to the last pass of another effect (``post()`` in that pass), so
a chain such as blur -> noise -> tone map -> grade draws one full-resolution pass where it drew four.
"""
from __future__ import annotations

import functools

_HEADER = """//VTK::System::Dec
in vec2 texCoord;
//VTK::Output::Dec
"""

# Bilinear reads (chromatic aberration, the half-resolution upsampling, the lens flare's features) use the
# sampler's own linear filter for the draw (``Context.draw(linear=...)``): llvmpipe interpolates float
# textures with float32 weights, clamped or with a zero border as the NumPy kernels, one fetch instead
# of four; the results differ from NumPy's by the float rounding of the texture coordinate (below
# 4e-4 on values up to 60 at 640x480).

_PIXEL = "  ivec2 size = textureSize(img, 0);\n  ivec2 p = ivec2(texCoord * vec2(size));\n"

# the output's own pixel when the output size differs from the input's
_OUT_PIXEL = "  ivec2 p = ivec2(texCoord * vec2(out_size));\n"

MAX_TAPS = 129  # Gaussian taps per pass: 2 ceil(3 sigma) + 1 for sigma up to 16 px (params allow 16)


# -- pointwise effects: one function each, uniforms prefixed by the effect -----------------------------
POINTWISE = ("sensor_noise", "tonemap", "color_grade", "laparoscope_mask")

_POINTWISE = {
    # counter-based Gaussian noise, the same field as effects.noise_field (hash32 = lowbias32)
    "sensor_noise": """uniform float noise_shot;
uniform float noise_rd;
uniform int noise_key;
uint hash32(uint x) {
  x ^= x >> 16; x *= 0x7feb352du; x ^= x >> 15; x *= 0x846ca68bu; x ^= x >> 16;
  return x;
}
float unit24(uint x) { return (float(x >> 8) + 0.5) * (1.0 / 16777216.0); }
// values m2 and m2 + 1 (m2 even): one Box-Muller pair
vec2 normal_pair(uint m2, uint key) {
  float r = sqrt(-2.0 * log(unit24(hash32(hash32(m2) ^ key))));
  float angle = 6.2831853071795865 * unit24(hash32(hash32(m2 + 1u) ^ key));
  return vec2(r * cos(angle), r * sin(angle));
}
vec3 fx_sensor_noise(vec3 x, ivec2 p, ivec2 size) {
  uint key = uint(noise_key);  // the uint32 key passed through a signed uniform, same bits
  uint n = uint(p.y * size.x + p.x) * 3u;
  // the pixel's values n, n + 1, n + 2 lie in two pairs (two logarithms, not three)
  vec2 a = normal_pair(n & ~1u, key), b = normal_pair((n & ~1u) + 2u, key);
  vec3 z = (n & 1u) == 0u ? vec3(a, b.x) : vec3(a.y, b);
  vec3 sd = sqrt(max(x, 0.0) * noise_shot + noise_rd * noise_rd);
  return max(x + sd * z, 0.0);
}
""",
    "tonemap": """uniform float tm_gain;
uniform int tm_curve;
uniform int tm_srgb;
float encode(float x) {
  x = clamp(x, 0.0, 1.0);
  return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}
vec3 fx_tonemap(vec3 x, ivec2 p, ivec2 size) {
  x = max(x, vec3(0.0)) * tm_gain;
  vec3 y;
  if (tm_curve == 0) y = clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
  else if (tm_curve == 1) y = x / (1.0 + x);
  else y = clamp(x, 0.0, 1.0);
  if (tm_srgb == 1) y = vec3(encode(y.r), encode(y.g), encode(y.b));
  return y;
}
""",
    "color_grade": """uniform sampler2D cg_lut;
uniform float cg_saturation;
uniform vec3 cg_luma;
// cg_lut: row c holds channel c, texel k the entries k and k + 1 (one fetch per channel, not two)
float lookup(float x, int c) {
  int n = textureSize(cg_lut, 0).x;
  float f = clamp(x, 0.0, 1.0) * float(n - 1);
  int k = min(int(f), n - 2);
  vec2 ab = texture(cg_lut, vec2((float(k) + 0.5) / float(n), (float(c) + 0.5) / 3.0)).rg;  // texel (k, c) at its centre
  return ab.x + (f - float(k)) * (ab.y - ab.x);
}
vec3 fx_color_grade(vec3 x, ivec2 p, ivec2 size) {
  vec3 y = vec3(lookup(x.r, 0), lookup(x.g, 1), lookup(x.b, 2));
  float l = dot(cg_luma, y);
  return clamp(vec3(l) + cg_saturation * (y - vec3(l)), 0.0, 1.0);
}
""",
    "laparoscope_mask": """uniform vec2 mask_centre;
uniform float mask_radius;
uniform float mask_softness;
uniform float mask_vignette;
vec3 fx_laparoscope_mask(vec3 x, ivec2 p, ivec2 size) {
  float rho = length(vec2(float(p.x) + 0.5 - mask_centre.x, float(p.y) + 0.5 - mask_centre.y)) / (0.5 * float(size.y));
  float edge;
  if (mask_softness == 0.0) edge = rho <= mask_radius ? 1.0 : 0.0;
  else {
    float t = clamp((rho - (mask_radius - 0.5 * mask_softness)) / mask_softness, 0.0, 1.0);
    edge = 1.0 - t * t * (3.0 - 2.0 * t);
  }
  float r = clamp(rho / mask_radius, 0.0, 1.0);
  return x * (edge * (1.0 - mask_vignette * r * r));
}
""",
}

# -- separable Gaussian ---------------------------------------------------------------------------------
GAUSS_BLOCK = 4  # outputs per fragment along the pass direction (one draw buffer each)


def _gauss_taps(kind: str, R: int, block: int = GAUSS_BLOCK) -> str:
    """Unrolled taps for ``block`` outputs from block + 2R fetches: each texel fetched once is added to
    every output it is a tap of, output b summing its taps k = 0 .. 2R in order from zero in float32
    with the weights of effects.gaussian_weights (as the numba passes: the same sums). Leaves the sums
    in a0 .. a{block - 1}."""
    lines = []
    for j in range(block + 2 * R):
        lines.append(f"  t = {kind}({j - R});")
        lines += [f"  a{b} += wts[{j - b}] * t;" for b in range(block) if 0 <= j - b <= 2 * R]
    decl = "".join(f"  vec3 a{b} = vec3(0.0);\n" for b in range(block))
    return decl + "  vec3 t;\n" + "\n".join(lines) + "\n"


def _gauss_writes() -> str:
    return "".join(f"  gl_FragData[{b}] = vec4(a{b}, 1.0);\n" for b in range(GAUSS_BLOCK))


# Up to this radius the vertical pass computes one output per fragment (2R + 1 fetches from the blocked
# rows) and writes the image itself, with the unsharp mask and any fused pointwise effects: at R = 3
# (sigma 1) blocked rows + this pass took 8.4 ms at 640x480 where blocked rows + blocked columns +
# reassembly took 9.9; at R = 9 the blocked columns stay faster (14.4 vs 16.9 ms).
GAUSS_PLAIN_V = 3


def _column_blocks_tap(x: str, y0: str) -> str:
    """GLSL lines defining ``tap(d)``: texel (``x``, ``y0`` + d) of ``rows``, the horizontal pass's target
    (blocks of GAUSS_BLOCK columns, layer = column mod GAUSS_BLOCK; rows clamped to the edge)."""
    return (f"  vec3 rs = vec3(textureSize(rows, 0));\n"
            f"  float u = (float({x} / {GAUSS_BLOCK}) + 0.5) / rs.x;\n"
            f"  float layer = (float({x} % {GAUSS_BLOCK}) + 0.5) / rs.z;\n"
            f"#define tap(d) texture(rows, vec3(u, (float({y0} + d) + 0.5) / rs.y, layer)).rgb\n")


def _gauss_rows_out(R: int) -> None:
    """``gauss_vb<R>`` (``gauss_vb<R>u``, ``gauss_vb<R>U``: the unsharp mask of an image, of a row-blocked
    one): the vertical pass of a Gaussian of radius R <= GAUSS_PLAIN_V whose result goes to the read-back
    or to another such Gaussian, GAUSS_BLOCK rows per fragment from GAUSS_BLOCK + 2R fetches (instead of
    2R + 1 per row), written "row-blocked" into the layers of a 3D target, layer = row mod GAUSS_BLOCK:
    ``Context.download`` reads it back row by row into place, ``gauss_h<R>r`` and the "U" passes read it
    in place. The same sums, in the same order, as ``gauss_vp<R>``; the pointwise epilogue runs on each
    row's value."""
    unsharp = "".join(f"  x = texture(orig, vec2(ox, (float(y0 + {b}) + 0.5) * oy)).rgb;\n"
                      f"  a{b} = clamp(x + amount * (x - a{b}), 0.0, 1.0);\n" for b in range(GAUSS_BLOCK))
    # orig row-blocked too (the Gaussian before wrote it): output b of this block is its texel (x, block, b)
    unsharp_rows = "".join(f"  x = texture(orig, vec3(ox, (float(b.y) + 0.5) * oy, {(b + 0.5) / GAUSS_BLOCK})).rgb;\n"
                           f"  a{b} = clamp(x + amount * (x - a{b}), 0.0, 1.0);\n" for b in range(GAUSS_BLOCK))
    writes = "".join(f"  gl_FragData[{b}] = vec4(post(a{b}, ivec2(b.x, y0 + {b}), size), 1.0);\n"
                     for b in range(GAUSS_BLOCK))
    for name, orig, code in ((f"gauss_vb{R}", "", ""),
                             (f"gauss_vb{R}u", "uniform sampler2D orig;\nuniform float amount;\n", unsharp),
                             (f"gauss_vb{R}U", "uniform sampler3D orig;\nuniform float amount;\n", unsharp_rows)):
        oy = "textureSize(orig, 0).y" if name.endswith("U") else "size.y"
        SHADERS[name] = _HEADER + orig + f"""uniform sampler3D rows;
uniform float wts[{2 * R + 1}];
uniform ivec2 size;
uniform ivec2 blocks;
//EPILOGUE::Dec
void main() {{
  ivec2 b = ivec2(texCoord * vec2(blocks));
  int y0 = b.y * {GAUSS_BLOCK};
{_column_blocks_tap("b.x", "y0")}{_gauss_taps("tap", R)}""" + (f"  vec3 x;\n  float ox = (float(b.x) + 0.5) / float(size.x), oy = 1.0 / float({oy});\n"
                               + code if orig else "") + writes + "}\n"


@functools.lru_cache(maxsize=None)
def gauss_passes(R: int) -> tuple[str, str]:
    """The two passes of a Gaussian of radius R (2R + 1 taps, edges clamped by the clamp-to-edge wrap):
    horizontal, from an image into blocks of GAUSS_BLOCK columns (a 3D target, layer = column mod
    block), then vertical from those: for R <= GAUSS_PLAIN_V one output per fragment straight into the
    image (``gauss_vp<R>``, ``gauss_vp<R>u`` with the unsharp mask; pointwise epilogue), else blocks of GAUSS_BLOCK
    rows that ``gauss_unpack`` reassembles. Registered in SHADERS under the returned names."""
    horizontal, vertical = f"gauss_h{R}", (f"gauss_vp{R}" if R <= GAUSS_PLAIN_V else f"gauss_v{R}")
    SHADERS[horizontal] = _HEADER + f"""uniform sampler2D img;
uniform float wts[{2 * R + 1}];
uniform ivec2 blocks;
void main() {{
  vec2 inv = 1.0 / vec2(textureSize(img, 0));
  ivec2 b = ivec2(texCoord * vec2(blocks));
  int x0 = b.x * {GAUSS_BLOCK};
  float v = (float(b.y) + 0.5) * inv.y;
#define tap(d) texture(img, vec2((float(x0 + d) + 0.5) * inv.x, v)).rgb
{_gauss_taps("tap", R)}{_gauss_writes()}}}
"""
    # the same from a row-blocked image (layer = row mod GAUSS_BLOCK: a Gaussian's blocked vertical pass)
    SHADERS[horizontal + "r"] = _HEADER + f"""uniform sampler3D img;
uniform float wts[{2 * R + 1}];
uniform ivec2 blocks;
void main() {{
  vec3 is = vec3(textureSize(img, 0));
  ivec2 b = ivec2(texCoord * vec2(blocks));
  int x0 = b.x * {GAUSS_BLOCK};
  float v = (float(b.y / {GAUSS_BLOCK}) + 0.5) / is.y, layer = (float(b.y % {GAUSS_BLOCK}) + 0.5) / is.z;
#define tap(d) texture(img, vec3((float(x0 + d) + 0.5) / is.x, v, layer)).rgb
{_gauss_taps("tap", R)}{_gauss_writes()}}}
"""
    if R <= GAUSS_PLAIN_V:
        unsharp = "  vec3 x = texture(orig, texCoord).rgb;\n"
        unsharp_rows = ("  vec3 x = texture(orig, vec3(texCoord.x, (float(p.y / {B}) + 0.5) / float(textureSize(orig, 0).y), "
                        "(float(p.y % {B}) + 0.5) / {B}.0)).rgb;\n").format(B=GAUSS_BLOCK)
        mask = "  a0 = clamp(x + amount * (x - a0), 0.0, 1.0);\n"
        for name, orig, code in ((vertical, "", ""),
                                 (vertical + "u", "uniform sampler2D orig;\nuniform float amount;\n", unsharp + mask),
                                 (vertical + "U", "uniform sampler3D orig;\nuniform float amount;\n", unsharp_rows + mask)):
            SHADERS[name] = _HEADER + orig + f"""uniform sampler3D rows;
uniform float wts[{2 * R + 1}];
uniform ivec2 size;
//EPILOGUE::Dec
void main() {{
  ivec2 p = ivec2(texCoord * vec2(size));
{_column_blocks_tap("p.x", "p.y")}{_gauss_taps("tap", R, 1)}{code}  gl_FragData[0] = vec4(post(a0, p, size), 1.0);
}}
"""
        _gauss_rows_out(R)
        return horizontal, vertical
    SHADERS[vertical] = _HEADER + f"""uniform sampler3D rows;
uniform float wts[{2 * R + 1}];
uniform ivec2 blocks;
void main() {{
  ivec2 b = ivec2(texCoord * vec2(blocks));
  int y0 = b.y * {GAUSS_BLOCK};
{_column_blocks_tap("b.x", "y0")}{_gauss_taps("tap", R)}{_gauss_writes()}}}
"""
    return horizontal, vertical


# -- depth of field ------------------------------------------------------------------------------------
DOF_BLOCK = (4, 4)  # output pixels per gather fragment (columns, rows), each written with imageStore
DOF_TILE = 16  # side of the square tiles whose reach bounds the gather loops (a multiple of both block sides)

# a pass that also writes images (imageStore): GLSL 1.50 plus the extension (core in GL 4.2)
_IMAGE_HEADER = _HEADER.replace("//VTK::System::Dec",
                                "//VTK::System::Dec\n#extension GL_ARB_shader_image_load_store : require")


# Loop-carried values cost llvmpipe more than the arithmetic: inside a loop every write to one of them is
# a masked store (load the old value, select by the lanes' execution mask, store), and the 16 vec4
# accumulators do not fit in the registers. The gather therefore fetches DOF_GROUP = (rows, columns)
# source texels per loop iteration and adds each output's terms from all of them in one expression
# (straight-line SSA values, not masked) before the one write to its accumulator: 2 x 2 texels per
# write, 26.7 vs 40.5 ms CPU for the gather on the benchmark's synthetic frame, 13.1 vs 17.6 ms on
# the rendered one (same process, alternating; 3 x 1, 4 x 1, 1 x 3 within 2 %, 1 x 6 and 4 x 2 slower).
DOF_GROUP = (2, 2)


def _dof_gather(kx: int, ky: int, rows: int = DOF_GROUP[0], cols: int = DOF_GROUP[1]) -> str:
    """Scatter-as-gather over a block of kx x ky outputs: each source texel fetched once is tested against
    all the block's outputs (one fetch for 16 outputs). Each output goes straight into the image
    ``dof_out`` with imageStore, after the pointwise epilogue (``post()``): no draw-buffer limit on the
    block (4 x 4: 16 outputs, where draw buffers allow 8) and no pass to reassemble the blocks. The
    fragment's own colour output is a dummy.

    The loops step over groups of ``rows`` x ``cols`` source texels (DOF_GROUP): the rows 2 rr + ky of
    the bound and each row's 2 span + kx texels divide exactly (ky % rows == kx % cols == 0), and a
    group of rows runs over the widest span among them. A texel visited beyond its own row's span
    lies outside the disc of the bound ``m`` around the block, so no output's exact test passes for
    it: the same terms as one texel at a time, summed in another order."""
    if ky % rows or kx % cols:
        raise ValueError("the texel group must divide the block")
    acc = "\n".join(f"  vec4 a{x}_{y} = vec4(0.0);" for y in range(ky) for x in range(kx))
    # squared row distances of source row dj + r to output row y: integers, exact in float32
    drow = "\n".join(f"    float d{r}_{y} = float((dj + {r} - {y}) * (dj + {r} - {y}));"
                      for r in range(rows) for y in range(ky))
    body = []
    for r in range(rows):
        for c in range(cols):
            body.append(f"      vec4 s{r}{c} = texture(src, q + vec2({c}.0 * inv.x, {r}.0 * inv.y));")
            body.append(f"      vec4 v{r}{c} = vec4(s{r}{c}.rgb, "
                        f"1.0 / (3.14159265358979 * max(s{r}{c}.a - 0.25, 0.25)));")
            # reach2 - dj^2 is exact in float32 (dj^2 is an integer, a multiple of the ulp of reach2), so
            # di^2 <= t is exactly the integer disc test di^2 + dj^2 <= reach2 of effects._scatter_disc
            body += [f"      float t{r}{c}_{y} = s{r}{c}.a - d{r}_{y};" for y in range(ky)]
    for c in range(cols):
        body += [f"      float e{c}_{x} = float((di + {c - x}) * (di + {c - x}));" for x in range(kx)]
    for y in range(ky):
        for x in range(kx):
            terms = " + ".join(f"(e{c}_{x} <= t{r}{c}_{y} ? v{r}{c} : vec4(0.0))"
                               for r in range(rows) for c in range(cols))
            body.append(f"      a{x}_{y} += {terms};")
    writes = "\n".join(f"  if (o.x + {x} < size.x && o.y + {y} < size.y) imageStore(dof_out, o + ivec2({x}, {y}), "
                        f"vec4(post(a{x}_{y}.rgb / a{x}_{y}.a, o + ivec2({x}, {y}), size), 1.0));"
                        for y in range(ky) for x in range(kx))
    nl = "\n"
    return _IMAGE_HEADER + f"""uniform sampler2D src;
uniform sampler2D tiles;
uniform ivec2 blocks;
uniform ivec2 size;
uniform int pad;
layout(rgba32f) writeonly uniform image2D dof_out;
//EPILOGUE::Dec
void main() {{
  ivec2 b = ivec2(texCoord * vec2(blocks));
  ivec2 o = b * ivec2({kx}, {ky});
  vec2 inv = 1.0 / vec2(textureSize(src, 0));
  vec2 uv = (vec2(o + ivec2(pad)) + 0.5) * inv;  // the source texel of output o (texture() at texel centres)
  float m = texelFetch(tiles, o / {DOF_TILE}, 0).r;
  // floor(sqrt()) may only overshoot (+1e-3): taps beyond a source's reach fail its own test anyway
  int rr = int(floor(sqrt(max(m, 0.0)) + 1e-3));
{acc}
  for (int dj = -rr; dj <= rr + {ky - 1}; dj += {rows}) {{
    // the row of the group nearest to the block's rows bounds the group's span
    int dm = dj + {rows - 1} < 0 ? dj + {rows - 1} : (dj > {ky - 1} ? dj - {ky - 1} : 0);
    int span = int(floor(sqrt(max(m - float(dm * dm), 0.0)) + 1e-3));
{drow}
    vec2 q = uv + vec2(float(-span), float(dj)) * inv;
    int di = -span;
    for (int k = (2 * span + {kx}) / {cols}; k > 0; --k, di += {cols}, q.x += {cols}.0 * inv.x) {{
{nl.join(body)}
    }}
  }}
{writes}
  gl_FragData[0] = vec4(0.0);
}}
"""


SHADERS = {
    # texture() at texCoord (the fragment's own texel centre, the viewport being the image's size) reads
    # the same texel as texelFetch(img, p, 0), a third faster on llvmpipe (a copy 1.7 vs 2.2 ms at 640x480)
    "copy": _HEADER + "uniform sampler2D img;\n//EPILOGUE::Dec\nvoid main() {\n" + _PIXEL
    + "  gl_FragData[0] = vec4(post(texture(img, texCoord).rgb, p, size), 1.0);\n}\n",
    # a run of pointwise effects on their own (the first effect of a chain, or fusion switched off)
    "pointwise": _HEADER + "uniform sampler2D img;\n//EPILOGUE::Dec\nvoid main() {\n" + _PIXEL
    + "  gl_FragData[0] = vec4(post(texture(img, texCoord).rgb, p, size), 1.0);\n}\n",
    "chromatic_aberration": _HEADER + "uniform sampler2D img;\nuniform vec3 scale;\nuniform vec2 centre;\n"
    "//EPILOGUE::Dec\n" + """
void main() {
""" + _PIXEL + """  // channel c bilinear at centre + (pos - centre) scale_c: the sampler's linear filter (clamped)
  vec2 pos = vec2(p) + 0.5, inv = 1.0 / vec2(size);
  vec3 rgb = vec3(texture(img, (centre + (pos - centre) * scale.r) * inv).r,
                  texture(img, (centre + (pos - centre) * scale.g) * inv).g,
                  texture(img, (centre + (pos - centre) * scale.b) * inv).b);
  gl_FragData[0] = vec4(post(rgb, p, size), 1.0);
}
""",
    # the separable Gaussian's blocks back to one image (gauss_passes); "gauss_unpack_sharpen": the unsharp
    # mask x + amount (x - blur) clipped, x from `orig`. Two shaders, not a uniform switch: llvmpipe runs
    # both sides of a branch on a uniform, and the blur would pay the fetch of `orig` (about 1.5 ms)
    **{name: _HEADER + "uniform sampler3D blocks;\nuniform ivec2 size;\n" + orig + "//EPILOGUE::Dec\n" + f"""
void main() {{
  ivec2 p = ivec2(texCoord * vec2(size));
  vec3 at = (vec3(p.x, p.y / {GAUSS_BLOCK}, p.y % {GAUSS_BLOCK}) + 0.5) / vec3(textureSize(blocks, 0));
  vec3 acc = texture(blocks, at).rgb;
{unsharp}  gl_FragData[0] = vec4(post(acc, p, size), 1.0);
}}
""" for name, orig, unsharp in (
        ("gauss_unpack", "", ""),
        ("gauss_unpack_sharpen", "uniform sampler2D orig;\nuniform float amount;\n",
         "  vec3 x = texture(orig, texCoord).rgb;\n  acc = clamp(x + amount * (x - acc), 0.0, 1.0);\n"))},
    # half resolution: the 2x2 mean of the part above threshold in luminance (effects._bright_half)
    "bright_half": _HEADER + "uniform sampler2D img;\nuniform float threshold;\nuniform vec3 luma;\n"
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
""" + _OUT_PIXEL + """  ivec2 q0 = 2 * p, q1 = min(2 * p + 1, size - 1);
  vec3 acc = part(texture(img, (vec2(q0.x, q0.y) + 0.5) * inv).rgb);
  acc += part(texture(img, (vec2(q1.x, q0.y) + 0.5) * inv).rgb);
  acc += part(texture(img, (vec2(q0.x, q1.y) + 0.5) * inv).rgb);
  acc += part(texture(img, (vec2(q1.x, q1.y) + 0.5) * inv).rgb);
  gl_FragData[0] = vec4(acc * 0.25, 1.0);
}
""",
    # img + k up(low), low at half resolution read bilinearly at ((i + 1/2) / 2, (j + 1/2) / 2)
    "add_upsampled": _HEADER + "uniform sampler2D img;\nuniform sampler2D low;\nuniform float k;\n"
    "//EPILOGUE::Dec\n" + """
void main() {
""" + _PIXEL + """  // bilinear at ((i + 1/2) / 2, (j + 1/2) / 2) half-res texels: the sampler's linear filter (clamped)
  vec3 up = texture(low, (vec2(p) + 0.5) * 0.5 / vec2(textureSize(low, 0))).rgb;
  gl_FragData[0] = vec4(post(texture(img, texCoord).rgb + k * up, p, size), 1.0);
}
""",
    # the DoF source, padded by `pad` texels of reach -1 (never inside a disc) so that the gather needs
    # no bounds test: (r w, g w, b w, reach^2), w = 1 / (pi max(reach^2 - 1/4, 1/4)) as effects._dof_weight
    "dof_source": _HEADER + "uniform sampler2D img;\nuniform sampler2D reach2;\nuniform int pad;\n" + """
void main() {
  ivec2 size = textureSize(img, 0);
  ivec2 p = ivec2(texCoord * vec2(size + 2 * pad)) - ivec2(pad);
  if (p.x < 0 || p.y < 0 || p.x >= size.x || p.y >= size.y) {
    gl_FragData[0] = vec4(0.0, 0.0, 0.0, -1.0);
  } else {
    float r2 = texelFetch(reach2, p, 0).r;
    float w = 1.0 / (3.14159265358979 * max(r2 - 0.25, 0.25));
    gl_FragData[0] = vec4(texelFetch(img, p, 0).rgb * w, r2);
  }
}
""",
    "dof_gather": _dof_gather(*DOF_BLOCK),
    # lens flare ghosts and halo at half resolution (lens_flare._features); ghosts (s, r, g, b)
}


@functools.lru_cache(maxsize=None)
def flare_features(n_ghosts: int, falloff: int, reads_half: tuple[bool, ...]) -> str:
    """Lens flare ghosts and halo at half resolution (lens_flare._features), unrolled for the number of
    ghosts, the integer fade exponent and the image each ghost reads (half resolution when |s| >= 1, else
    quarter): constants let the shader compiler drop the loops and uniform-array indexing. Ghost k is
    ``ghosts[k] = (s, r, g, b)``. Registered in SHADERS under the returned name."""
    name = f"flare_features_{n_ghosts}_{falloff}_{''.join('h' if h else 'q' for h in reads_half)}"
    fade = "".join("  f *= base;\n" for _ in range(falloff))
    ghosts = "".join(f"""  {{
    float s = ghosts[{k}].x;
    vec2 q = centre + (pos - centre) / s;
    float wk = fade(q) / (s * s);
    if (wk > 0.0) acc += ghosts[{k}].yzw * wk * {"texture(half_res, q * inv_half).rgb" if half
                                                   else "texture(quarter, q * inv_quarter).rgb"};
  }}
""" for k, half in enumerate(reads_half))
    SHADERS[name] = _HEADER + f"""uniform sampler2D half_res;
uniform sampler2D quarter;
uniform vec2 centre;
uniform float rho;
uniform float halo;
uniform vec3 halo_tint;
uniform vec4 ghosts[{max(n_ghosts, 1)}];
float fade(vec2 q) {{
  float base = max(1.0 - length(q - centre) / rho, 0.0), f = 1.0;
{fade}  return f;
}}
void main() {{
  vec2 size = vec2(textureSize(half_res, 0));
  ivec2 p = ivec2(texCoord * size);
  // bilinear reads, zero outside (lens_flare.bilinear_zero): the samplers' linear filter with a zero border;
  // full-res position q is q / 2 half-res and q / 4 quarter-res texels
  vec2 inv_half = 0.5 / size, inv_quarter = 0.25 / vec2(textureSize(quarter, 0));
  vec2 pos = 2.0 * (vec2(p) + 0.5);
  vec3 acc = vec3(0.0);
{ghosts}  vec2 d = centre - pos;
  float dist = length(d);
  if (halo > 0.0 && dist > 0.0) {{
    vec2 q = pos + d * (halo / dist);
    float wh = fade(q);
    if (wh > 0.0) acc += halo_tint * wh * texture(half_res, q * inv_half).rgb;
  }}
  gl_FragData[0] = vec4(acc, 1.0);
}}
"""
    return name


@functools.lru_cache(maxsize=None)
def source(name: str, epilogue: tuple[str, ...] = ()) -> str:
    """The fragment shader ``name`` with the pointwise effects ``epilogue`` applied, in order, to what it
    writes (``post()``; the identity for an empty epilogue)."""
    fs = SHADERS[name]
    if "//EPILOGUE::Dec" not in fs:
        if epilogue:
            raise ValueError(f"pass {name!r} takes no pointwise epilogue")
        return fs
    calls = "".join(f"  x = fx_{effect}(x, p, size);\n" for effect in epilogue)
    dec = "".join(_POINTWISE[effect] for effect in dict.fromkeys(epilogue))
    return fs.replace("//EPILOGUE::Dec", dec + "vec3 post(vec3 x, ivec2 p, ivec2 size) {\n" + calls + "  return x;\n}\n")
