"""The NumPy reference implementation of every post-effect: pure functions on float32 (H, W, 3) images.

Pixel centres are at integer + 0.5; images are row-major with row 0 at the top.
"""
from __future__ import annotations

import functools

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
                sx = cx + (x - cx) * scales[c]
                sy = cy + (y - cy) * scales[c]
                fx = min(max(sx - 0.5, 0.0), w - 1.0)
                fy = min(max(sy - 0.5, 0.0), h - 1.0)
                x0 = min(int(fx), w - 2) if w > 1 else 0
                y0 = min(int(fy), h - 2) if h > 1 else 0
                tx = fx - x0
                ty = fy - y0
                x1 = min(x0 + 1, w - 1)
                y1 = min(y0 + 1, h - 1)
                top = img[y0, x0, c] * (1 - tx) + img[y0, x1, c] * tx
                bottom = img[y1, x0, c] * (1 - tx) + img[y1, x1, c] * tx
                out[j, i, c] = top * (1 - ty) + bottom * ty
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


@njit(cache=True, parallel=True)
def _gather_disc(src, dj, di, d2, R):
    """Scatter-as-gather disc blur: pixel q spreads its value uniformly over its own CoC disc
    (``|q - p|^2 <= reach2[q] = r_q^2 + 1/4``, weight ``1 / (pi max(r_q, 1/2)^2)``), so an in-focus
    pixel (CoC ~ 0) never spreads onto its neighbours.

    ``src`` (H, W, 5) packs (r w, g w, b w, w, reach2) per pixel so one tap reads one cache line;
    ``(dj, di, d2)`` lists the offsets inside the largest disc, row by row."""
    h, w, _ = src.shape
    out = np.empty((h, w, 3), np.float32)
    n = dj.shape[0]
    for j in prange(h):
        for i in range(w):
            a0 = np.float32(0.0)
            a1 = np.float32(0.0)
            a2 = np.float32(0.0)
            ws = np.float32(0.0)
            if R <= j < h - R and R <= i < w - R:  # interior: no bounds tests, branch-free taps
                for k in range(n):
                    jj = j + dj[k]
                    ii = i + di[k]
                    m = np.float32(1.0) if d2[k] <= src[jj, ii, 4] else np.float32(0.0)
                    a0 += m * src[jj, ii, 0]
                    a1 += m * src[jj, ii, 1]
                    a2 += m * src[jj, ii, 2]
                    ws += m * src[jj, ii, 3]
            else:
                for k in range(n):
                    jj = j + dj[k]
                    ii = i + di[k]
                    if jj < 0 or jj >= h or ii < 0 or ii >= w or d2[k] > src[jj, ii, 4]:
                        continue
                    a0 += src[jj, ii, 0]
                    a1 += src[jj, ii, 1]
                    a2 += src[jj, ii, 2]
                    ws += src[jj, ii, 3]
            out[j, i, 0] = a0 / ws
            out[j, i, 1] = a1 / ws
            out[j, i, 2] = a2 / ws
    return out


def dof_source(img: np.ndarray, coc: np.ndarray) -> np.ndarray:
    """(H, W, 5) float32: premultiplied colour, weight ``1 / (pi max(r, 1/2)^2)`` and reach ``r^2 + 1/4``."""
    c = coc.astype(np.float64)
    weight = 1.0 / (np.pi * np.maximum(c, 0.5) ** 2)
    src = np.empty(img.shape[:2] + (5,), np.float32)
    src[..., :3] = img * weight[..., None]
    src[..., 3] = weight
    src[..., 4] = c * c + 0.25
    return src


def depth_of_field(img: np.ndarray, depth: np.ndarray, p: DepthOfField, fov_deg: float) -> np.ndarray:
    coc = coc_radius_px(depth, p, fov_deg, img.shape[1])
    rmax = float(coc.max())
    if rmax < 0.5:
        return img.copy()
    R = int(np.ceil(rmax))
    jj, ii = np.mgrid[-R:R + 1, -R:R + 1]
    d2 = (jj * jj + ii * ii).ravel()
    keep = d2 <= rmax * rmax + 0.25
    return _gather_disc(dof_source(img, coc), jj.ravel()[keep].astype(np.int64), ii.ravel()[keep].astype(np.int64),
                        d2[keep].astype(np.float32), R)


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
    x = min(max(x, 0.0), 1.0)
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1.0 / 2.4) - 0.055


