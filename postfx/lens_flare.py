"""Pseudo lens flare from HDR highlights, NumPy reference (the GLSL passes in ``postfx.osmesa`` mirror it).

After J. Chapman, "Pseudo Lens Flare" (2013), made geometric: stray reflections between lens surfaces
image the bright sources a second time, scaled about the optical centre (ghosts) or spread around it
(halo). Steps, all in scene-linear light before the tone map:

1. ``B``: the part of each pixel above ``threshold`` in luminance, averaged over 2x2 blocks (half
   resolution: the flare is low-frequency), and ``B4`` its 2x2 average (quarter resolution).
2. Features at half resolution. Ghost ``[s, r, g, b]`` at output position p (full-res pixels) reads the
   source at ``q = c + (p - c) / s``: a highlight at x shows at ``c + s (x - c)``. It is weighted by
   ``tint / s^2`` (the ghost's energy does not depend on its scale) and by the radial fade of its
   source ``f(q) = (1 - min(|q - c| / rho, 1))^falloff``, rho = half the image diagonal. Ghosts with
   |s| >= 1 read ``B`` and smaller ones ``B4``, so that neighbouring outputs never step over a
   source texel. The halo reads ``q = p + h (c - p) / |c - p|`` (h = ``halo_radius`` x half the
   height): a highlight at distance d from the centre shows at distance d + h on the same ray (and,
   for d < h, at h - d on the other side); one at the centre draws a ring of radius h.
   Outside the image the sources are zero (a clamp would smear the border into every ghost).
3. Gaussian blur of ``blur_px / 2`` half-res pixels, bilinear upsampling, ``img + intensity F``.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from postfx.effects import add_upsampled, bright_half, gaussian_blur, threads_for
from postfx.params import LensFlare


@njit(cache=True)  # a few hundred microseconds: a parallel region would cost more to wake
def downsample2(img):
    """2x2 block mean (indices clamped at an odd edge)."""
    h, w, nc = img.shape
    hh, wh = (h + 1) // 2, (w + 1) // 2
    out = np.empty((hh, wh, nc), np.float32)
    for jh in range(hh):
        j0, j1 = 2 * jh, min(2 * jh + 1, h - 1)
        for ih in range(wh):
            i0, i1 = 2 * ih, min(2 * ih + 1, w - 1)
            for c in range(nc):
                out[jh, ih, c] = (img[j0, i0, c] + img[j0, i1, c] + img[j1, i0, c] + img[j1, i1, c]) * np.float32(0.25)
    return out


@njit(cache=True, inline="always")
def bilinear_zero(img, x, y):
    """Bilinear sample (r, g, b) at (x, y) in texels (centres at +0.5), zero outside the image."""
    h, w = img.shape[0], img.shape[1]
    fx = x - np.float32(0.5)
    fy = y - np.float32(0.5)
    x0f = np.floor(fx)
    y0f = np.floor(fy)
    tx = fx - x0f
    ty = fy - y0f
    x0 = int(x0f)
    y0 = int(y0f)
    r = np.float32(0.0)
    g = np.float32(0.0)
    b = np.float32(0.0)
    if x0 < -1 or y0 < -1 or x0 >= w or y0 >= h:
        return r, g, b
    for dy in range(2):
        yy = y0 + dy
        if yy < 0 or yy >= h:
            continue
        wy = ty if dy == 1 else np.float32(1.0) - ty
        for dx in range(2):
            xx = x0 + dx
            if xx < 0 or xx >= w:
                continue
            wxy = wy * (tx if dx == 1 else np.float32(1.0) - tx)
            r += wxy * img[yy, xx, 0]
            g += wxy * img[yy, xx, 1]
            b += wxy * img[yy, xx, 2]
    return r, g, b


@njit(cache=True, inline="always")
def _fade(qx, qy, cx, cy, rho, falloff):
    """``(1 - min(|q - c| / rho, 1))^falloff``, an integer power by repeated products (as the shader)."""
    d = np.sqrt((qx - cx) * (qx - cx) + (qy - cy) * (qy - cy)) / rho
    base = max(np.float32(1.0) - d, np.float32(0.0))
    f = np.float32(1.0)
    for _ in range(falloff):
        f *= base
    return f


@njit(cache=True, parallel=True)
def _features(half, quarter, cx, cy, rho, ghosts, halo, halo_tint, falloff):
    """Ghosts and halo at half resolution; positions in full-res pixels (half texel k is centred at
    2k + 1). ``ghosts`` (n, 4) float32 rows [s, r, g, b]."""
    hh, wh, _ = half.shape
    out = np.zeros((hh, wh, 3), np.float32)
    two = np.float32(2.0)
    for jh in prange(hh):
        py = two * (np.float32(jh) + np.float32(0.5))
        for ih in range(wh):
            px = two * (np.float32(ih) + np.float32(0.5))
            a0 = np.float32(0.0)
            a1 = np.float32(0.0)
            a2 = np.float32(0.0)
            for k in range(ghosts.shape[0]):
                s = ghosts[k, 0]
                qx = cx + (px - cx) / s
                qy = cy + (py - cy) / s
                wk = _fade(qx, qy, cx, cy, rho, falloff) / (s * s)
                if wk <= np.float32(0.0):
                    continue
                if abs(s) >= np.float32(1.0):
                    r, g, b = bilinear_zero(half, qx / two, qy / two)
                else:
                    r, g, b = bilinear_zero(quarter, qx / np.float32(4.0), qy / np.float32(4.0))
                a0 += ghosts[k, 1] * wk * r
                a1 += ghosts[k, 2] * wk * g
                a2 += ghosts[k, 3] * wk * b
            dx = cx - px
            dy = cy - py
            d = np.sqrt(dx * dx + dy * dy)
            if halo > np.float32(0.0) and d > np.float32(0.0):
                qx = px + dx * (halo / d)
                qy = py + dy * (halo / d)
                wh_ = _fade(qx, qy, cx, cy, rho, falloff)
                if wh_ > np.float32(0.0):
                    r, g, b = bilinear_zero(half, qx / two, qy / two)
                    a0 += halo_tint[0] * wh_ * r
                    a1 += halo_tint[1] * wh_ * g
                    a2 += halo_tint[2] * wh_ * b
            out[jh, ih, 0] = a0
            out[jh, ih, 1] = a1
            out[jh, ih, 2] = a2
    return out


def geometry(shape, p: LensFlare):
    """Optical centre (full-res pixels), fade radius rho (half diagonal) and halo radius h [px]."""
    h, w = shape[:2]
    return (np.float32(p.centre[0] * w), np.float32(p.centre[1] * h), np.float32(0.5 * np.hypot(w, h)),
            np.float32(p.halo_radius * 0.5 * h))


def ghost_table(p: LensFlare) -> np.ndarray:
    return np.array(p.ghosts, np.float32).reshape(-1, 4)


def features(img: np.ndarray, p: LensFlare) -> np.ndarray:
    """The flare's light at half resolution, before the blur and ``intensity``."""
    half = bright_half(img, p.threshold)
    cx, cy, rho, halo = geometry(img.shape, p)
    with threads_for(half.size):
        return _features(half, downsample2(half), cx, cy, rho, ghost_table(p), halo,
                         np.array(p.halo_tint, np.float32), int(p.falloff))


def lens_flare(img: np.ndarray, p: LensFlare) -> np.ndarray:
    low = features(img, p)
    if p.blur_px > 0.0:
        low = gaussian_blur(low, 0.5 * p.blur_px)
    return add_upsampled(img, low, p.intensity)
