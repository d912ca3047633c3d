"""The NumPy reference implementation of every post-effect: pure functions on float32 (H, W, 3) images.

Pixel centres are at integer + 0.5; images are row-major with row 0 at the top.
"""
from __future__ import annotations

import contextlib
import functools

import numba
import numpy as np
from numba import njit, prange

from postfx.params import (Bloom, Blur, ChromaticAberration, ColorGrade, DepthOfField, LaparoscopeMask, SensorNoise,
                           Sharpen, Tonemap)


@njit(cache=True, parallel=True)
def _radial_resample(img, cx, cy, scales):
    """Channel c of pixel (i, j) samples the input at c + (p - c) * scales[c], bilinearly (pixel
    centres at +0.5, coordinates clamped to the image)."""
    h, w, nc = img.shape
    out = np.empty_like(img)
    for j in prange(h):
        y = j + 0.5
        for i in range(w):
            x = i + 0.5
            for c in range(nc):
                sx = np.float32(cx + (x - cx) * scales[c])
                sy = np.float32(cy + (y - cy) * scales[c])
                out[j, i, c] = bilinear_clamped(img, c, sx, sy)
    return out


def chromatic_aberration(img: np.ndarray, p: ChromaticAberration) -> np.ndarray:
    """Magnify channel c by ``1 + strength_c`` about the optical centre (bilinear resampling)."""
    h, w, _ = img.shape
    scales = np.array([1.0 / (1.0 + k) if k > -1.0 else 1e6 for k in (p.strength_r, p.strength_g, p.strength_b)])
    return _radial_resample(np.ascontiguousarray(img, dtype=np.float32), p.centre[0] * w, p.centre[1] * h, scales)


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


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / np.maximum(e1 - e0, 1e-12), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def mask_weights(h: int, w: int, p: LaparoscopeMask) -> np.ndarray:
    """(H, W) float32 weights: 1 inside the scope circle, 0 outside, a smoothstep edge of width
    ``softness`` centred on ``radius``, times the vignette ``1 - vignette (rho / radius)^2``."""
    return _mask_weights(h, w, p.radius, p.softness, p.vignette, p.offset[0], p.offset[1])


@functools.lru_cache(maxsize=8)
def _mask_weights(h, w, radius, softness, vignette, off_x, off_y) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    cx, cy = w * (0.5 + off_x), h * (0.5 + off_y)
    rho = np.hypot(x - cx, y - cy) / (0.5 * h)
    if softness == 0.0:
        edge = (rho <= radius).astype(np.float64)
    else:
        edge = 1.0 - smoothstep(radius - 0.5 * softness, radius + 0.5 * softness, rho)
    weights = (edge * (1.0 - vignette * np.clip(rho / radius, 0.0, 1.0) ** 2)).astype(np.float32)
    weights.setflags(write=False)
    return weights


def laparoscope_mask(img: np.ndarray, p: LaparoscopeMask) -> np.ndarray:
    return img * mask_weights(img.shape[0], img.shape[1], p)[..., None]  # weights cached per size and params


@njit(cache=True, inline="always")
def _srgb1(x):
    x = min(max(x, np.float32(0.0)), np.float32(1.0))
    return np.float32(12.92) * x if x <= np.float32(0.0031308) else (np.float32(1.055) * x ** np.float32(1.0 / 2.4)
                                                                      - np.float32(0.055))


@njit(cache=True, inline="always")
def _tonemap1(x, gain, curve, srgb):
    """One float32 value: exposure ``gain``, then the curve (0 ACES fit, 1 Reinhard, 2 clamp), then sRGB."""
    zero, one = np.float32(0.0), np.float32(1.0)
    x = max(x, zero) * gain
    if curve == 0:  # ACES fit (Narkowicz 2015)
        y = min(max((x * (np.float32(2.51) * x + np.float32(0.03)))
                    / (x * (np.float32(2.43) * x + np.float32(0.59)) + np.float32(0.14)), zero), one)
    elif curve == 1:
        y = x / (one + x)
    else:
        y = min(x, one)
    return _srgb1(y) if srgb else y


