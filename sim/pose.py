"""Rigid tool poses along keyframes: positions linear in time, orientations unit quaternions ``(w, x, y, z)``
(tool frame to world) spherically interpolated along the shorter arc (slerp, Shoemake 1985), both held before the
first keyframe and after the last; at a keyframe the pose is that keyframe's exactly. Shared by the instruments
(``tissuerender.instruments``) and the mesh tools (``sim.contact_bodies.MeshProbe``).
"""
from __future__ import annotations

import numpy as np


def quat_matrix(q) -> np.ndarray:
    """The rotation matrix of the unit quaternion ``q`` (w, x, y, z)."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def slerp(q0, q1, u: float) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions along the shorter arc; ``q0`` at u = 0 and
    ``q1`` (or ``-q1``, the same rotation) at u = 1 exactly."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    if u <= 0.0:
        return q0.copy()
    d = float(q0 @ q1)
    if d < 0.0:
        q1, d = -q1, -d
    if u >= 1.0:
        return q1.copy()
    if d > 1.0 - 1e-12:  # nearly equal: the chord, renormalised
        q = (1.0 - u) * q0 + u * q1
    else:
        th = np.arccos(d)
        q = (np.sin((1.0 - u) * th) * q0 + np.sin(u * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


def bracket(times: np.ndarray, t: float) -> tuple[int, int, float]:
    """The keyframes ``i, j`` around ``t`` and the fraction ``u`` of the way from i to j (i = j, u = 0 outside)."""
    if t <= times[0]:
        return 0, 0, 0.0
    if t >= times[-1]:
        return len(times) - 1, len(times) - 1, 0.0
    j = int(np.searchsorted(times, t, side="right"))
    return j - 1, j, (t - times[j - 1]) / (times[j] - times[j - 1])


def orientation_at(times: np.ndarray, quaternions: np.ndarray, t: float) -> np.ndarray:
    """The unit quaternion at ``t`` of keyframes ``quaternions`` (k, 4), normalised, at ``times`` (k,)."""
    i, j, u = bracket(times, t)
    return slerp(quaternions[i], quaternions[j], u)
