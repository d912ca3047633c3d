"""The NumPy reference implementation of every post-effect: pure functions on float32 (H, W, 3) images.

Pixel centres are at integer + 0.5; images are row-major with row 0 at the top.
"""
from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

from postfx.params import ChromaticAberration, DepthOfField, LaparoscopeMask, Tonemap


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
def _gather_disc(img, reach2, weight, rmax):
    """Scatter-as-gather disc blur: pixel q spreads its value uniformly over its own CoC disc
    (``|q - p|^2 <= reach2[q] = r_q^2 + 1/4``, weight ``1 / (pi max(r_q, 1/2)^2)``), so an in-focus
    pixel (CoC ~ 0) never spreads onto its neighbours."""
    h, w, nc = img.shape
    out = np.empty_like(img)
    R = int(np.ceil(rmax))
    for j in prange(h):
        for i in range(w):
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            wsum = 0.0
            for jj in range(max(j - R, 0), min(j + R + 1, h)):
                dj2 = (jj - j) * (jj - j)
                for ii in range(max(i - R, 0), min(i + R + 1, w)):
                    if dj2 + (ii - i) * (ii - i) > reach2[jj, ii]:
                        continue
                    wt = weight[jj, ii]
                    acc0 += wt * img[jj, ii, 0]
                    acc1 += wt * img[jj, ii, 1]
                    acc2 += wt * img[jj, ii, 2]
                    wsum += wt
            out[j, i, 0] = acc0 / wsum
            out[j, i, 1] = acc1 / wsum
            out[j, i, 2] = acc2 / wsum
    return out


def depth_of_field(img: np.ndarray, depth: np.ndarray, p: DepthOfField, fov_deg: float) -> np.ndarray:
    coc = coc_radius_px(depth, p, fov_deg, img.shape[1])
    if float(coc.max()) < 0.5:
        return img.copy()
    reach2 = (coc.astype(np.float64) ** 2 + 0.25).astype(np.float32)
    weight = (1.0 / (np.pi * np.maximum(coc.astype(np.float64), 0.5) ** 2)).astype(np.float32)
    return _gather_disc(np.ascontiguousarray(img, dtype=np.float32), reach2, weight, float(coc.max()))


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


def aces(x: np.ndarray) -> np.ndarray:
    """ACES filmic fit (Narkowicz 2015): monotonic on x >= 0, maps 0 -> 0 and large x -> 1."""
    a, b, c, d, e = (np.float32(v) for v in (2.51, 0.03, 2.43, 0.59, 0.14))
    return np.clip((x * (a * x + b)) / (x * (c * x + d) + e), 0.0, 1.0)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function on [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, np.float32(1.0 / 2.4)) - 0.055)


def tonemap(img: np.ndarray, p: Tonemap) -> np.ndarray:
    x = np.maximum(img, np.float32(0.0)) * np.float32(2.0**p.exposure)
    if p.curve == "aces":
        y = aces(x)
    elif p.curve == "reinhard":
        y = x / (1.0 + x)
    else:
        y = np.clip(x, 0.0, 1.0)
    return (srgb_encode(y) if p.srgb else y).astype(np.float32)
