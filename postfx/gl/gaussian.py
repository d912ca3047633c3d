"""The separable Gaussian as GL passes (blur, sharpen, and the low-resolution blurs of bloom and lens
flare), mirroring ``postfx.gaussian``: each output sums the same taps, in the same order, in float32.

The horizontal pass computes GAUSS_BLOCK outputs per fragment from GAUSS_BLOCK + 2R fetches, written
into the layers of a 3D target (layer = column mod GAUSS_BLOCK); the vertical pass reads those.
Row-blocked images (``Context.row_blocked``: a 3D target whose layer k holds the rows k, k + L, ...)
let a Gaussian of small radius hand its result to the read-back or to the next Gaussian without a pass
that reassembles the rows.
"""
from __future__ import annotations

import functools

from postfx.gaussian import gaussian_weights
from postfx.gl.library import FloatArray, IVec2
from postfx.gl.shaders import HEADER, SHADERS, Epilogue

MAX_TAPS = 129  # Gaussian taps per pass: 2 ceil(3 sigma) + 1 for sigma up to 16 px (params allow 16)
GAUSS_BLOCK = 4  # outputs per fragment along the pass direction (one draw buffer each)


def _gauss_taps(kind: str, R: int, block: int = GAUSS_BLOCK) -> str:
    """Unrolled taps for ``block`` outputs from block + 2R fetches: each texel fetched once is added to
    every output it is a tap of, output b summing its taps k = 0 .. 2R in order from zero in float32
    with the weights of ``gaussian_weights`` (as the numba passes: the same sums). Leaves the sums
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
# rows) and writes the image itself, with the unsharp mask and any fused pointwise effects; beyond it
# the blocked columns and a reassembly pass are faster (docs/postfx.md, "How fast, and why").
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
        SHADERS[name] = HEADER + orig + f"""uniform sampler3D rows;
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
    SHADERS[horizontal] = HEADER + f"""uniform sampler2D img;
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
    SHADERS[horizontal + "r"] = HEADER + f"""uniform sampler3D img;
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
            SHADERS[name] = HEADER + orig + f"""uniform sampler3D rows;
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
    SHADERS[vertical] = HEADER + f"""uniform sampler3D rows;
uniform float wts[{2 * R + 1}];
uniform ivec2 blocks;
void main() {{
  ivec2 b = ivec2(texCoord * vec2(blocks));
  int y0 = b.y * {GAUSS_BLOCK};
{_column_blocks_tap("b.x", "y0")}{_gauss_taps("tap", R)}{_gauss_writes()}}}
"""
    return horizontal, vertical


# the separable Gaussian's blocks back to one image (gauss_passes); "gauss_unpack_sharpen": the unsharp
# mask x + amount (x - blur) clipped, x from `orig`. Two shaders, not a uniform switch: llvmpipe runs
# both sides of a branch on a uniform, and the blur would pay the fetch of `orig`
for _name, _orig, _unsharp in (
        ("gauss_unpack", "", ""),
        ("gauss_unpack_sharpen", "uniform sampler2D orig;\nuniform float amount;\n",
         "  vec3 x = texture(orig, texCoord).rgb;\n  acc = clamp(x + amount * (x - acc), 0.0, 1.0);\n")):
    SHADERS[_name] = HEADER + "uniform sampler3D blocks;\nuniform ivec2 size;\n" + _orig + "//EPILOGUE::Dec\n" + f"""
