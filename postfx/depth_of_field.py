"""Depth of field: thin-lens circle of confusion from depth, each pixel spread uniformly over its disc.

| name | default | unit | range | equation |
|---|---|---|---|---|
| `focus_distance` | 0.1 | m | (0, 1e5] | in-focus distance `d_f` |
| `aperture` | 0.001 | m | [0, 1] | aperture radius A |
| `focal_length` | 0.004 | m | (0, 1] | focal length f |
| `max_radius_px` | 12 | px | [0, 64] | CoC radius `r = min(c W / (4 f tan(fov / 2)), max_radius_px)`, `c = 2 A f abs(d - d_f) / (d (d_f - f))` |

Scatter-as-gather: pixel q spreads its colour uniformly over its disc ``{p : |p - q|^2 <= r_q^2 + 1/4}``
with weight ``w_q = 1 / (pi max(r_q, 1/2)^2)``, and each output is ``sum w_q c_q / sum w_q`` over the
discs covering it, so an in-focus pixel never spreads. Depth at infinity (the background) takes the
far limit ``|d - d_f| / d -> 1``.

The NumPy reference sums each output's terms by rows (a difference array per row); the GL pass gathers
them over blocks of DOF_BLOCK outputs within a per-tile bound on the reach (``dof_tiles``). Both test
the same integer disc ``di^2 + dj^2 <= reach2`` on the same float32 ``reach2`` and sum the same terms,
in another order.
"""
from __future__ import annotations

import math
import time
from typing import Annotated

import numpy as np
from numba import njit, prange
from pydantic import Field

from postfx.effect import Effect, EffectParams
from postfx.gl.library import IVec2
from postfx.gl.shaders import HEADER, IMAGE_HEADER, register


class DepthOfField(EffectParams):
    """Thin-lens depth of field: circle of confusion from depth, gathered with a disc kernel.

    CoC diameter on the sensor ``c = 2 A f |d - d_f| / (d (d_f - f))`` for aperture radius A, focal
    length f, focus distance d_f and depth d; in pixels ``c W / (2 f tan(fov/2))``.
    """

    focus_distance: Annotated[float, Field(gt=0.0, le=1e5, description="in-focus distance [m]")] = 0.1
    aperture: Annotated[float, Field(ge=0.0, le=1.0, description="aperture radius [m]")] = 0.001
    focal_length: Annotated[float, Field(gt=0.0, le=1.0, description="lens focal length [m]")] = 0.004
    max_radius_px: Annotated[float, Field(ge=0.0, le=64.0, description="largest blur radius [px]")] = 12.0


