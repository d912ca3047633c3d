"""NumPy (numba) kernels several effects share: Rec. 709 luma, bilinear reads, the half-resolution
bright pass and upsampling of bloom and lens flare, and the thread count of small kernels.

Pixel centres are at integer + 0.5; images are row-major float32 (H, W, 3) with row 0 at the top.
"""
from __future__ import annotations

import contextlib

import numba
import numpy as np
from numba import njit, prange

LUMA = (0.2126, 0.7152, 0.0722)  # Rec. 709

# Below this many values (a 640x480 RGB frame at half resolution has 230 400) a kernel runs on one
# thread: each parallel region waits for its slowest thread, and on a loaded machine the second thread
# often waits for the scheduler far longer than the work takes (docs/postfx.md, "How fast, and why").
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


@njit(cache=True)  # a small kernel: a parallel region would cost more to wake than it saves
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
