"""Blue-noise sample rotations: the per-pixel Cranley–Patterson offsets of the light samples taken from a
tiling blue-noise texture instead of white noise (Georgiev & Fajardo 2016, "Blue-noise dithered
sampling"). Each pixel's estimate is as unbiased as before (the offset is still uniform over the
pixels), but neighbouring pixels get offsets far apart, so their errors anticorrelate and the remaining
noise sits at high spatial frequencies, which the eye - and FLIP's contrast-sensitivity filter - damp.

The texture comes from Ulichney's void-and-cluster method (1993): a toroidal Gaussian energy
(sigma = 1.5 pixels) over a binary pattern; the initial pattern is relaxed by swapping its tightest
cluster into its largest void, then every pixel gets a rank by removing clusters (ones, phase 1),
filling voids up to half (phase 2) and filling the tightest clusters of the remaining zeros (phase 3).
Ranks / size are uniform on [0, 1). Generated once per (size, seed) in numba and cached.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from numba import njit, prange

TILE = 64
SIGMA = 1.5


@njit(cache=True)
def _splat(energy, kernel, j, i, sign):
    n = energy.shape[0]
    for a in range(n):
        ja = (j + a) % n
        for b in range(n):
            energy[ja, (i + b) % n] += sign * kernel[a, b]


@njit(cache=True)
def _extreme(energy, pattern, want_one, largest):
    """Index of the largest (or smallest) energy among pixels whose pattern value is ``want_one``."""
    n = energy.shape[0]
    best = -np.inf if largest else np.inf
    bj, bi = -1, -1
    for j in range(n):
        for i in range(n):
            if pattern[j, i] == want_one:
                e = energy[j, i]
                if (largest and e > best) or ((not largest) and e < best):
                    best, bj, bi = e, j, i
    return bj, bi


@njit(cache=True)
def _energy(pattern, kernel, value):
    n = pattern.shape[0]
    energy = np.zeros((n, n))
    for j in range(n):
        for i in range(n):
            if pattern[j, i] == value:
                _splat(energy, kernel, j, i, 1.0)
    return energy


@njit(cache=True)
def _void_and_cluster(initial, kernel):
    n = initial.shape[0]
    total = n * n
    pattern = initial.copy()
    energy = _energy(pattern, kernel, True)
    # relax the initial pattern: move the tightest cluster into the largest void until stable
    for _ in range(10 * total):
        cj, ci = _extreme(energy, pattern, True, True)
        pattern[cj, ci] = False
        _splat(energy, kernel, cj, ci, -1.0)
        vj, vi = _extreme(energy, pattern, False, False)
        pattern[vj, vi] = True
        _splat(energy, kernel, vj, vi, 1.0)
        if vj == cj and vi == ci:
            break
    ones = 0
    for j in range(n):
        for i in range(n):
            ones += pattern[j, i]
    rank = np.zeros((n, n), np.int64)
    # phase 1: rank the initial ones by removing tightest clusters
    work = pattern.copy()
    e1 = energy.copy()
    for r in range(ones - 1, -1, -1):
        cj, ci = _extreme(e1, work, True, True)
        work[cj, ci] = False
        _splat(e1, kernel, cj, ci, -1.0)
        rank[cj, ci] = r
    # phase 2: fill the largest voids up to half
    work = pattern.copy()
    e2 = energy.copy()
    r = ones
    while r < total // 2:
        vj, vi = _extreme(e2, work, False, False)
        work[vj, vi] = True
        _splat(e2, kernel, vj, vi, 1.0)
        rank[vj, vi] = r
        r += 1
    # phase 3: the remaining zeros, tightest cluster of zeros first
    e3 = _energy(work, kernel, False)
    while r < total:
        cj, ci = _extreme(e3, work, False, True)
        work[cj, ci] = True
        _splat(e3, kernel, cj, ci, -1.0)
        rank[cj, ci] = r
        r += 1
    return rank


STORED = Path(__file__).with_name("bluenoise_64.npy")  # generate(64, 0) and generate(64, 1), as uint16 ranks


@functools.lru_cache(maxsize=8)
def texture(size: int = TILE, seed: int = 0) -> np.ndarray:
    """(size, size) blue-noise values, each of (k + 0.5) / size^2 exactly once (read-only). The two
    tiles the renderer uses are stored (``STORED``, tested equal to the generator) rather than generated at
    every start."""
    if size == TILE and seed in (0, 1) and STORED.exists():
        rank = np.load(STORED)[seed].astype(np.int64)
    else:
        rank = generate(size, seed)
    out = (rank + 0.5) / (size * size)
    out.setflags(write=False)
    return out


def generate(size: int, seed: int) -> np.ndarray:
    """Void-and-cluster ranks (size, size), 0 ... size^2 - 1, for a seeded initial pattern."""
    d = np.minimum(np.arange(size), size - np.arange(size)).astype(float)
    kernel = np.exp(-(d[:, None] ** 2 + d[None, :] ** 2) / (2.0 * SIGMA * SIGMA))
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xB10E]))
    initial = np.zeros(size * size, bool)
    initial[rng.choice(size * size, size * size // 10, replace=False)] = True
    return _void_and_cluster(initial.reshape(size, size), kernel)


@njit(cache=True, parallel=True)
def _lookup(rows, cols, ss, a, b, shift, out, phase):
    n = a.shape[0]
    for k in prange(rows.shape[0]):
        r, c = rows[k] // ss, cols[k] // ss
        out[k, 0] = (a[r % n, c % n] + shift[0]) % 1.0
        out[k, 1] = (b[r % n, c % n] + shift[1]) % 1.0
        phase[k] = (rows[k] % ss) * ss + cols[k] % ss


def rotations(rows: np.ndarray, cols: np.ndarray, seed: int, ss: int = 1):
    """(k, 2) Cranley–Patterson offsets for the pixels holding raster samples (rows, cols) of an image
    supersampled ss x ss: two independent blue-noise tiles, each shifted by a per-seed uniform offset (so
    frames with different seeds differ, and each pixel's offset stays uniform); and each sample's index
    in its pixel, 0 ... ss^2 - 1."""
    shift = np.random.default_rng(np.random.SeedSequence([seed, 0xB1])).random(2)
    out = np.empty((rows.shape[0], 2))
    phase = np.empty(rows.shape[0], np.int64)
    _lookup(np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(cols, dtype=np.int64), int(ss),
            texture(TILE, 0), texture(TILE, 1), shift, out, phase)
    return out, phase
