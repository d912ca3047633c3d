"""The NumPy reference implementation of every post-effect: pure functions on float32 (H, W, 3) images.

Pixel centres are at integer + 0.5; images are row-major with row 0 at the top.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from postfx.params import ChromaticAberration, DepthOfField, LaparoscopeMask, Tonemap


def _bilinear(channel: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample ``channel`` at continuous pixel coordinates (centres at +0.5), clamping at the edges."""
    h, w = channel.shape
    fx = np.clip(x - 0.5, 0.0, w - 1.0)
    fy = np.clip(y - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(fx.astype(np.int64), w - 2) if w > 1 else np.zeros_like(fx, dtype=np.int64)
    y0 = np.minimum(fy.astype(np.int64), h - 2) if h > 1 else np.zeros_like(fy, dtype=np.int64)
    tx, ty = fx - x0, fy - y0
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    top = channel[y0, x0] * (1 - tx) + channel[y0, x1] * tx
    bottom = channel[y1, x0] * (1 - tx) + channel[y1, x1] * tx
    return top * (1 - ty) + bottom * ty


def chromatic_aberration(img: np.ndarray, p: ChromaticAberration) -> np.ndarray:
    """Magnify channel c by ``1 + strength_c`` about the optical centre (bilinear resampling)."""
    h, w, _ = img.shape
    cx, cy = p.centre[0] * w, p.centre[1] * h
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    out = np.empty_like(img)
    for c, k in enumerate((p.strength_r, p.strength_g, p.strength_b)):
        scale = 1.0 / (1.0 + k) if k > -1.0 else 1e6
        out[..., c] = _bilinear(img[..., c], cx + (x - cx) * scale, cy + (y - cy) * scale)
    return out


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
def _gather_disc(img, coc, rmax):
    """Scatter-as-gather disc blur: pixel q spreads its value uniformly over its own CoC disc, so an
    in-focus pixel (CoC ~ 0) never spreads onto its neighbours."""
    h, w, nc = img.shape
    out = np.empty_like(img)
    R = int(np.ceil(rmax))
    for j in prange(h):
        for i in range(w):
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            wsum = 0.0
            for dj in range(-R, R + 1):
                jj = j + dj
                if jj < 0 or jj >= h:
                    continue
                for di in range(-R, R + 1):
                    ii = i + di
                    if ii < 0 or ii >= w:
                        continue
                    r = coc[jj, ii]
                    dist2 = di * di + dj * dj
                    if dist2 > r * r + 0.25:
                        continue
                    area = np.pi * max(r, 0.5) ** 2
                    wt = 1.0 / area
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
    return _gather_disc(np.ascontiguousarray(img, dtype=np.float32), coc, float(coc.max()))


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / np.maximum(e1 - e0, 1e-12), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def mask_weights(h: int, w: int, p: LaparoscopeMask) -> np.ndarray:
    """(H, W) float32 weights: 1 inside the scope circle, 0 outside, a smoothstep edge of width
    ``softness`` centred on ``radius``, times the vignette ``1 - vignette (rho / radius)^2``."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    cx, cy = w * (0.5 + p.offset[0]), h * (0.5 + p.offset[1])
    rho = np.hypot(x - cx, y - cy) / (0.5 * h)
    edge = 1.0 - smoothstep(p.radius - 0.5 * p.softness, p.radius + 0.5 * p.softness, rho)
    if p.softness == 0.0:
        edge = (rho <= p.radius).astype(np.float64)
    vignette = 1.0 - p.vignette * np.clip(rho / p.radius, 0.0, 1.0) ** 2
    return (edge * vignette).astype(np.float32)


def laparoscope_mask(img: np.ndarray, p: LaparoscopeMask) -> np.ndarray:
    return img * mask_weights(img.shape[0], img.shape[1], p)[..., None]


def aces(x: np.ndarray) -> np.ndarray:
    """ACES filmic fit (Narkowicz 2015): monotonic on x >= 0, maps 0 -> 0 and large x -> 1."""
    return np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function on [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def tonemap(img: np.ndarray, p: Tonemap) -> np.ndarray:
    x = np.maximum(img, 0.0) * (2.0**p.exposure)
    if p.curve == "aces":
        y = aces(x)
    elif p.curve == "reinhard":
        y = x / (1.0 + x)
    else:
        y = np.clip(x, 0.0, 1.0)
    return (srgb_encode(y) if p.srgb else y).astype(np.float32)