@njit(cache=True, parallel=True)
def _tonemap_kernel(img, gain, curve, srgb):
    h, w, nc = img.shape
    out = np.empty_like(img)
    for j in prange(h):
        for i in range(w):
            for c in range(nc):
                x = max(np.float64(img[j, i, c]), 0.0) * gain
                if curve == 0:  # ACES fit (Narkowicz 2015)
                    y = min(max((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0), 1.0)
                elif curve == 1:
                    y = x / (1.0 + x)
                else:
                    y = min(x, 1.0)
                out[j, i, c] = _srgb1(y) if srgb else y
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


@njit(cache=True, parallel=True)
def _grade_kernel(img, lut, saturation, l0, l1, l2):
    h, w, _ = img.shape
    n = lut.shape[0]
    out = np.empty_like(img)
    for j in prange(h):
        for i in range(w):
            f0 = min(max(np.float64(img[j, i, 0]), 0.0), 1.0) * (n - 1)
            f1 = min(max(np.float64(img[j, i, 1]), 0.0), 1.0) * (n - 1)
            f2 = min(max(np.float64(img[j, i, 2]), 0.0), 1.0) * (n - 1)
            k0, k1, k2 = min(int(f0), n - 2), min(int(f1), n - 2), min(int(f2), n - 2)
            r = lut[k0, 0] + (f0 - k0) * (lut[k0 + 1, 0] - lut[k0, 0])
            g = lut[k1, 1] + (f1 - k1) * (lut[k1 + 1, 1] - lut[k1, 1])
            b = lut[k2, 2] + (f2 - k2) * (lut[k2 + 1, 2] - lut[k2, 2])
            luma = l0 * r + l1 * g + l2 * b
            out[j, i, 0] = min(max(luma + saturation * (r - luma), 0.0), 1.0)
            out[j, i, 1] = min(max(luma + saturation * (g - luma), 0.0), 1.0)
            out[j, i, 2] = min(max(luma + saturation * (b - luma), 0.0), 1.0)
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
def _convolve_1d(img, w, horizontal):
    """One separable pass with clamped edges: along rows (horizontal) or columns."""
    h, wd, nc = img.shape
    R = (w.shape[0] - 1) // 2
    out = np.empty_like(img)
    for j in prange(h):
        for i in range(wd):
            for c in range(nc):
                acc = np.float32(0.0)
                for k in range(w.shape[0]):
                    if horizontal:
                        acc += w[k] * img[j, min(max(i + k - R, 0), wd - 1), c]
                    else:
                        acc += w[k] * img[min(max(j + k - R, 0), h - 1), i, c]
                out[j, i, c] = acc
    return out


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur with clamped edges (the GLSL passes do the same taps)."""
    w = gaussian_weights(sigma)
    img = np.ascontiguousarray(img, dtype=np.float32)
    return _convolve_1d(_convolve_1d(img, w, True), w, False)


def blur(img: np.ndarray, p: Blur) -> np.ndarray:
    return gaussian_blur(img, p.sigma_px)


def sharpen(img: np.ndarray, p: Sharpen) -> np.ndarray:
    return np.clip(img + np.float32(p.amount) * (img - gaussian_blur(img, p.sigma_px)), 0.0, 1.0)


def bright_part(img: np.ndarray, threshold: float) -> np.ndarray:
    """The part of each pixel above ``threshold`` in Rec. 709 luminance, keeping its colour."""
    lum = img @ np.array(LUMA, np.float32)
    scale = np.maximum(lum - np.float32(threshold), 0.0) / np.maximum(lum, np.float32(1e-12))
    return (img * scale[..., None]).astype(np.float32)


def bloom(img: np.ndarray, p: Bloom) -> np.ndarray:
    return img + np.float32(p.intensity) * gaussian_blur(bright_part(img, p.threshold), p.sigma_px)


def noise_field(shape, seed: int) -> np.ndarray:
    """Standard normal float32 field for the frame's seed (shared by both backends)."""
    return np.random.default_rng(np.random.SeedSequence([seed, 0x5E45])).standard_normal(shape).astype(np.float32)


def sensor_noise(img: np.ndarray, p: SensorNoise, seed: int) -> np.ndarray:
    z = noise_field(img.shape, seed)
    sd = np.sqrt(np.maximum(img, 0.0) * np.float32(p.shot) + np.float32(p.read) ** 2)
    return np.maximum(img + sd * z, 0.0)
