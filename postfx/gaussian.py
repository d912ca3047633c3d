"""The separable Gaussian of blur, sharpen, bloom and lens flare, NumPy reference (the GLSL passes in
``postfx.gl.gaussian`` do the same taps in the same order)."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from postfx.kernels import threads_for


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


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur with clamped edges (the GLSL passes do the same taps)."""
    w = gaussian_weights(sigma)
    img = np.ascontiguousarray(img, dtype=np.float32)
    with threads_for(img.size):
        return _convolve_columns(_convolve_rows(img, w), w, img, np.float32(0.0), False)


def unsharp_mask(img: np.ndarray, sigma: float, amount: float) -> np.ndarray:
    """``x + amount (x - blur_sigma(x))`` clipped to [0, 1], the vertical pass fused with the mask."""
    w = gaussian_weights(sigma)
    img = np.ascontiguousarray(img, dtype=np.float32)
    return _convolve_columns(_convolve_rows(img, w), w, img, np.float32(amount), True)
