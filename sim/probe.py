"""Rigid tools: a sphere or capsule following a keyframed path, pushing tissue nodes out of itself.

Contact is resolved by projection (a unilateral position constraint, as in PBD): a node found inside
the probe is moved to the nearest point of its surface. Integrators call it every substep with the
probe at the substep's time, so a probe moving less than its radius per substep cannot pass
through a node (no tunnelling at the speeds used in ``scenes/``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass
class Probe:
    """``kind`` "sphere" or "capsule" (segment of ``length`` along ``axis`` centred on the path point)."""

    kind: str
    radius: float
    times: np.ndarray
    positions: np.ndarray
    axis: np.ndarray = None
    length: float = 0.0

    def __post_init__(self):
        self.times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        axis = np.array([0.0, 0.0, 1.0]) if self.axis is None else np.asarray(self.axis, dtype=np.float64)
        self.axis = axis / np.linalg.norm(axis)
        if self.kind not in ("sphere", "capsule"):
            raise ValueError(f"probe kind must be 'sphere' or 'capsule', found {self.kind!r}")

    def position(self, t: float) -> np.ndarray:
        """Path point at time ``t`` (linear between keyframes, held before the first and after the last)."""
        return np.array([np.interp(t, self.times, self.positions[:, k]) for k in range(3)])

    def segment(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        c = self.position(t)
        half = 0.5 * self.length * self.axis if self.kind == "capsule" else np.zeros(3)
        return c - half, c + half


@njit(cache=True)
def push_out_of_capsule(x, inv_mass, a, b, radius):
    """Move every free node (inverse mass > 0) inside the capsule a-b of ``radius`` onto its surface.
    A sphere is the capsule with a == b. Returns the number of nodes moved."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    len2 = ab0 * ab0 + ab1 * ab1 + ab2 * ab2
    moved = 0
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        ap0, ap1, ap2 = x[i, 0] - a[0], x[i, 1] - a[1], x[i, 2] - a[2]
        s = 0.0
        if len2 > 0.0:
            s = min(max((ap0 * ab0 + ap1 * ab1 + ap2 * ab2) / len2, 0.0), 1.0)
        c0, c1, c2 = a[0] + s * ab0, a[1] + s * ab1, a[2] + s * ab2
        d0, d1, d2 = x[i, 0] - c0, x[i, 1] - c1, x[i, 2] - c2
        dist = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if dist < radius:
            if dist < 1e-12:  # at the axis: push along +z (up, away from the tissue's support)
                d0, d1, d2, dist = 0.0, 0.0, 1.0, 1.0
            scale = radius / dist
            x[i, 0] = c0 + d0 * scale
            x[i, 1] = c1 + d1 * scale
            x[i, 2] = c2 + d2 * scale
            moved += 1
    return moved


def resolve_contact(x: np.ndarray, probe: Probe, t: float, inv_mass: np.ndarray) -> int:
    """Project the free nodes of ``x`` (in place) out of ``probe`` at time ``t``; returns how many moved."""
    a, b = probe.segment(t)
    return int(push_out_of_capsule(x, inv_mass, a, b, float(probe.radius)))