def coc_radius_px(depth: np.ndarray, p: DepthOfField, fov_deg: float, width: int) -> np.ndarray:
    """Thin-lens circle-of-confusion radius in pixels, clamped to ``max_radius_px`` (0 at infinity
    depth of the background is taken as the far limit ``A f / (d_f - f)``)."""
    f, A, df = p.focal_length, p.aperture, p.focus_distance
    d = np.where(np.isfinite(depth), np.maximum(depth, 1e-9), np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(np.isfinite(d), np.abs(d - df) / d, 1.0)  # |d - df| / d -> 1 as d -> inf
    c_sensor = 2.0 * A * f * rel / max(df - f, 1e-9)  # diameter [m]
    sensor_width = 2.0 * f * np.tan(np.radians(fov_deg) / 2.0)
    radius = 0.5 * c_sensor * width / sensor_width
    return np.minimum(radius, p.max_radius_px).astype(np.float32)


def dof_reach2(coc: np.ndarray) -> np.ndarray:
    """Squared reach ``r^2 + 1/4`` of every pixel's disc (float32, shared by both backends so that the
    integer disc test ``di^2 + dj^2 <= reach2`` picks exactly the same pixels in each)."""
    c = coc.astype(np.float64)
    return (c * c + 0.25).astype(np.float32)


@njit(cache=True, inline="always")
def _dof_weight(reach2):
    """Disc weight ``1 / (pi max(r, 1/2)^2)`` with ``r^2 = reach2 - 1/4`` (float32, as the shader)."""
    return np.float32(1.0) / (np.float32(np.pi) * max(reach2 - np.float32(0.25), np.float32(0.25)))


@njit(cache=True, parallel=True)
def _dof_premultiply(img, reach2):
    """(H, W, 4) float32 ``(r w, g w, b w, w)`` and (H, W) int32 ``floor(reach2)`` per source pixel."""
    h, w, _ = img.shape
    vals = np.empty((h, w, 4), np.float32)
    reach_floor = np.empty((h, w), np.int32)
    for j in prange(h):
        for i in range(w):
            wq = _dof_weight(reach2[j, i])
            for c in range(3):
                vals[j, i, c] = img[j, i, c] * wq
            vals[j, i, 3] = wq
            reach_floor[j, i] = int(reach2[j, i])
    return vals, reach_floor


@njit(cache=True, parallel=True)
def _scatter_disc(vals, reach_floor, R):
    """Scatter-as-gather disc blur, by rows: pixel q spreads its colour uniformly over its own disc
    ``{p : |p - q|^2 <= reach2[q]}`` with weight ``w_q = 1 / (pi max(r_q, 1/2)^2)``, and each output is
    ``sum w_q c_q / sum w_q`` over the discs covering it, so an in-focus pixel never spreads.

    For output row j and source row jq the disc of q covers the span ``|i - iq| <= s``,
    ``s = isqrt(floor(reach2[q]) - (j - jq)^2)`` (the offsets are integers, so ``floor`` changes no
    test). Each span is added to a float64 difference array and one running sum per row gives the
    output: O(R) work per pixel instead of the O(R^2) taps of a gather (the GLSL pass gathers; both
    sum the same terms, in another order)."""
    h, w, _ = vals.shape
    out = np.empty((h, w, 3), np.float32)
    for j in prange(h):
        diff = np.zeros((w + 1, 4), np.float64)
        for jq in range(max(j - R, 0), min(j + R + 1, h)):
            dj2 = (jq - j) * (jq - j)
            for iq in range(w):
                t = reach_floor[jq, iq] - dj2
                if t < 0:
                    continue
                s = int(np.sqrt(np.float64(t)))
                if s * s > t:  # guard the float square root at exact squares
                    s -= 1
                elif (s + 1) * (s + 1) <= t:
                    s += 1
                lo = max(iq - s, 0)
                hi = min(iq + s + 1, w)
                for c in range(4):
                    v = np.float64(vals[jq, iq, c])
                    diff[lo, c] += v
                    diff[hi, c] -= v
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        for i in range(w):
            a0 += diff[i, 0]
            a1 += diff[i, 1]
            a2 += diff[i, 2]
            a3 += diff[i, 3]
            out[j, i, 0] = a0 / a3
            out[j, i, 1] = a1 / a3
            out[j, i, 2] = a2 / a3
    return out


def depth_of_field(img: np.ndarray, depth: np.ndarray, p: DepthOfField, fov_deg: float) -> np.ndarray:
    coc = coc_radius_px(depth, p, fov_deg, img.shape[1])
    rmax = float(coc.max())
    if rmax < 0.5:
        return img.copy()
    vals, reach_floor = _dof_premultiply(np.ascontiguousarray(img, dtype=np.float32), dof_reach2(coc))
    return _scatter_disc(vals, reach_floor, int(np.ceil(rmax)))



# -- GL recipe --------------------------------------------------------------------------------------
DOF_BLOCK = (4, 4)  # output pixels per gather fragment (columns, rows), each written with imageStore
DOF_TILE = 16  # side of the square tiles whose reach bounds the gather loops (a multiple of both block sides)

# Loop-carried values cost llvmpipe more than the arithmetic: inside a loop every write to one of them is
# a masked store (load the old value, select by the lanes' execution mask, store), and the 16 vec4
# accumulators do not fit in the registers. The gather therefore fetches DOF_GROUP = (rows, columns)
# source texels per loop iteration and adds each output's terms from all of them in one expression
# (straight-line SSA values, not masked) before the one write to its accumulator. 2 x 2 texels per
# write measured fastest of the groups tried (docs/postfx.md, "How fast, and why").
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
            # di^2 <= t is exactly the integer disc test di^2 + dj^2 <= reach2 of _scatter_disc
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
    return IMAGE_HEADER + f"""uniform sampler2D src;
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


DOF_GATHER = register("dof_gather", _dof_gather(*DOF_BLOCK))

# the DoF source, padded by `pad` texels of reach -1 (never inside a disc) so that the gather needs
# no bounds test: (r w, g w, b w, reach^2), w = 1 / (pi max(reach^2 - 1/4, 1/4)) as _dof_weight
DOF_SOURCE = register("dof_source", HEADER + "uniform sampler2D img;\nuniform sampler2D reach2;\nuniform int pad;\n" + """
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
""")


# error_model="numpy": IEEE division without numba's zero-division check, which kept the loops from
# vectorising; no operation changes, the results are the same bits
@njit(cache=True, error_model="numpy")
def _coc_reach2(depth, eps, df, k, denom, half, width, sensor_width, max_r, tile, reach2, tiles):
    """``reach2 = dof_reach2(coc_radius_px(depth, ...))`` to the bit, in one loop over the
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
    """(reach2, tile maxima): ``dof_reach2(coc_radius_px(depth, p, fov_deg, width))`` (the
    same float32 values) and, per DOF_TILE x DOF_TILE tile, its largest reach2 (-1 where a partial tile
    has no pixel)."""
    depth = np.asarray(depth)
    h, w = depth.shape
    tiles = np.full((-(-h // DOF_TILE), -(-w // DOF_TILE)), -1.0, np.float32)
    if depth.dtype not in (np.float32, np.float64):  # the kernel mirrors NumPy for these two only
        reach2 = dof_reach2(coc_radius_px(depth, p, fov_deg, width))
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



def draw(ctx, tex, params: DepthOfField, ep, frame):
    """The DoF from the texture ``tex``, or, when the DoF is the chain's first effect (``tex`` None), from
    the frame ``frame.host`` still on the CPU: then its padded source is built there (one numba loop)
    and uploaded in place of the frame, which saves the ``dof_source`` pass and the frame's own upload."""
    host = frame.host if tex is None else None
    h, w = host.shape[:2] if host is not None else (tex.GetHeight(), tex.GetWidth())
    t0 = time.perf_counter()
    reach2, tile_max = coc_reach2(frame.depth, params, frame.lens.fov_deg, w)
    ctx.note("dof reach2 + tile maxima (CPU)", t0)
    max_reach2 = float(tile_max.max())
    if max_reach2 < 0.5:  # every CoC radius below 1/2 (reach2 = r^2 + 1/4): nothing moves
        if tex is None:
            tex = ctx.upload(host)
        return ctx.draw("copy", {"img": tex, **ep.inputs}, ep.uniforms, w, h, epilogue=ep.passes)
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
        src = ctx.draw(DOF_SOURCE, {"img": tex, "reach2": reach_tex}, {"pad": pad}, w + 2 * pad, h + 2 * pad)
    tiles = ctx.upload_into("dof_tiles", dilate_tiles(tile_max, max_reach2))
    blocks = (-(-w // kx), -(-h // ky))
    out = ctx.target(w, h)
    dummy = ctx.draw(DOF_GATHER, {"src": src, "tiles": tiles, **ep.inputs},
                     {"blocks": IVec2(blocks), "size": IVec2((w, h)), "pad": pad, **ep.uniforms},
                     blocks[0], blocks[1], epilogue=ep.passes, images={"dof_out": out})
    ctx.release(src, dummy)
    return out


def _reference(img, depth, p, lens, seed):
    return depth_of_field(img, depth, p, lens.fov_deg)


EFFECT = Effect("depth_of_field", DepthOfField, _reference, draw)
