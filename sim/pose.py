"""Rigid tool poses along keyframes: positions linear in time, orientations unit quaternions ``(w, x, y, z)``
(tool frame to world) spherically interpolated along the shorter arc (slerp, Shoemake 1985), both held before the
first keyframe and after the last; at a keyframe the pose is that keyframe's exactly. Shared by the instruments
(``tissuerender.instruments``) and the mesh tools (``sim.contact_bodies.MeshProbe``).

Each function takes many times (or quaternions) at once, one row each: the XPBD sweeps ask for the poses of all the
substeps of a step in one call (``sim.integrators.xpbd.sweeps``). A row's result is the one-row call's bit for bit:
only elementwise operations, and the dot products through ``matmul`` over rows, which calls the same BLAS dot per
row as one ``q0 @ q1`` (tests/sim/test_pose.py checks rows against one-row calls).
"""
from __future__ import annotations

import numpy as np


def _row_dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a[k] @ b[k]`` per row k of (n, m) arrays (each row's product the one-row ``@``: a BLAS dot)."""
    return np.matmul(a[:, None, :], b[:, :, None])[:, 0, 0]


def quat_matrices(q) -> np.ndarray:
    """The rotation matrices (n, 3, 3) of unit quaternions ``q`` (n, 4) (w, x, y, z)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)


def quat_matrix(q) -> np.ndarray:
    """The rotation matrix of the unit quaternion ``q`` (w, x, y, z)."""
    return quat_matrices(q)[0]


def slerps(q0, q1, u) -> np.ndarray:
    """Spherical linear interpolation per row between unit quaternions ``q0``, ``q1`` (n, 4) at fractions ``u``
    (n,) along the shorter arc; ``q0`` at u <= 0 and ``q1`` (or ``-q1``, the same rotation) at u >= 1 exactly."""
    u = np.asarray(u, dtype=np.float64).reshape(-1)
    q0 = np.ascontiguousarray(np.broadcast_to(np.asarray(q0, dtype=np.float64).reshape(-1, 4), (u.size, 4)))
    q1 = np.ascontiguousarray(np.broadcast_to(np.asarray(q1, dtype=np.float64).reshape(-1, 4), (u.size, 4)))
    d = _row_dots(q0, q1)
    flip = d < 0.0
    q1, d = np.where(flip[:, None], -q1, q1), np.where(flip, -d, d)
    chord = d > 1.0 - 1e-12  # nearly equal: the chord, renormalised
    th = np.arccos(np.where(chord, 0.5, d))  # rows on the chord: unused
    along = (np.sin((1.0 - u) * th)[:, None] * q0 + np.sin(u * th)[:, None] * q1) / np.sin(th)[:, None]
    q = np.where(chord[:, None], (1.0 - u)[:, None] * q0 + u[:, None] * q1, along)
    q = q / np.sqrt(_row_dots(q, q))[:, None]
    return np.where((u <= 0.0)[:, None], q0, np.where((u >= 1.0)[:, None], q1, q))


def slerp(q0, q1, u: float) -> np.ndarray:
    """:func:`slerps` of one pair."""
    return slerps(q0, q1, [u])[0]


def brackets(times: np.ndarray, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per time of ``t`` (n,): the keyframes ``i, j`` around it and the fraction ``u`` of the way from i to j
    (i = j, u = 0 outside)."""
    times = np.asarray(times, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    last = len(times) - 1
    if last == 0:
        zero = np.zeros(t.size, np.int64)
        return zero, zero, np.zeros(t.size)
    j = np.clip(np.searchsorted(times, t, side="right"), 1, last)
    u = (t - times[j - 1]) / (times[j] - times[j - 1])
    before, after = t <= times[0], t >= times[-1]
    i = np.where(before, 0, np.where(after, last, j - 1))
    j = np.where(before, 0, np.where(after, last, j))
    return i, j, np.where(before | after, 0.0, u)


def bracket(times: np.ndarray, t: float) -> tuple[int, int, float]:
    """The keyframes ``i, j`` around ``t`` and the fraction ``u`` of the way from i to j (i = j, u = 0 outside)."""
    i, j, u = brackets(times, [t])
    return int(i[0]), int(j[0]), float(u[0])


def orientation_at(times: np.ndarray, quaternions: np.ndarray, t: float) -> np.ndarray:
    """The unit quaternion at ``t`` of keyframes ``quaternions`` (k, 4), normalised, at ``times`` (k,)."""
    i, j, u = bracket(times, t)
    return slerp(quaternions[i], quaternions[j], u)