void main() {{
  ivec2 p = ivec2(texCoord * vec2(size));
  vec3 at = (vec3(p.x, p.y / {GAUSS_BLOCK}, p.y % {GAUSS_BLOCK}) + 0.5) / vec3(textureSize(blocks, 0));
  vec3 acc = texture(blocks, at).rgb;
{_unsharp}  gl_FragData[0] = vec4(post(acc, p, size), 1.0);
}}
"""


def radius(sigma: float) -> int:
    return (gaussian_weights(sigma).size - 1) // 2


def reads_rows(sigma: float) -> bool:
    """Whether a Gaussian of ``sigma`` reads a row-blocked image in place (radius <= GAUSS_PLAIN_V)."""
    return radius(sigma) <= GAUSS_PLAIN_V


def gaussian(ctx, tex, sigma, orig=None, amount=0.0, epilogue=None, rows_out=False):
    """Separable Gaussian (``postfx.gaussian.gaussian_blur``) in blocks of GAUSS_BLOCK outputs per fragment; with
    ``orig``, the unsharp mask's ``orig + amount (orig - blur)`` clipped. ``epilogue``: pointwise effects
    fused into the last pass (``shaders.Epilogue``).

    Row-blocked images (``Context.row_blocked``: a 3D target whose layer k holds the rows k, k + L, ...):
    with ``rows_out`` a radius up to GAUSS_PLAIN_V writes its result so, GAUSS_BLOCK rows per fragment
    from GAUSS_BLOCK + 2R fetches instead of 2R + 1 per row (``_gauss_rows_out``; the caller asks
    for it when the result goes to the read-back or to another such Gaussian); ``tex`` (and ``orig``)
    may be row-blocked, and are read in place."""
    w = tex.GetWidth()
    h = ctx.row_blocked.get(id(tex), tex.GetHeight())
    weights = gaussian_weights(sigma)
    if weights.size > MAX_TAPS:
        raise ValueError(f"sigma_px = {sigma} needs {weights.size} taps, the shader holds {MAX_TAPS}")
    R = (weights.size - 1) // 2
    horizontal, vertical = gauss_passes(R)
    wts = FloatArray(weights)
    bx, by = -(-w // GAUSS_BLOCK), -(-h // GAUSS_BLOCK)
    rows = ctx.draw(horizontal + ("r" if id(tex) in ctx.row_blocked else ""), {"img": tex},
                    {"wts": wts, "blocks": IVec2((bx, h))}, bx, h, layers=GAUSS_BLOCK)
    ep = epilogue or Epilogue()
    # the unsharp mask's variant: "u" for an image, "U" for a row-blocked one
    unsharp = "" if orig is None else ("U" if id(orig) in ctx.row_blocked else "u")
    if rows_out and R <= GAUSS_PLAIN_V:
        inputs = {"rows": rows, **({} if orig is None else {"orig": orig}), **ep.inputs}
        uniforms = {"wts": wts, "size": IVec2((w, h)), "blocks": IVec2((w, by)), **ep.uniforms}
        if orig is not None:
            uniforms["amount"] = float(amount)
        out = ctx.draw(f"gauss_vb{R}{unsharp}", inputs, uniforms, w, by, epilogue=ep.passes, layers=GAUSS_BLOCK)
        ctx.row_blocked[id(out)] = h
        ctx.release(rows)
        return out
    if unsharp == "U" and R > GAUSS_PLAIN_V:
        raise ValueError("a row-blocked image goes only to Gaussians of radius <= GAUSS_PLAIN_V")
    if R <= GAUSS_PLAIN_V:  # one output per fragment, straight into the image
        inputs = {"rows": rows, **({} if orig is None else {"orig": orig}), **ep.inputs}
        uniforms = {"wts": wts, "size": IVec2((w, h)), **ep.uniforms}
        if orig is not None:
            uniforms["amount"] = float(amount)
        out = ctx.draw(vertical + unsharp, inputs, uniforms, w, h, epilogue=ep.passes)
        ctx.release(rows)
        return out
    cols = ctx.draw(vertical, {"rows": rows}, {"wts": wts, "blocks": IVec2((w, by))}, w, by, layers=GAUSS_BLOCK)
    ctx.release(rows)
    inputs = {"blocks": cols, **({} if orig is None else {"orig": orig}), **ep.inputs}
    uniforms = {"size": IVec2((w, h)), **ep.uniforms}
    if orig is not None:
        uniforms["amount"] = float(amount)
    out = ctx.draw("gauss_unpack" if orig is None else "gauss_unpack_sharpen", inputs, uniforms, w, h,
                   epilogue=ep.passes)
    ctx.release(cols)
    return out