@njit(cache=True, parallel=True)
def _tonemap_kernel(img, gain, curve, srgb):
    """float32 throughout, as the shader (float64 pow cost 40 % more and changed nothing visible)."""
    h, w, nc = img.shape
    out = np.empty_like(img)
    gain = np.float32(gain)
    for j in prange(h):
        for i in range(w):
            for c in range(nc):
                out[j, i, c] = _tonemap1(img[j, i, c], gain, curve, srgb)
    return out


TONE_CURVES = {"aces": 0, "reinhard": 1, "clamp": 2}


def tonemap(img: np.ndarray, p: Tonemap) -> np.ndarray:
    """Exposure ``2^exposure``, then the ACES fit, Reinhard ``x / (1 + x)`` or a clamp, then sRGB."""
    return _tonemap_kernel(np.ascontiguousarray(img, dtype=np.float32), float(2.0**p.exposure),
                           TONE_CURVES[p.curve], bool(p.srgb))


LUT_SIZE = 1024
LUMA = (0.2126, 0.7152, 0.0722)  # Rec. 709


def _monotone_curve(points):
    from scipy.interpolate import PchipInterpolator

    pts = np.asarray(points, dtype=np.float64)
    spline = PchipInterpolator(pts[:, 0], pts[:, 1], extrapolate=False)
    return lambda x: np.where(x <= pts[0, 0], pts[0, 1], np.where(x >= pts[-1, 0], pts[-1, 1], spline(x)))


@functools.lru_cache(maxsize=16)
def _grade_lut(key: str) -> np.ndarray:
    p = ColorGrade.model_validate_json(key)
    x = np.linspace(0.0, 1.0, LUT_SIZE)
    master = _monotone_curve(p.curve)
    lut = np.empty((LUT_SIZE, 3), np.float32)
    for c, own in enumerate((p.curve_r, p.curve_g, p.curve_b)):
        y = np.clip(x + p.lift[c] * (1.0 - x), 0.0, None) ** (1.0 / p.gamma[c]) * p.gain[c]
        y = np.clip(y, 0.0, 1.0)
        with np.errstate(divide="ignore"):
            a, b = y**p.contrast, (1.0 - y) ** p.contrast
        y = np.where(a + b > 0, a / np.maximum(a + b, 1e-300), 0.0)
        y = master(y)
        if own is not None:
            y = _monotone_curve(own)(y)
        lut[:, c] = np.clip(y, 0.0, 1.0)
    lut.setflags(write=False)
    return lut


def grade_lut(p: ColorGrade) -> np.ndarray:
    """(LUT_SIZE, 3) float32: the per-channel part of the grade sampled on [0, 1]."""
    return _grade_lut(p.model_dump_json())  # lists make the model unhashable: cache on its JSON


@njit(cache=True, inline="always")
def _grade1(r0, g0, b0, lut, saturation, l0, l1, l2):
    """One pixel: the per-channel LUT (linear interpolation), then saturation about luma, in float64."""
    n = lut.shape[0]
    f0 = min(max(np.float64(r0), 0.0), 1.0) * (n - 1)
    f1 = min(max(np.float64(g0), 0.0), 1.0) * (n - 1)
    f2 = min(max(np.float64(b0), 0.0), 1.0) * (n - 1)
    k0, k1, k2 = min(int(f0), n - 2), min(int(f1), n - 2), min(int(f2), n - 2)
    r = lut[k0, 0] + (f0 - k0) * (lut[k0 + 1, 0] - lut[k0, 0])
    g = lut[k1, 1] + (f1 - k1) * (lut[k1 + 1, 1] - lut[k1, 1])
    b = lut[k2, 2] + (f2 - k2) * (lut[k2 + 1, 2] - lut[k2, 2])
    luma = l0 * r + l1 * g + l2 * b
    return (min(max(luma + saturation * (r - luma), 0.0), 1.0), min(max(luma + saturation * (g - luma), 0.0), 1.0),
            min(max(luma + saturation * (b - luma), 0.0), 1.0))


@njit(cache=True, parallel=True)
def _grade_kernel(img, lut, saturation, l0, l1, l2):
    h, w, _ = img.shape
    out = np.empty_like(img)
    for j in prange(h):
        for i in range(w):
            r, g, b = _grade1(img[j, i, 0], img[j, i, 1], img[j, i, 2], lut, saturation, l0, l1, l2)
            out[j, i, 0] = r
            out[j, i, 1] = g
            out[j, i, 2] = b
    return out


