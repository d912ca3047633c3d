"""A run of consecutive pointwise effects (sensor noise, tone map, colour grade, mask) in one pass over
the image, NumPy backend: the same result, to the bit, as the effects one after the other (tested).
The GL backend fuses them too, as an epilogue of the pass before (``postfx.gl.shaders.source``).

A pointwise effect joins the fused run through an op of ``_pointwise_kernel``; one without an op runs on
its own.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from postfx.color_grade import grade_lut, grade_pixel
from postfx.kernels import LUMA
from postfx.laparoscope_mask import mask_weights
from postfx.sensor_noise import U24, hash32, noise_key
from postfx.tonemap import TONE_CURVES, tonemap_value

POINTWISE = ("sensor_noise", "tonemap", "color_grade", "laparoscope_mask")  # the kernel's ops, in order
_OP = {name: k for k, name in enumerate(POINTWISE)}


@njit(cache=True, parallel=True)
def _pointwise_kernel(img, ops, fpar, ipar, lut, weights):
    """A run of pointwise effects, row by row in one parallel loop: op 0 sensor noise (fpar shot, read;
    ipar key), 1 tone map (fpar gain; ipar curve, srgb), 2 colour grade (fpar saturation, luma; ``lut``),
    3 mask (``weights``). Each op does the float32 arithmetic of its own effect's kernel and the value
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
                    u1[m - m0] = (np.float32(hash32(hash32(n) ^ key) >> 8) + np.float32(0.5)) * np.float32(U24)
                    u2[m - m0] = (np.float32(hash32(hash32(n + 1) ^ key) >> 8) + np.float32(0.5)) * np.float32(U24)
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
                    x[f] = tonemap_value(x[f], gain, ipar[k, 0], ipar[k, 1])
            elif op == 2:
                for i in range(w):
                    r, g, b = grade_pixel(x[i * nc], x[i * nc + 1], x[i * nc + 2], lut, fpar[k, 0], fpar[k, 1],
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


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


_NO_LUT = _readonly(np.zeros((2, 3), np.float32))
_NO_WEIGHTS = _readonly(np.zeros((1, 1), np.float32))


def pointwise_chain(img: np.ndarray, run, seed: int = 0) -> np.ndarray:
    """Apply ``run`` (a list of ``(name, params)`` of pointwise effects, at most one colour grade) in one
    pass; equal to applying them one after the other."""
    img = np.ascontiguousarray(img, dtype=np.float32)
    h, w = img.shape[:2]
    ops = np.array([_OP[name] for name, _ in run], np.int64)
    fpar = np.zeros((len(run), 4), np.float64)
    ipar = np.zeros((len(run), 2), np.int64)
    # placeholders read-only like grade_lut's and mask_weights' cached arrays: one numba signature, one compile
    lut, weights = _NO_LUT, _NO_WEIGHTS
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
