"""Sensor noise: seeded Gaussian noise on the linear signal, deterministic for the frame's seed.

| name | default | unit | range | equation |
|---|---|---|---|---|
| `shot` | 0.002 | linear value | [0, 1] | variance `shot x + read^2` (shot noise proportional to the signal) |
| `read` | 0.003 | linear value | [0, 1] | read noise standard deviation (constant) |

The result is ``max(x + sqrt(max(x, 0) shot + read^2) z, 0)`` with ``z`` a standard normal field drawn
from a counter-based generator (``noise_field``), so the GL backend draws the same field without an
upload. Pointwise: fused with its neighbours in a chain.
"""
from __future__ import annotations

from typing import Annotated

import numpy as np
from numba import njit, prange
from pydantic import Field

from postfx.effect import Effect, EffectParams, Pointwise


class SensorNoise(EffectParams):
    """Seeded sensor noise on linear values: Gaussian with variance ``shot x + read^2`` (shot noise
    proportional to the signal, read noise constant), deterministic for the frame's seed."""

    shot: Annotated[float, Field(ge=0.0, le=1.0)] = 0.002
    read: Annotated[float, Field(ge=0.0, le=1.0)] = 0.003


NOISE_SALT = 0x5E45A1B3
U24 = 1.0 / 16777216.0


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
            u1[m - m0] = (np.float32(hash32(hash32(n) ^ key) >> 8) + np.float32(0.5)) * np.float32(U24)
            u2[m - m0] = (np.float32(hash32(hash32(n + 1) ^ key) >> 8) + np.float32(0.5)) * np.float32(U24)
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


# counter-based Gaussian noise, the same field as noise_field (hash32 = lowbias32)
GLSL = """uniform float noise_shot;
uniform float noise_rd;
uniform int noise_key;
uint hash32(uint x) {
  x ^= x >> 16; x *= 0x7feb352du; x ^= x >> 15; x *= 0x846ca68bu; x ^= x >> 16;
  return x;
}
float unit24(uint x) { return (float(x >> 8) + 0.5) * (1.0 / 16777216.0); }
// values m2 and m2 + 1 (m2 even): one Box-Muller pair
vec2 normal_pair(uint m2, uint key) {
  float r = sqrt(-2.0 * log(unit24(hash32(hash32(m2) ^ key))));
  float angle = 6.2831853071795865 * unit24(hash32(hash32(m2 + 1u) ^ key));
  return vec2(r * cos(angle), r * sin(angle));
}
vec3 fx_sensor_noise(vec3 x, ivec2 p, ivec2 size) {
  uint key = uint(noise_key);  // the uint32 key passed through a signed uniform, same bits
  uint n = uint(p.y * size.x + p.x) * 3u;
  // the pixel's values n, n + 1, n + 2 lie in two pairs (two logarithms, not three)
  vec2 a = normal_pair(n & ~1u, key), b = normal_pair((n & ~1u) + 2u, key);
  vec3 z = (n & 1u) == 0u ? vec3(a, b.x) : vec3(a.y, b);
  vec3 sd = sqrt(max(x, 0.0) * noise_shot + noise_rd * noise_rd);
  return max(x + sd * z, 0.0);
}
"""


def bind(ctx, p: SensorNoise, width: int, height: int, seed: int) -> tuple[dict, dict]:
    key = noise_key(seed)
    return {}, {"noise_shot": float(p.shot), "noise_rd": float(p.read),
                "noise_key": key - (1 << 32) if key >= 1 << 31 else key}


def _reference(img, depth, p, lens, seed):
    return sensor_noise(img, p, seed)


EFFECT = Effect("sensor_noise", SensorNoise, _reference, pointwise=Pointwise(GLSL, bind))