def color_grade(img: np.ndarray, p: ColorGrade) -> np.ndarray:
    """Grade display values in [0, 1]: the per-channel LUT (linear interpolation), then saturation."""
    return _grade_kernel(np.ascontiguousarray(img, dtype=np.float32), grade_lut(p), float(p.saturation), *LUMA)


def gaussian_weights(sigma: float) -> np.ndarray:
    """Normalised 1-D Gaussian taps for offsets -R..R, R = ceil(3 sigma)."""
    R = int(np.ceil(3.0 * sigma))
    x = np.arange(-R, R + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return (w / w.sum()).astype(np.float32)


@njit(cache=True, parallel=True)
def _convolve_rows(img, w):
    """The horizontal pass with clamped edges. Each row is copied once with its R edge pixels
    repeated, then every tap is one multiply-add over the whole contiguous row (pixel and channel
    interleaved, so the offset of tap k is k * channels): this loop vectorises, where a clamped index
    per tap did not. Each output still sums its taps in the order k = 0 .. 2R from zero, in float32,
    as the shader does."""
    h, wd, nc = img.shape
    R = (w.shape[0] - 1) // 2
    n = wd * nc
    out = np.empty_like(img)
    flat = out.reshape(h, n)
    for j in prange(h):
        row = np.empty((wd + 2 * R) * nc, np.float32)
        for i in range(wd + 2 * R):
            src = min(max(i - R, 0), wd - 1)
            for c in range(nc):
                row[i * nc + c] = img[j, src, c]
        acc = np.zeros(n, np.float32)
        for k in range(w.shape[0]):
            wk = w[k]
            off = k * nc
            for f in range(n):
                acc[f] += wk * row[off + f]
        flat[j, :] = acc
    return out


@njit(cache=True, parallel=True)
def _convolve_columns(img, w, orig, amount, unsharp):
    """The vertical pass with clamped edges, whole rows at a time (vectorised); with ``unsharp``, fused
    with the unsharp mask ``x + amount (x - blur)`` clipped to [0, 1] (x from ``orig``)."""
    h, wd, nc = img.shape
    R = (w.shape[0] - 1) // 2
    n = wd * nc
    src = img.reshape(h, n)
    x = orig.reshape(h, n)
    out = np.empty_like(img)
    flat = out.reshape(h, n)
    zero, one = np.float32(0.0), np.float32(1.0)
    for j in prange(h):
        acc = np.zeros(n, np.float32)
        for k in range(w.shape[0]):
            wk = w[k]
            jj = min(max(j + k - R, 0), h - 1)
            for f in range(n):
                acc[f] += wk * src[jj, f]
        if unsharp:
            for f in range(n):
                acc[f] = min(max(x[j, f] + amount * (x[j, f] - acc[f]), zero), one)
        flat[j, :] = acc
    return out


# Below this many values (a 640x480 RGB frame at half resolution has 230 400) a kernel runs on one
# thread. Each parallel region waits for its slowest thread: on a loaded 2-core machine the second
# thread often waits for the scheduler, and every region then cost 12 ms (measured at load 3.4: the
# half-resolution Gaussian 24 ms on two threads, 1 ms on one; bloom 36 vs 12 ms, lens flare 63 vs 22)
# for work of about a millisecond; with two idle cores one thread costs a fraction of a millisecond more.
SERIAL_BELOW = 1 << 18


@contextlib.contextmanager
def threads_for(values: int):
    """Run the numba kernels inside on one thread when they touch fewer than SERIAL_BELOW values."""
    threads = numba.get_num_threads()
    if values >= SERIAL_BELOW or threads == 1:
        yield
        return
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(threads)


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur with clamped edges (the GLSL passes do the same taps)."""
    w = gaussian_weights(sigma)
    img = np.ascontiguousarray(img, dtype=np.float32)
    with threads_for(img.size):
        return _convolve_columns(_convolve_rows(img, w), w, img, np.float32(0.0), False)


def blur(img: np.ndarray, p: Blur) -> np.ndarray:
    return gaussian_blur(img, p.sigma_px)


def sharpen(img: np.ndarray, p: Sharpen) -> np.ndarray:
    """Unsharp mask ``x + amount (x - blur_sigma(x))`` clipped to [0, 1]."""
    w = gaussian_weights(p.sigma_px)
    img = np.ascontiguousarray(img, dtype=np.float32)
    return _convolve_columns(_convolve_rows(img, w), w, img, np.float32(p.amount), True)


@njit(cache=True)  # under a millisecond: a parallel region would cost more to wake
def _bright_half(img, threshold, l0, l1, l2):
    """Half resolution (ceil(H/2), ceil(W/2)): the mean over each 2x2 block (indices clamped at an odd
    edge) of the part of each pixel above ``threshold`` in luminance. The mean keeps the energy per area,
    and the bilinear upsampling spreads each texel over weights that sum to 4 full-res pixels."""
    h, w, _ = img.shape
    hh, wh = (h + 1) // 2, (w + 1) // 2
    out = np.empty((hh, wh, 3), np.float32)
    for jh in range(hh):
        for ih in range(wh):
            a0 = np.float32(0.0)
            a1 = np.float32(0.0)
            a2 = np.float32(0.0)
            for dy in range(2):
                j = min(2 * jh + dy, h - 1)
                for dx in range(2):
                    i = min(2 * ih + dx, w - 1)
                    r, g, b = img[j, i, 0], img[j, i, 1], img[j, i, 2]
                    lum = l0 * r + l1 * g + l2 * b
                    s = max(lum - threshold, np.float32(0.0)) / max(lum, np.float32(1e-12))
                    a0 += r * s
                    a1 += g * s
                    a2 += b * s
            out[jh, ih, 0] = a0 * np.float32(0.25)
            out[jh, ih, 1] = a1 * np.float32(0.25)
            out[jh, ih, 2] = a2 * np.float32(0.25)
    return out


def bright_half(img: np.ndarray, threshold: float) -> np.ndarray:
    return _bright_half(np.ascontiguousarray(img, dtype=np.float32), np.float32(threshold),
                        *(np.float32(v) for v in LUMA))


@njit(cache=True, inline="always")
def bilinear_clamped(img, c, x, y):
    """Bilinear sample of channel c at (x, y) in pixels (centres at +0.5), coordinates clamped."""
    h, w = img.shape[0], img.shape[1]
    fx = min(max(x - np.float32(0.5), np.float32(0.0)), np.float32(w - 1))
    fy = min(max(y - np.float32(0.5), np.float32(0.0)), np.float32(h - 1))
    x0 = min(int(fx), w - 2) if w > 1 else 0
    y0 = min(int(fy), h - 2) if h > 1 else 0
    tx = fx - x0
    ty = fy - y0
    x1 = min(x0 + 1, w - 1)
    y1 = min(y0 + 1, h - 1)
    top = img[y0, x0, c] * (1 - tx) + img[y0, x1, c] * tx
    bottom = img[y1, x0, c] * (1 - tx) + img[y1, x1, c] * tx
    return top * (1 - ty) + bottom * ty


@njit(cache=True, parallel=True)
def _add_upsampled(img, low, k):
    """``img + k up(low)``: ``low`` at half resolution, read bilinearly at ((i + 1/2) / 2, (j + 1/2) / 2)
    (``bilinear_clamped``'s weights, computed once for the three channels)."""
    h, w, nc = img.shape
    hl, wl = low.shape[0], low.shape[1]
    out = np.empty_like(img)
    half = np.float32(0.5)
    for j in prange(h):
        fy = min(max((np.float32(j) + half) * half - half, np.float32(0.0)), np.float32(hl - 1))
        y0 = min(int(fy), hl - 2) if hl > 1 else 0
        ty = fy - y0
        y1 = min(y0 + 1, hl - 1)
        for i in range(w):
            fx = min(max((np.float32(i) + half) * half - half, np.float32(0.0)), np.float32(wl - 1))
            x0 = min(int(fx), wl - 2) if wl > 1 else 0
            tx = fx - x0
            x1 = min(x0 + 1, wl - 1)
            for c in range(nc):
                top = low[y0, x0, c] * (1 - tx) + low[y0, x1, c] * tx
                bottom = low[y1, x0, c] * (1 - tx) + low[y1, x1, c] * tx
                out[j, i, c] = img[j, i, c] + k * (top * (1 - ty) + bottom * ty)
    return out


def add_upsampled(img: np.ndarray, low: np.ndarray, k: float) -> np.ndarray:
    return _add_upsampled(np.ascontiguousarray(img, dtype=np.float32), low, np.float32(k))


def bloom(img: np.ndarray, p: Bloom) -> np.ndarray:
    """Glow at half resolution (a low-frequency effect): the bright part averaged over 2x2 blocks,
    blurred by ``sigma_px / 2`` half-res pixels, upsampled bilinearly and added times ``intensity``."""
    low = gaussian_blur(bright_half(img, p.threshold), 0.5 * p.sigma_px)
    return add_upsampled(img, low, p.intensity)


NOISE_SALT = 0x5E45A1B3
_U24 = 1.0 / 16777216.0


@njit(cache=True, inline="always")
def hash32(x):
    """Integer hash of a uint32 held in an int64 ("lowbias32", C. Wellons 2018); the GLSL ``hash32``.
    The products may wrap in 64 bits: only their low 32 bits are kept, and those are exact."""
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    x ^= x >> 16
    return x


@njit(cache=True, parallel=True)
def _noise_field(h, w, nc, key):
    """Standard normal field from a counter-based generator. Values 2m and 2m + 1 of the flat
    (row, column, channel) index are one Box-Muller pair, ``r cos(2 pi u2)`` and ``r sin(2 pi u2)``
    with ``r = sqrt(-2 ln u1)``, and ``u_k = (hash32(hash32(2m + k) ^ key) >> 8 + 1/2) / 2^24``
    (k = 0, 1; exact in float32). Any value can be drawn alone, so the shader draws the same field
    without an upload."""
    total = h * w * nc
    out = np.empty(total + 1, np.float32)
    npairs = (total + 1) // 2
    two_pi = np.float32(2.0 * np.pi)
    chunk = 4096
    for b in prange((npairs + chunk - 1) // chunk):
        m0 = b * chunk
        m1 = min(m0 + chunk, npairs)
        u1 = np.empty(chunk, np.float32)
        u2 = np.empty(chunk, np.float32)
        for m in range(m0, m1):  # the hashes vectorise apart from the transcendental functions
            n = np.int64(m) * 2
            u1[m - m0] = (np.float32(hash32(hash32(n) ^ key) >> 8) + np.float32(0.5)) * np.float32(_U24)
            u2[m - m0] = (np.float32(hash32(hash32(n + 1) ^ key) >> 8) + np.float32(0.5)) * np.float32(_U24)
        for m in range(m0, m1):
            r = np.sqrt(np.float32(-2.0) * np.log(u1[m - m0]))
            angle = two_pi * u2[m - m0]
            out[2 * m] = r * np.cos(angle)
            out[2 * m + 1] = r * np.sin(angle)
    return out[:total].reshape(h, w, nc)


def noise_key(seed: int) -> int:
    """The generator's key for a frame seed (a uint32)."""
    return int(hash32(np.int64((int(seed) ^ NOISE_SALT) & 0xFFFFFFFF)))


def noise_field(shape, seed: int) -> np.ndarray:
    """Standard normal float32 field (H, W, C) for the frame's seed (the shader draws the same one)."""
    h, w, nc = shape
    return _noise_field(h, w, nc, np.int64(noise_key(seed)))


def sensor_noise(img: np.ndarray, p: SensorNoise, seed: int) -> np.ndarray:
    z = noise_field(img.shape, seed)
    sd = np.sqrt(np.maximum(img, 0.0) * np.float32(p.shot) + np.float32(p.read) ** 2)
    return np.maximum(img + sd * z, 0.0)


# -- runs of pointwise effects in one pass (apply_chain) -------------------------------------------------
POINTWISE = ("sensor_noise", "tonemap", "color_grade", "laparoscope_mask")
_OP = {name: k for k, name in enumerate(POINTWISE)}


@njit(cache=True, parallel=True)
def _pointwise_kernel(img, ops, fpar, ipar, lut, weights):
    """A run of pointwise effects, row by row in one parallel loop: op 0 sensor noise (fpar shot, read;
    ipar key), 1 tone map (fpar gain; ipar curve, srgb), 2 colour grade (fpar saturation, luma; ``lut``),
    3 mask (``weights``). Each op does the float32 arithmetic of its own kernel above and the value
    is rounded to float32 between ops, as when they run one after the other, so the result is the
    same to the bit (tested); one pass over the image instead of one per effect."""
    h, w, nc = img.shape
    out = np.empty_like(img)
    n_row = w * nc
    two_pi = np.float32(2.0 * np.pi)
    zero = np.float32(0.0)
    for j in prange(h):
        x = np.empty(n_row, np.float32)
        for i in range(w):
            for c in range(nc):
                x[i * nc + c] = img[j, i, c]
        for k in range(ops.shape[0]):
            op = ops[k]
            if op == 0:  # the values (j w + i) nc + c of the counter-based field, pairs (2m, 2m + 1)
                n0 = j * n_row
                m0 = n0 // 2
                m1 = (n0 + n_row - 1) // 2 + 1
                u1 = np.empty(m1 - m0, np.float32)
                u2 = np.empty(m1 - m0, np.float32)
                key = ipar[k, 0]
                for m in range(m0, m1):
                    n = np.int64(m) * 2
                    u1[m - m0] = (np.float32(hash32(hash32(n) ^ key) >> 8) + np.float32(0.5)) * np.float32(_U24)
                    u2[m - m0] = (np.float32(hash32(hash32(n + 1) ^ key) >> 8) + np.float32(0.5)) * np.float32(_U24)
                shot = np.float32(fpar[k, 0])
                read = np.float32(fpar[k, 1])
                read2 = read * read
                for m in range(m0, m1):
                    r = np.sqrt(np.float32(-2.0) * np.log(u1[m - m0]))
                    angle = two_pi * u2[m - m0]
                    for t in range(2):
                        f = 2 * m + t - n0
                        if f < 0 or f >= n_row:
                            continue
                        z = r * np.cos(angle) if t == 0 else r * np.sin(angle)
                        sd = np.sqrt(max(x[f], zero) * shot + read2)
                        x[f] = max(x[f] + sd * z, zero)
            elif op == 1:
                gain = np.float32(fpar[k, 0])
                for f in range(n_row):
                    x[f] = _tonemap1(x[f], gain, ipar[k, 0], ipar[k, 1])
            elif op == 2:
                for i in range(w):
                    r, g, b = _grade1(x[i * nc], x[i * nc + 1], x[i * nc + 2], lut, fpar[k, 0], fpar[k, 1],
                                      fpar[k, 2], fpar[k, 3])
                    x[i * nc] = r
                    x[i * nc + 1] = g
                    x[i * nc + 2] = b
            else:
                for i in range(w):
                    for c in range(nc):
                        x[i * nc + c] = x[i * nc + c] * weights[j, i]
        for i in range(w):
            for c in range(nc):
                out[j, i, c] = x[i * nc + c]
    return out


def pointwise_chain(img: np.ndarray, run, seed: int = 0) -> np.ndarray:
    """Apply ``run`` (a list of ``(name, params)`` of pointwise effects, at most one colour grade) in one
    pass; equal to applying them one after the other."""
    img = np.ascontiguousarray(img, dtype=np.float32)
    h, w = img.shape[:2]
    ops = np.array([_OP[name] for name, _ in run], np.int64)
    fpar = np.zeros((len(run), 4), np.float64)
    ipar = np.zeros((len(run), 2), np.int64)
    lut = np.zeros((2, 3), np.float32)
    weights = np.zeros((1, 1), np.float32)
    for k, (name, p) in enumerate(run):
        if name == "sensor_noise":
            fpar[k, :2] = p.shot, p.read
            ipar[k, 0] = noise_key(seed)
        elif name == "tonemap":
            fpar[k, 0] = float(np.float32(2.0**p.exposure))
            ipar[k] = TONE_CURVES[p.curve], int(bool(p.srgb))
        elif name == "color_grade":
            if lut.shape[0] != 2:
                raise ValueError("one colour grade per pointwise run")
            lut = grade_lut(p)
            fpar[k] = p.saturation, *LUMA
        else:
            if weights.shape != (1, 1):
                raise ValueError("one mask per pointwise run")
            weights = mask_weights(h, w, p)
    return _pointwise_kernel(img, ops, fpar, ipar, lut, weights)
